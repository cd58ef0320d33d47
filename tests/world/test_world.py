"""The synthetic world: scenes, renderer, walks, ground-truth cloud and detection noise.

The world is the ground truth the mapping engine is scored against, so these tests check
geometry, not pictures: a rendered depth pixel back-projected with the camera must land on
the object the instance image names, walks must stay in the rooms, and so on.
Small cameras (160 x 120) keep the suite fast.
"""

from __future__ import annotations

import itertools
import math
import re

import numpy as np
import open3d as o3d
import pytest
from scipy import ndimage

from client_sim.sources.synthetic import SyntheticSource
from world import (
    BACKGROUND_CLASSES,
    CATEGORIES,
    NOISE_PROFILES,
    SCENE_NAMES,
    DetectionModel,
    Renderer,
    Room,
    Scene,
    SceneObject,
    default_camera,
    gt_point_cloud,
    make_scene,
    walk_trajectory,
)
from world.categories import PLACEMENTS, ROOM_TYPES

SMALL_CAMERA = default_camera(160, 120)


@pytest.fixture(scope="module")
def apartment() -> Scene:
    return make_scene("apartment", 0)


@pytest.fixture(scope="module")
def apartment_walk(apartment: Scene) -> list[np.ndarray]:
    return walk_trajectory(apartment, 300, seed=0)


@pytest.fixture(scope="module")
def apartment_renderer(apartment: Scene) -> Renderer:
    return Renderer(apartment)


@pytest.fixture(scope="module")
def walk_views(apartment_renderer: Renderer, apartment_walk: list[np.ndarray]):
    """Rendered views at a spread of poses along the walk (every room gets some)."""
    indices = range(0, len(apartment_walk), 15)
    return [
        (apartment_walk[i], apartment_renderer.render(apartment_walk[i], SMALL_CAMERA))
        for i in indices
    ]


def bbox_table(scene: Scene) -> np.ndarray:
    """float [max_id + 1, 6] bounding boxes indexed by instance id."""
    table = np.zeros((max(o.instance_id for o in scene.objects) + 1, 6))
    for obj in scene.objects:
        table[obj.instance_id] = obj.bbox
    return table


def backproject(depth: np.ndarray, pose: np.ndarray, intrinsics) -> np.ndarray:
    """World points [H, W, 3] of every pixel (pixel centres at integer coordinates)."""
    fx, fy, cx, cy = intrinsics
    v, u = np.indices(depth.shape)
    camera_points = np.stack([(u - cx) / fx * depth, (v - cy) / fy * depth, depth], axis=-1)
    return camera_points @ pose[:3, :3].T + pose[:3, 3]


def rotation_angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    cos = (np.trace(a[:3, :3].T @ b[:3, :3]) - 1) / 2
    return math.degrees(math.acos(np.clip(cos, -1.0, 1.0)))


# --- categories ---------------------------------------------------------------------------


def test_there_are_at_least_40_categories_with_unique_names():
    names = [c.name for c in CATEGORIES.values()]
    assert len(CATEGORIES) >= 40
    assert len(set(names)) == len(names)
    assert all(key == c.name for key, c in CATEGORIES.items())
    assert not set(names) & set(BACKGROUND_CLASSES)


def test_every_category_has_valid_sizes_placement_colours_and_language():
    for name, cat in CATEGORIES.items():
        assert all(0 < lo <= hi for lo, hi in cat.size_m), name
        assert cat.placement in PLACEMENTS, name
        assert cat.rooms and set(cat.rooms) <= set(ROOM_TYPES), name
        assert cat.colors and all(len(c) == 3 and all(0 <= v <= 255 for v in c) for c in cat.colors)
        assert cat.paraphrases and name not in cat.confusions, name


def test_paraphrases_do_not_name_another_category():
    # "a swivel chair" may say "chair" for "office chair", but a lamp's paraphrase may not
    # say "nightstand": that query would be ambiguous between two classes.
    for name, cat in CATEGORIES.items():
        for text in cat.paraphrases:
            for other in CATEGORIES:
                if other != name and other not in name:
                    assert not re.search(rf"\b{re.escape(other)}\b", text), (name, text, other)


def test_realistic_sizes_of_a_sofa_and_a_mug(apartment: Scene):
    sofa = next(o for o in apartment.objects if o.category == "sofa")
    mug = next(o for o in apartment.objects if o.category == "mug")
    sofa_extent = sofa.bbox[3:] - sofa.bbox[:3]
    assert 1.8 <= max(sofa_extent[:2]) <= 2.2 and 0.85 <= min(sofa_extent[:2]) <= 0.95
    assert 0.8 <= sofa_extent[2] <= 0.9
    assert 0.08 <= mug.bbox[5] - mug.bbox[2] <= 0.1


def test_free_standing_and_wall_objects_have_their_category_height():
    # The sink's tap rises above the counter; a tv standing on a stand gets a foot.
    for name in SCENE_NAMES:
        for obj in make_scene(name, 1).objects:
            if obj.is_background or obj.support_id or obj.category == "sink":
                continue
            lo, hi = CATEGORIES[obj.category].size_m[2]
            assert lo - 0.005 <= obj.bbox[5] - obj.bbox[2] <= hi + 0.005, obj.category


# --- scenes -------------------------------------------------------------------------------


def test_make_scene_is_deterministic_per_seed_and_differs_across_seeds():
    def signature(scene: Scene):
        return [(o.instance_id, o.category, tuple(np.round(o.bbox, 6))) for o in scene.objects]

    assert signature(make_scene("office", 3)) == signature(make_scene("office", 3))
    assert signature(make_scene("office", 3)) != signature(make_scene("office", 4))


def test_bad_scene_name_raises_value_error_naming_the_options():
    with pytest.raises(ValueError, match="living_room.*apartment"):
        make_scene("garage")


@pytest.mark.parametrize("name", SCENE_NAMES)
def test_each_scene_is_furnished_with_unique_ids_and_background_surfaces(name: str):
    scene = make_scene(name, 0)
    ids = [o.instance_id for o in scene.objects]
    assert len(set(ids)) == len(ids) and min(ids) >= 1
    categories = {o.category for o in scene.objects}
    assert set(BACKGROUND_CLASSES) <= categories
    assert categories - set(BACKGROUND_CLASSES) <= set(CATEGORIES)
    n_objects = sum(not o.is_background for o in scene.objects)
    if name == "apartment":
        assert len(scene.rooms) == 4 and len(scene.doorways) >= 3
        assert 100 <= n_objects <= 260
        assert {r.type for r in scene.rooms} == {"living_room", "kitchen", "office", "bedroom"}
    else:
        assert len(scene.rooms) == 1 and scene.rooms[0].type == name
        assert 25 <= n_objects <= 80
    assert scene.categories_present == sorted(categories - set(BACKGROUND_CLASSES))
    some = scene.objects[len(scene.objects) // 2]
    assert scene.object_by_id(some.instance_id) is some


def test_several_instances_of_a_category_vary_in_colour(apartment: Scene):
    chairs = [o.color for o in apartment.objects if o.category in ("book", "mug", "chair")]
    assert len(set(chairs)) > 3


def test_objects_stay_in_their_room_and_appear_in_rooms_of_their_category(apartment: Scene):
    for obj in apartment.objects:
        if obj.is_background:
            continue
        room = apartment.rooms[obj.room]
        x0, y0, x1, y1 = room.bounds
        assert x0 - 1e-6 <= obj.bbox[0] and obj.bbox[3] <= x1 + 1e-6, obj.category
        assert y0 - 1e-6 <= obj.bbox[1] and obj.bbox[4] <= y1 + 1e-6, obj.category
        assert obj.bbox[2] >= 0 and obj.bbox[5] <= room.height, obj.category
        assert room.type in CATEGORIES[obj.category].rooms, obj.category


def test_objects_do_not_interpenetrate_except_with_what_they_stand_on(apartment: Scene):
    objects = [o for o in apartment.objects if not o.is_background]
    boxes = np.array([o.bbox for o in objects])
    overlap = (
        (boxes[:, None, :3] < boxes[None, :, 3:] - 1e-6)
        & (boxes[None, :, :3] < boxes[:, None, 3:] - 1e-6)
    ).all(axis=2)
    for i, j in zip(*np.nonzero(np.triu(overlap, 1)), strict=True):
        a, b = objects[i], objects[j]
        assert a.support_id == b.instance_id or b.support_id == a.instance_id, (
            a.category,
            b.category,
        )


def test_small_objects_stand_on_a_surface(apartment: Scene):
    for obj in apartment.objects:
        if not obj.is_background and CATEGORIES[obj.category].placement == "on_surface":
            support = apartment.object_by_id(obj.support_id)
            assert CATEGORIES[support.category].is_surface, (obj.category, support.category)
            assert support.bbox[2] <= obj.bbox[2] <= support.bbox[5] + 0.01


# --- rendering ----------------------------------------------------------------------------


def test_default_camera_has_a_60_degree_fov_and_a_centred_principal_point():
    camera = default_camera()
    assert (camera.width, camera.height) == (640, 480)
    assert math.degrees(2 * math.atan(camera.width / 2 / camera.fx)) == pytest.approx(60.0)
    assert camera.intrinsics == (camera.fx, camera.fy, 319.5, 239.5)


def test_back_projected_depth_lands_on_the_object_the_instance_image_names(apartment, walk_views):
    boxes = bbox_table(apartment)
    for pose, view in walk_views:
        assert view.rgb.shape == (120, 160, 3) and view.rgb.dtype == np.uint8
        assert view.depth_m.dtype == np.float32 and view.instance_ids.dtype == np.uint16
        hit = view.instance_ids > 0
        assert np.array_equal(hit, view.depth_m > 0)
        points = backproject(view.depth_m, pose, SMALL_CAMERA.intrinsics)[hit]
        box = boxes[view.instance_ids[hit]]
        inside = np.all((points >= box[:, :3] - 0.01) & (points <= box[:, 3:] + 0.01), axis=1)
        assert inside.all()


def test_views_show_only_objects_of_the_scene_and_see_furniture(apartment, walk_views):
    ids = {o.instance_id for o in apartment.objects}
    seen: set[int] = set()
    for _pose, view in walk_views:
        visible = set(np.unique(view.instance_ids).tolist()) - {0}
        assert visible <= ids
        seen |= visible
    seen_categories = {apartment.object_by_id(i).category for i in seen}
    assert len(seen_categories - set(BACKGROUND_CLASSES)) >= 15


def test_depth_is_z_depth_along_the_optical_axis():
    # A camera 1 m from a wall, square on: z-depth is 1 m at the centre and at the corners.
    corners = np.array([[-5, 0, -5], [5, 0, -5], [5, 0, 5], [-5, 0, 5]], float)
    wall = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(corners), o3d.utility.Vector3iVector([[0, 1, 2], [0, 2, 3]])
    )
    bbox = np.concatenate([corners.min(0), corners.max(0)])
    scene = Scene(
        "wall",
        0,
        [SceneObject(1, "wall", wall, (200, 200, 200), bbox.reshape(2, 3).mean(0), bbox)],
        [Room("living_room", (-5.0, -5.0, 5.0, 5.0), 2.7)],
    )
    pose = np.eye(4)
    pose[:3, :3] = np.array([[-1, 0, 0], [0, 0, -1], [0, -1, 0]], float).T  # x, y, z axes as rows
    pose[:3, 3] = (0.0, 1.0, 0.0)
    view = Renderer(scene).render(pose, SMALL_CAMERA)
    assert np.allclose(view.depth_m, 1.0, atol=1e-5)
    assert np.all(view.instance_ids == 1)


def test_texture_noise_changes_colours_but_not_geometry(apartment_renderer, apartment_walk):
    pose = apartment_walk[100]
    plain = apartment_renderer.render(pose, SMALL_CAMERA)
    noisy = apartment_renderer.render(pose, SMALL_CAMERA, 0.05, np.random.default_rng(1))
    again = apartment_renderer.render(pose, SMALL_CAMERA, 0.05, np.random.default_rng(1))
    assert np.array_equal(plain.depth_m, noisy.depth_m)
    assert np.array_equal(plain.instance_ids, noisy.instance_ids)
    assert not np.array_equal(plain.rgb, noisy.rgb)
    assert np.array_equal(noisy.rgb, again.rgb)


# --- walks --------------------------------------------------------------------------------


def test_walk_poses_are_rigid_camera_to_world_transforms(apartment_walk):
    assert len(apartment_walk) == 300
    for pose in apartment_walk:
        rotation = pose[:3, :3]
        assert pose.shape == (4, 4)
        assert np.allclose(rotation.T @ rotation, np.eye(3), atol=1e-9)
        assert np.linalg.det(rotation) == pytest.approx(1.0)
        assert np.array_equal(pose[3], [0, 0, 0, 1])


def test_walk_stays_in_the_rooms_at_eye_height_and_out_of_furniture(apartment, apartment_walk):
    boxes = np.array([o.bbox for o in apartment.objects if not o.is_background])
    for pose in apartment_walk:
        x, y, z = pose[:3, 3]
        assert apartment.room_index_at(x, y) >= 0
        assert 1.45 <= z <= 1.65
        inside = np.all((pose[:3, 3] >= boxes[:, :3]) & (pose[:3, 3] <= boxes[:, 3:]), axis=1)
        assert not inside.any()


def test_walk_visits_every_room_of_the_apartment(apartment, apartment_walk):
    rooms = {apartment.room_index_at(*pose[:2, 3]) for pose in apartment_walk}
    assert rooms == set(range(len(apartment.rooms)))


def test_walk_moves_a_few_centimetres_and_degrees_per_frame_looking_slightly_down(apartment_walk):
    steps = [np.linalg.norm(b[:3, 3] - a[:3, 3]) for a, b in itertools.pairwise(apartment_walk)]
    turns = [rotation_angle_deg(a, b) for a, b in itertools.pairwise(apartment_walk)]
    assert np.mean(steps) >= 0.015 and max(steps) <= 0.066
    assert np.mean(turns) <= 3.0 and max(turns) <= 6.5
    optical_axis_z = np.array([pose[2, 2] for pose in apartment_walk])  # camera z in world
    assert np.all(optical_axis_z < 0) and np.all(optical_axis_z > -0.6)


def test_walk_is_deterministic_per_seed_and_handles_short_walks():
    scene = make_scene("bedroom", 2)
    first = walk_trajectory(scene, 40, seed=5)
    assert all(
        np.array_equal(a, b) for a, b in zip(first, walk_trajectory(scene, 40, seed=5), strict=True)
    )
    assert not np.allclose(first[-1], walk_trajectory(scene, 40, seed=6)[-1])
    assert len(walk_trajectory(scene, 1)) == 1 and walk_trajectory(scene, 0) == []


# --- ground-truth cloud -------------------------------------------------------------------


@pytest.fixture(scope="module")
def kitchen_gt():
    scene = make_scene("kitchen", 0)
    return scene, gt_point_cloud(scene, spacing_m=0.04)


def test_gt_cloud_labels_match_instance_categories(kitchen_gt):
    scene, gt = kitchen_gt
    assert gt.points.dtype == np.float32 and gt.instance_ids.dtype == np.int32
    assert gt.class_idx.dtype == np.int32 and len(gt.points) == len(gt.class_idx) == len(
        gt.instance_ids
    )
    assert gt.class_names == sorted(gt.class_names)
    assert set(BACKGROUND_CLASSES) <= set(gt.class_names)
    categories = np.array(gt.class_names)[gt.class_idx]
    for instance_id in np.unique(gt.instance_ids)[::7]:
        assert set(categories[gt.instance_ids == instance_id]) == {
            scene.object_by_id(instance_id).category
        }


def test_gt_points_lie_on_their_objects_at_about_the_requested_spacing(kitchen_gt):
    scene, gt = kitchen_gt
    boxes = bbox_table(scene)[gt.instance_ids]
    assert np.all((gt.points >= boxes[:, :3] - 1e-4) & (gt.points <= boxes[:, 3:] + 1e-4))
    floor = scene.objects[0]
    assert floor.category == "floor"
    floor_points = (gt.instance_ids == floor.instance_id).sum()
    x0, y0, x1, y1 = scene.rooms[0].bounds
    # Floor samples are ~1 per 4 cm x 4 cm, minus what furniture covers.
    assert 0.3 < floor_points * 0.04**2 / ((x1 - x0) * (y1 - y0)) < 1.05


def test_gt_cloud_drops_surfaces_hidden_by_contact(kitchen_gt):
    scene, gt = kitchen_gt
    fridge = next(o for o in scene.objects if o.category == "refrigerator")
    floor_ids = [o.instance_id for o in scene.objects if o.category == "floor"]
    under = np.all(
        (gt.points[:, :2] > fridge.bbox[:2] + 0.05) & (gt.points[:, :2] < fridge.bbox[3:5] - 0.05),
        axis=1,
    )
    assert not (under & np.isin(gt.instance_ids, floor_ids)).any()
    fridge_points = gt.points[gt.instance_ids == fridge.instance_id]
    assert len(fridge_points) and fridge_points[:, 2].min() > 0.0015  # no bottom face


# --- detection noise ----------------------------------------------------------------------


def test_bad_noise_profile_raises_value_error_naming_the_options(apartment):
    with pytest.raises(ValueError, match="none.*standard.*bleed"):
        DetectionModel(apartment, "heavy")
    assert NOISE_PROFILES == ("none", "standard", "bleed")


def test_no_noise_gives_one_exact_detection_per_visible_object(apartment, walk_views):
    model = DetectionModel(apartment, "none")
    for index, (_pose, view) in enumerate(walk_views):
        detections = model.detect(view, index)
        assert detections.depth_m is view.depth_m
        ids, counts = np.unique(view.instance_ids, return_counts=True)
        expected = {
            int(i)
            for i, n in zip(ids, counts, strict=True)
            if i and n >= 50 and not apartment.object_by_id(i).is_background
        }
        assert len(detections.instances) == len(expected)
        for det in detections.instances:
            mask = detections.instance_ids == det["id"]
            (true_id,) = np.unique(view.instance_ids[mask])
            assert int(true_id) in expected
            assert det["label"] == apartment.object_by_id(true_id).category and det["score"] == 1.0
            assert np.array_equal(mask, view.instance_ids == true_id)


def standard_run(scene, views, seed=0):
    model = DetectionModel(scene, "standard", seed=seed)
    return [model.detect(view, index) for index, (_pose, view) in enumerate(views)]


def test_standard_noise_is_deterministic_for_a_seed(apartment, walk_views):
    first = standard_run(apartment, walk_views)
    second = standard_run(apartment, walk_views)
    for a, b in zip(first, second, strict=True):
        assert a.instances == b.instances
        assert np.array_equal(a.instance_ids, b.instance_ids) and np.array_equal(
            a.depth_m, b.depth_m
        )
    other = standard_run(apartment, walk_views, seed=1)
    assert any(a.instances != b.instances for a, b in zip(first, other, strict=True))
    # Frame i's noise depends on (seed, i) only, not on which frames came before it.
    model = DetectionModel(apartment, "standard")
    assert model.detect(walk_views[5][1], 5).instances == first[5].instances


def test_standard_noise_misses_confuses_and_never_reports_background(apartment, walk_views):
    runs = standard_run(apartment, walk_views)
    background = set(BACKGROUND_CLASSES)
    visible_total = detected = confused = spurious = 0
    for (_pose, view), detections in zip(walk_views, runs, strict=True):
        ids = set(np.unique(detections.instance_ids).tolist()) - {0}
        assert ids == {d["id"] for d in detections.instances} == set(detections.sources)
        ids_seen, counts = np.unique(view.instance_ids, return_counts=True)
        visible = {
            int(i)
            for i, n in zip(ids_seen, counts, strict=True)
            if i and n >= 50 and not apartment.object_by_id(i).is_background
        }
        visible_total += len(visible)
        for det in detections.instances:
            assert det["label"] not in background
            assert 0.3 <= det["score"] <= 1.0
            source = detections.sources[det["id"]]
            if source == 0:
                spurious += 1
                continue
            assert source in visible
            detected += 1
            category = apartment.object_by_id(source).category
            if det["label"] != category:
                confused += 1
                assert det["label"] in CATEGORIES[category].confusions
    assert visible_total > 100
    assert 0.03 < 1 - detected / visible_total < 0.3  # missed
    assert 0.02 < confused / detected < 0.25
    assert spurious <= len(walk_views) // 4


def test_standard_masks_are_noisy_only_near_the_object_border(apartment, walk_views):
    model = DetectionModel(apartment, "standard")
    for index, (_pose, view) in enumerate(walk_views[:8]):
        detections = model.detect(view, index)
        if 0 in detections.sources.values():
            continue  # a spurious blob may cover anything
        for det_id, source in detections.sources.items():
            truth = view.instance_ids == source
            mask = detections.instance_ids == det_id
            halo = ndimage.binary_dilation(truth, iterations=3)
            assert not (mask & ~halo).any()  # never more than 2 px outside the object
            core = ndimage.binary_erosion(truth, iterations=3)
            if core.sum() >= 20:  # small objects' grown masks may bite into what they stand on
                assert mask[core].mean() > 0.8


def test_standard_depth_noise_grows_with_distance(apartment, walk_views):
    model = DetectionModel(apartment, "standard")
    near_err, far_err = [], []
    for index, (_pose, view) in enumerate(walk_views):
        noisy = model.detect(view, index).depth_m
        z = view.depth_m
        assert np.array_equal(noisy > 0, z > 0)
        near_err.append((noisy - z)[(z > 0.5) & (z < 1.5)])
        far_err.append((noisy - z)[z > 3.5])
    assert np.std(np.concatenate(far_err)) > 2 * np.std(np.concatenate(near_err)) > 0


# --- the synthetic source -----------------------------------------------------------------


def test_synthetic_source_renders_every_nth_frame_deterministically():
    source = SyntheticSource("living_room", n_frames=30, camera=SMALL_CAMERA, seed=2)
    frames = list(source.frames(every=10))
    assert len(source) == 30 and [f.index for f in frames] == [0, 10, 20]
    assert [f.t for f in frames] == pytest.approx([0.0, 10 / 30, 20 / 30])
    again = SyntheticSource("living_room", n_frames=30, camera=SMALL_CAMERA, seed=2).frame(10)
    assert np.array_equal(frames[1].view.rgb, again.view.rgb)
    assert frames[1].detections.instances == again.detections.instances
    assert np.array_equal(frames[1].pose, again.pose) and frames[1].camera == SMALL_CAMERA
    assert frames[1].view.rgb.shape == (120, 160, 3)
    with pytest.raises(ValueError, match="noise profile"):
        SyntheticSource("living_room", n_frames=5, noise="wild")

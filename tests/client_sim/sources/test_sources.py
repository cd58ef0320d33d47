"""Frame sources: the 7-Scenes, Replica and TUM RGB-D loaders behind one interface.

Loaders are checked two ways: on tiny datasets the tests write with known values (always
run), and on the real samples in ../shared/data (skipped when absent), where the strongest
check is geometric: two frames back-projected with their poses must land on one surface.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from PIL import Image
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from app.mapping.geometry import backproject
from client_sim.sources import FrameSource, SourceFrame, make_source
from client_sim.sources.base import depth_at_rgb_size
from client_sim.sources.replica import ReplicaSource
from client_sim.sources.sevenscenes import SEVEN_SCENES_INTRINSICS, SevenScenesSource
from client_sim.sources.tum import FREIBURG1_INTRINSICS, TumSource, quaternion_to_matrix

pytestmark = pytest.mark.timeout(60)

REPO_ROOT = Path(__file__).resolve().parents[3]


def shared_data_dir() -> Path:
    """The shared sample data folder, or skip the test if this checkout has none."""
    env = os.environ.get("SEMANTICXR_SHARED_DATA")
    path = Path(env) if env else Path(__file__).resolve().parents[4] / "shared" / "data"
    if not path.is_dir():
        pytest.skip(f"shared sample data not found at {path} (set SEMANTICXR_SHARED_DATA)")
    return path


@pytest.fixture(scope="module")
def kitchen() -> SevenScenesSource:
    path = shared_data_dir() / "7scenes-redkitchen"
    if not path.is_dir():
        pytest.skip(f"7-Scenes sample not found at {path}")
    return SevenScenesSource(path)


@pytest.fixture(scope="module")
def office() -> ReplicaSource:
    path = shared_data_dir() / "replica-office0-sample" / "office0"
    if not path.is_dir():
        pytest.skip(f"Replica sample not found at {path}")
    return ReplicaSource(path)


# --- geometry helpers --------------------------------------------------------------------


def world_points(frame: SourceFrame, step_px: int, pose: np.ndarray | None = None) -> np.ndarray:
    """float32 [N, 3] world points of every `step_px`-th valid depth pixel of `frame`."""
    v, u = np.mgrid[0 : frame.depth_m.shape[0] : step_px, 0 : frame.depth_m.shape[1] : step_px]
    z_m = frame.depth_m[v, u]
    valid = z_m > 0
    pose = frame.pose if pose is None else pose
    return backproject(u[valid], v[valid], z_m[valid], frame.intrinsics, pose)


def median_gap_m(points: np.ndarray, reference: np.ndarray) -> float:
    """Median distance (m) from each point to its nearest neighbour in `reference`."""
    distances, _ = cKDTree(reference).query(points)
    return float(np.median(distances))


def assert_rigid(pose: np.ndarray) -> None:
    assert pose.shape == (4, 4) and pose.dtype == np.float64
    np.testing.assert_allclose(pose[3], [0, 0, 0, 1])
    np.testing.assert_allclose(pose[:3, :3].T @ pose[:3, :3], np.eye(3), atol=1e-3)
    assert np.linalg.det(pose[:3, :3]) == pytest.approx(1.0, abs=1e-3)


def plane_depth(
    pose: np.ndarray, intrinsics, size_px: tuple[int, int], normal, offset_m: float
) -> np.ndarray:
    """float64 [H, W] z-depth of the world plane normal . X = offset_m seen from `pose`."""
    fx, fy, cx, cy = intrinsics
    width_px, height_px = size_px
    v, u = np.mgrid[0:height_px, 0:width_px]
    rays_cam = np.stack([(u - cx) / fx, (v - cy) / fy, np.ones_like(u, float)], axis=-1)
    rays_world = rays_cam @ pose[:3, :3].T
    normal = np.asarray(normal, float)
    depth = (offset_m - normal @ pose[:3, 3]) / (rays_world @ normal)
    return np.where(depth > 0, depth, 0.0)


def look_pose(yaw_rad: float, position) -> np.ndarray:
    """Camera-to-world pose turned `yaw_rad` about the camera's y (down) axis."""
    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_euler("y", yaw_rad).as_matrix()
    pose[:3, 3] = position
    return pose


def write_uint16_png(path: Path, values: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(values.astype(np.uint16)).save(path)


def write_rgb(path: Path, size_px: tuple[int, int], seed: int) -> np.ndarray:
    """A random RGB image saved losslessly as PNG (or as JPEG if the suffix says so)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    rgb = np.random.default_rng(seed).integers(0, 256, (size_px[1], size_px[0], 3), np.uint8)
    Image.fromarray(rgb).save(path)
    return rgb


# --- tiny datasets written by the tests -------------------------------------------------

SMALL_SIZE_PX = (80, 60)
SMALL_INTRINSICS = (70.0, 70.0, 39.5, 29.5)
WALL_NORMAL, WALL_OFFSET_M = (0.0, 0.0, 1.0), 2.5  # the world plane z = 2.5 m


def write_seven_scenes(folder: Path, n_frames: int = 3) -> list[np.ndarray]:
    """A 7-Scenes folder of `n_frames` frames looking at a wall; returns the poses."""
    poses = []
    for number in range(n_frames):
        pose = look_pose(0.1 * number, (0.05 * number, 0.0, 0.0))
        stem = folder / f"frame-{number:06d}"
        write_rgb(Path(f"{stem}.color.png"), SMALL_SIZE_PX, number)
        depth_mm = np.round(
            plane_depth(pose, SMALL_INTRINSICS, SMALL_SIZE_PX, WALL_NORMAL, WALL_OFFSET_M) * 1000
        )
        depth_mm[0, :] = 65535  # the dataset's "no reading"
        write_uint16_png(Path(f"{stem}.depth.png"), depth_mm)
        np.savetxt(f"{stem}.pose.txt", pose)
        poses.append(pose)
    k = np.array([[70.0, 0, 39.5], [0, 70.0, 29.5], [0, 0, 1]])
    np.savetxt(folder / "camera-intrinsics.txt", k)
    return poses


def write_replica(scene: Path, n_frames: int = 3, cam_params_in_parent: bool = True) -> list:
    """A NICE-SLAM-layout Replica scene looking at a wall; returns the poses."""
    poses = [look_pose(-0.05 * i, (0.0, 0.02 * i, 0.3)) for i in range(n_frames + 2)]
    for number in range(n_frames):
        write_rgb(scene / "results" / f"frame{number:06d}.jpg", SMALL_SIZE_PX, number)
        depth_m = plane_depth(poses[number], SMALL_INTRINSICS, SMALL_SIZE_PX, WALL_NORMAL, 2.5)
        write_uint16_png(scene / "results" / f"depth{number:06d}.png", np.round(depth_m * 6553.5))
    # The trajectory has more lines than frames present, as in a partial copy of a scene.
    (scene / "traj.txt").write_text(
        "".join(" ".join(f"{x:.17g}" for x in p.ravel()) + "\n" for p in poses)
    )
    fx, fy, cx, cy = SMALL_INTRINSICS
    camera = {"w": 80, "h": 60, "fx": fx, "fy": fy, "cx": cx, "cy": cy, "scale": 6553.5}
    cam_dir = scene.parent if cam_params_in_parent else scene
    (cam_dir / "cam_params.json").write_text(json.dumps({"camera": camera}))
    return poses[:n_frames]


# Expected frames (rgb, depth, pose): (100.000, 100.005, 99.995), (100.033, 100.048, 100.04),
# (100.133, 100.139, 100.13). 100.066 is dropped: its only depth within 20 ms, 100.048, is
# closer to 100.033 and pairs are one-to-one. 100.100 is dropped: no pose within 20 ms.
# Depth 100.300 matches nothing. The depth list is deliberately out of order.
TUM_RGB_TIMES = [100.000, 100.033, 100.066, 100.100, 100.133]
TUM_DEPTH_TIMES = [100.005, 100.048, 100.300, 100.098, 100.139]
TUM_POSE_TIMES = [99.995, 100.02, 100.04, 100.07, 100.13]


def tum_depth_m(timestamp_s: float) -> float:
    return 1.0 + (timestamp_s - 100.0)


def write_tum(folder: Path, depth_size_px: tuple[int, int] = SMALL_SIZE_PX) -> dict:
    """A TUM folder with known associations; returns {rgb time: (pose, rgb)} of the kept."""
    folder.mkdir(parents=True, exist_ok=True)
    rgb_lines, depth_lines, pose_lines = ["# color images", "# timestamp filename"], [], []
    poses = {}
    for i, t in enumerate(TUM_POSE_TIMES):
        rotation = Rotation.from_euler("xyz", [0.1 * i, -0.2 + 0.05 * i, 0.3])
        qx, qy, qz, qw = rotation.as_quat()  # scipy is scalar-last, like TUM
        position = (0.1 * i, -0.05 * i, 0.02 * i)
        pose_lines.append(f"{t:.4f} " + " ".join(f"{x:.7f}" for x in (*position, qx, qy, qz, qw)))
        pose = np.eye(4)
        pose[:3, :3], pose[:3, 3] = rotation.as_matrix(), position
        poses[t] = pose
    rgbs = {}
    for i, t in enumerate(TUM_RGB_TIMES):
        name = f"rgb/{t:.6f}.png"
        rgbs[t] = write_rgb(folder / name, SMALL_SIZE_PX, i)
        rgb_lines.append(f"{t:.6f} {name}")
    for t in TUM_DEPTH_TIMES:
        name = f"depth/{t:.6f}.png"
        # depth = 1 m + 1 mm per ms of timestamp, so a test can tell which file was paired
        depth_m = tum_depth_m(t)
        write_uint16_png(folder / name, np.full(depth_size_px[::-1], round(depth_m * 5000)))
        depth_lines.append(f"{t:.6f} {name}")
    for name, lines in (("rgb.txt", rgb_lines), ("depth.txt", depth_lines)):
        (folder / name).write_text("\n".join(lines) + "\n")
    (folder / "groundtruth.txt").write_text(
        "# timestamp tx ty tz qx qy qz qw\n" + "\n".join(pose_lines)
    )
    return {"rgb": rgbs, "poses": poses}


# --- the interface ------------------------------------------------------------------------


class CountingSource(FrameSource):
    """Five blank frames: exercises the base class alone."""

    name = "counting"

    def __len__(self) -> int:
        return 5

    def frame(self, index: int) -> SourceFrame:
        index = self._check_index(index)
        return SourceFrame(
            index=index,
            t=index / 10,
            rgb=np.zeros((2, 2, 3), np.uint8),
            depth_m=np.zeros((2, 2), np.float32),
            pose=np.eye(4),
            intrinsics=(1.0, 1.0, 0.5, 0.5),
        )


def test_frames_steps_through_the_source_and_stops_at_the_limit():
    source = CountingSource()
    assert [f.index for f in source.frames()] == [0, 1, 2, 3, 4]
    assert [f.index for f in source.frames(every=2)] == [0, 2, 4]
    assert [f.index for f in source.frames(every=2, limit=2)] == [0, 2]
    assert list(source.frames(limit=0)) == []
    with pytest.raises(ValueError, match="every"):
        list(source.frames(every=0))


def test_frame_index_outside_the_source_is_an_index_error():
    source = CountingSource()
    for bad_index in (5, -1):
        with pytest.raises(IndexError, match="out of range"):
            source.frame(bad_index)


def test_depth_at_another_resolution_is_resized_to_rgb_size_by_nearest_neighbour():
    depth_m = np.array([[1.0, 2.0], [3.0, 0.0]], np.float32)
    resized = depth_at_rgb_size(depth_m, (4, 6, 3))
    assert resized.shape == (4, 6) and resized.dtype == np.float32
    assert set(np.unique(resized)) == {0.0, 1.0, 2.0, 3.0}  # no blended depths
    assert resized[0, 0] == 1.0 and resized[3, 5] == 0.0


# --- 7-Scenes ---------------------------------------------------------------------------


def test_seven_scenes_depth_is_millimetres_with_65535_invalid(tmp_path):
    poses = write_seven_scenes(tmp_path)
    source = SevenScenesSource(tmp_path)
    frame = source.frame(1)
    assert len(source) == 3 and frame.t == pytest.approx(1 / 30)
    assert frame.rgb.shape == (60, 80, 3) and frame.depth_m.shape == (60, 80)
    assert np.all(frame.depth_m[0] == 0.0)
    raw = np.asarray(Image.open(tmp_path / "frame-000001.depth.png"))
    np.testing.assert_allclose(frame.depth_m[1:], raw[1:] / 1000.0, rtol=1e-6)
    np.testing.assert_allclose(frame.pose, poses[1])
    assert frame.intrinsics == SMALL_INTRINSICS
    assert frame.instance_ids is None and frame.instances is None


def test_seven_scenes_frames_back_project_onto_the_wall_they_saw(tmp_path):
    write_seven_scenes(tmp_path)
    for frame in SevenScenesSource(tmp_path).frames():
        points = world_points(frame, step_px=3)
        # 1 mm depth quantisation at 2.5 m.
        assert np.abs(points[:, 2] - WALL_OFFSET_M).max() < 2e-3


def test_seven_scenes_intrinsics_default_and_override(tmp_path):
    write_seven_scenes(tmp_path)
    (tmp_path / "camera-intrinsics.txt").unlink()
    assert SevenScenesSource(tmp_path).intrinsics == SEVEN_SCENES_INTRINSICS
    override = (500.0, 501.0, 300.0, 200.0)
    assert SevenScenesSource(tmp_path, intrinsics=override).frame(0).intrinsics == override


def test_seven_scenes_frames_in_a_data_subfolder_are_found(tmp_path):
    write_seven_scenes(tmp_path / "data")
    assert len(SevenScenesSource(tmp_path)) == 3


def test_seven_scenes_missing_pose_names_the_file(tmp_path):
    write_seven_scenes(tmp_path)
    (tmp_path / "frame-000002.pose.txt").unlink()
    with pytest.raises(FileNotFoundError, match="frame-000002.pose.txt"):
        SevenScenesSource(tmp_path)


def test_seven_scenes_malformed_pose_names_the_file(tmp_path):
    write_seven_scenes(tmp_path)
    (tmp_path / "frame-000001.pose.txt").write_text("1 0 0 0\n0 1 0 0\n0 0 1 0\n")
    with pytest.raises(ValueError, match=r"frame-000001\.pose\.txt.*16 numbers"):
        SevenScenesSource(tmp_path).frame(1)
    (tmp_path / "frame-000001.pose.txt").write_text("2 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n")
    with pytest.raises(ValueError, match=r"frame-000001\.pose\.txt.*orthonormal"):
        SevenScenesSource(tmp_path).frame(1)


def test_seven_scenes_empty_folder_says_what_it_looked_for(tmp_path):
    with pytest.raises(FileNotFoundError, match=r"frame-XXXXXX\.color\.jpg"):
        SevenScenesSource(tmp_path)


def test_kitchen_sample_has_300_frames_of_640x480(kitchen):
    assert len(kitchen) == 300
    frame = kitchen.frame(299)
    assert frame.index == 299 and frame.t == pytest.approx(299 / 30)
    assert frame.rgb.shape == (480, 640, 3) and frame.rgb.dtype == np.uint8
    assert frame.depth_m.shape == (480, 640) and frame.depth_m.dtype == np.float32
    assert frame.intrinsics == (585.0, 585.0, 320.0, 240.0)


def test_kitchen_depth_is_metric_and_poses_are_rigid(kitchen):
    for frame in kitchen.frames(every=30):
        valid = frame.depth_m[frame.depth_m > 0]
        assert valid.size > 0.5 * frame.depth_m.size
        assert valid.min() >= 0.3 and valid.max() <= 5.0
        assert 1.0 <= np.median(valid) <= 3.0
        assert_rigid(frame.pose)


@pytest.mark.parametrize("first", [0, 100, 200, 298])
def test_consecutive_kitchen_frames_fuse_into_one_surface(kitchen, first):
    cloud_a = world_points(kitchen.frame(first), step_px=4)
    cloud_b = world_points(kitchen.frame(first + 1), step_px=4)
    assert median_gap_m(cloud_a, cloud_b) < 0.03


def test_kitchen_poses_explain_the_motion_between_distant_frames(kitchen):
    # Consecutive frames barely move; 20-30 frames apart the camera has moved ~20 cm, so
    # frames line up only if the poses are applied the right way round.
    for first, second in [(100, 120), (200, 230)]:
        frame_a, frame_b = kitchen.frame(first), kitchen.frame(second)
        cloud_a = world_points(frame_a, step_px=4)
        aligned = median_gap_m(cloud_a, world_points(frame_b, step_px=4))
        ignoring_motion = median_gap_m(cloud_a, world_points(frame_b, 4, pose=frame_a.pose))
        assert aligned < 0.03
        assert ignoring_motion > 3 * aligned


# --- Replica ----------------------------------------------------------------------------


def test_replica_depth_scale_and_poses_come_from_cam_params_and_traj(tmp_path):
    scene = tmp_path / "room0"
    poses = write_replica(scene)
    source = ReplicaSource(scene)
    assert len(source) == 3 and source.cam_params_path == tmp_path / "cam_params.json"
    for frame, pose in zip(source.frames(), poses, strict=True):
        np.testing.assert_allclose(frame.pose, pose)
        assert frame.intrinsics == SMALL_INTRINSICS
        points = world_points(frame, step_px=3)
        assert np.abs(points[:, 2] - 2.5).max() < 1e-3  # 1 / 6553.5 m quantisation


def test_replica_cam_params_in_the_scene_folder_wins(tmp_path):
    scene = tmp_path / "room0"
    write_replica(scene, cam_params_in_parent=False)
    (tmp_path / "cam_params.json").write_text("not json: must not be read")
    assert ReplicaSource(scene).cam_params_path == scene / "cam_params.json"


def test_replica_missing_files_are_named(tmp_path):
    scene = tmp_path / "room0"
    write_replica(scene)
    (scene / "results" / "depth000001.png").unlink()
    with pytest.raises(FileNotFoundError, match="depth000001.png"):
        ReplicaSource(scene)
    (tmp_path / "cam_params.json").unlink()
    with pytest.raises(FileNotFoundError, match="cam_params.json"):
        ReplicaSource(scene)


def test_replica_bad_trajectory_line_is_named(tmp_path):
    scene = tmp_path / "room0"
    write_replica(scene)
    lines = (scene / "traj.txt").read_text().splitlines()
    lines[1] = " ".join(lines[1].split()[:15])
    (scene / "traj.txt").write_text("\n".join(lines))
    with pytest.raises(ValueError, match=r"traj\.txt:2: expected 16 numbers"):
        ReplicaSource(scene)


def test_replica_trajectory_shorter_than_the_frames_is_refused(tmp_path):
    scene = tmp_path / "room0"
    write_replica(scene)
    lines = (scene / "traj.txt").read_text().splitlines()
    (scene / "traj.txt").write_text("\n".join(lines[:2]))
    with pytest.raises(ValueError, match="traj.txt: has 2 poses"):
        ReplicaSource(scene)


def test_office_sample_frames_match_cam_params(office):
    assert len(office) == 4
    assert office.intrinsics == (600.0, 600.0, 599.5, 339.5)
    frame = office.frame(0)
    assert frame.rgb.shape == (680, 1200, 3) and frame.depth_m.shape == (680, 1200)
    valid = frame.depth_m[frame.depth_m > 0]
    assert valid.min() >= 0.1 and valid.max() <= 10.0
    assert 1.0 <= np.median(valid) <= 3.0
    assert_rigid(frame.pose)


@pytest.mark.parametrize("first", [0, 1, 2])
def test_consecutive_office_frames_fuse_into_one_surface(office, first):
    cloud_a = world_points(office.frame(first), step_px=6)
    cloud_b = world_points(office.frame(first + 1), step_px=6)
    assert median_gap_m(cloud_a, cloud_b) < 0.03


def test_office_frames_lie_on_the_published_mesh(office):
    # The strongest check of the camera convention: the scene's own mesh. With the camera's
    # y and z flipped (OpenGL convention), the median distance is ~0.6 m.
    import open3d as o3d

    mesh_path = office.root.parent / "office0_mesh.ply"
    if not mesh_path.is_file():
        pytest.skip(f"Replica mesh not found at {mesh_path}")
    mesh = o3d.t.geometry.TriangleMesh.from_legacy(o3d.io.read_triangle_mesh(str(mesh_path)))
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(mesh)
    for frame in office.frames(every=3):
        points = o3d.core.Tensor(world_points(frame, step_px=8))
        assert np.median(scene.compute_distance(points).numpy()) < 0.01


# --- TUM RGB-D --------------------------------------------------------------------------


def test_tum_associates_rgb_depth_and_pose_within_20_ms(tmp_path):
    write_tum(tmp_path)
    source = TumSource(tmp_path)
    np.testing.assert_allclose(source.timestamps_s, [100.000, 100.033, 100.133])
    np.testing.assert_allclose(source.depth_timestamps_s, [100.005, 100.048, 100.139])
    assert [f.t for f in source.frames()] == pytest.approx([0.0, 0.033, 0.133])


def test_tum_poses_and_depths_are_the_ones_written(tmp_path):
    written = write_tum(tmp_path)
    source = TumSource(tmp_path)
    expected = [(100.000, 99.995, 100.005), (100.033, 100.04, 100.048), (100.133, 100.13, 100.139)]
    for frame, (rgb_t, pose_t, depth_t) in zip(source.frames(), expected, strict=True):
        np.testing.assert_allclose(frame.pose, written["poses"][pose_t], atol=1e-6)
        np.testing.assert_array_equal(frame.rgb, written["rgb"][rgb_t])
        np.testing.assert_allclose(frame.depth_m, tum_depth_m(depth_t), atol=2e-4)
        assert frame.intrinsics == FREIBURG1_INTRINSICS


def test_tum_depth_at_lower_resolution_comes_out_at_rgb_size(tmp_path):
    write_tum(tmp_path, depth_size_px=(40, 30))
    frame = TumSource(tmp_path, intrinsics=SMALL_INTRINSICS).frame(0)
    assert frame.depth_m.shape == frame.rgb.shape[:2]
    assert frame.intrinsics == SMALL_INTRINSICS


def test_tum_bad_groundtruth_line_is_named(tmp_path):
    write_tum(tmp_path)
    with (tmp_path / "groundtruth.txt").open("a") as out:
        out.write("\n101.0 1 2 3 0 0 0\n")
    with pytest.raises(ValueError, match=r"groundtruth\.txt:7: expected"):
        TumSource(tmp_path)


def test_tum_missing_listed_image_is_named(tmp_path):
    write_tum(tmp_path)
    (tmp_path / "depth" / "100.048000.png").unlink()
    with pytest.raises(FileNotFoundError, match="100.048000.png"):
        TumSource(tmp_path)


def test_tum_missing_list_file_is_named(tmp_path):
    write_tum(tmp_path)
    (tmp_path / "depth.txt").unlink()
    with pytest.raises(FileNotFoundError, match="depth.txt"):
        TumSource(tmp_path)


@settings(max_examples=50, deadline=None)
@given(
    st.lists(st.floats(-1.0, 1.0), min_size=4, max_size=4).filter(lambda q: np.linalg.norm(q) > 0.1)
)
def test_tum_quaternions_turn_into_the_same_rotation_as_scipys(quaternion):
    qx, qy, qz, qw = np.asarray(quaternion) / np.linalg.norm(quaternion)
    expected = Rotation.from_quat([qx, qy, qz, qw]).as_matrix()
    np.testing.assert_allclose(quaternion_to_matrix(qx, qy, qz, qw, "test"), expected, atol=1e-9)


# --- labels -----------------------------------------------------------------------------


def write_labels(labels_dir: Path, stem: str, size_px: tuple[int, int]) -> np.ndarray:
    ids = np.zeros(size_px[::-1], np.uint16)
    ids[10:20, 10:30] = 7
    ids[30:40, 40:60] = 300
    write_uint16_png(labels_dir / f"{stem}.png", ids)
    instances = [
        {"id": 7, "label": "mug", "score": 0.9},
        {"id": 300, "label": "kettle", "score": 0.55, "extra": "ignored"},
    ]
    (labels_dir / f"{stem}.json").write_text(json.dumps(instances))
    return ids


def test_labels_folder_attaches_detections_to_its_frames_only(tmp_path):
    write_tum(tmp_path / "seq")
    source = TumSource(tmp_path / "seq", labels_dir=tmp_path / "labels")
    ids = write_labels(tmp_path / "labels", source.stem(1), SMALL_SIZE_PX)
    with_labels, without = source.frame(1), source.frame(0)
    np.testing.assert_array_equal(with_labels.instance_ids, ids)
    assert with_labels.instance_ids.dtype == np.uint16
    assert with_labels.instances == [
        {"id": 7, "label": "mug", "score": 0.9},
        {"id": 300, "label": "kettle", "score": 0.55},
    ]
    assert without.instance_ids is None and without.instances is None


def test_labels_use_each_datasets_frame_stem(tmp_path):
    write_seven_scenes(tmp_path / "seq")
    write_labels(tmp_path / "labels", "frame-000002", SMALL_SIZE_PX)
    frame = SevenScenesSource(tmp_path / "seq", labels_dir=tmp_path / "labels").frame(2)
    assert [inst["label"] for inst in frame.instances] == ["mug", "kettle"]
    write_replica(tmp_path / "replica" / "room0")
    write_labels(tmp_path / "replica_labels", "frame000000", SMALL_SIZE_PX)
    frame = ReplicaSource(tmp_path / "replica" / "room0", labels_dir=tmp_path / "replica_labels")
    assert frame.frame(0).instance_ids is not None


def test_labels_half_pair_or_wrong_size_is_an_error(tmp_path):
    write_seven_scenes(tmp_path / "seq")
    labels = tmp_path / "labels"
    write_labels(labels, "frame-000000", SMALL_SIZE_PX)
    (labels / "frame-000000.json").unlink()
    source = SevenScenesSource(tmp_path / "seq", labels_dir=labels)
    with pytest.raises(FileNotFoundError, match=r"frame-000000\.json"):
        source.frame(0)
    write_labels(labels, "frame-000001", (40, 30))
    with pytest.raises(ValueError, match="expected the RGB size"):
        source.frame(1)


def test_labels_with_a_bad_instance_name_the_entry(tmp_path):
    write_seven_scenes(tmp_path / "seq")
    labels = tmp_path / "labels"
    write_labels(labels, "frame-000000", SMALL_SIZE_PX)
    (labels / "frame-000000.json").write_text(json.dumps([{"id": 0, "label": "x", "score": 1}]))
    with pytest.raises(ValueError, match=r"frame-000000\.json\[0\]: id"):
        SevenScenesSource(tmp_path / "seq", labels_dir=labels).frame(0)


# --- the factory ------------------------------------------------------------------------


def test_make_source_builds_each_kind_from_its_spec(tmp_path):
    write_tum(tmp_path / "tum")
    write_seven_scenes(tmp_path / "7s")
    write_replica(tmp_path / "replica" / "room0")
    assert isinstance(make_source(f"tum:{tmp_path / 'tum'}", max_dt_s=0.02), TumSource)
    assert isinstance(make_source(f"7scenes:{tmp_path / '7s'}"), SevenScenesSource)
    assert isinstance(make_source(f"replica:{tmp_path / 'replica' / 'room0'}"), ReplicaSource)
    for bad_spec in ("kinect:/tmp", "tum", "tum:"):
        with pytest.raises(ValueError, match="source"):
            make_source(bad_spec)


def test_make_source_for_a_dataset_does_not_import_the_synthetic_world(tmp_path):
    write_tum(tmp_path / "tum")
    spec = f"tum:{tmp_path / 'tum'}"
    code = (
        "import sys\n"
        "from client_sim.sources import make_source\n"
        f"make_source({spec!r}).frame(0)\n"
        "assert 'client_sim.sources.synthetic' not in sys.modules\n"
        "assert 'world.scene' not in sys.modules\n"
    )
    subprocess.run([sys.executable, "-c", code], cwd=REPO_ROOT, check=True, timeout=60)

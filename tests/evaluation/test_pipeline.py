"""The mapping engine on the synthetic world: lifting against the renderer, both organisations
on a small scene, and `semanticxr eval` end to end."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import open3d as o3d
import pytest

from app.config import Knobs
from app.mapping import geometry as geo
from app.mapping.engine import MappingEngine, make_perception
from client_sim.encoder import downsample_depth
from client_sim.sources.synthetic import SyntheticSource
from evaluation.walk import EvalConfig, run_eval
from world.render import default_camera

SMALL = default_camera(160, 120)


@pytest.fixture(scope="module")
def living_room():
    return SyntheticSource("living_room", n_frames=120, camera=SMALL, noise="none")


def distance_to_scene(scene, points: np.ndarray) -> np.ndarray:
    raycasting = o3d.t.geometry.RaycastingScene()
    for obj in scene.objects:
        raycasting.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(obj.mesh))
    query = o3d.core.Tensor(points.astype(np.float32))
    return raycasting.compute_distance(query).numpy()


@pytest.mark.parametrize("ratio", [1, 2, 5])
def test_lifted_points_lie_on_the_rendered_surfaces(living_room, ratio):
    frame = living_room.frame(40)
    depth = downsample_depth(frame.view.depth_m, ratio)
    ids = [int(i) for i in np.unique(frame.view.instance_ids) if i]
    lifted = geo.lift_instances_batched(
        frame.view.instance_ids, ids, depth, frame.intrinsics, frame.pose, 10.0
    )
    points = np.concatenate(list(lifted.values()))
    assert len(points) > 100
    off = distance_to_scene(living_room.scene, points)
    near = np.linalg.norm(points - frame.pose[:3, 3], axis=1) < geo.SMOOTH_FROM_M
    assert near.sum() > 100 and (~near).sum() > 100
    # exact renderer depth: every point lifted as measured is on a mesh surface (to float
    # precision); a far one is read at its local plane, which leaves a flat face as it is and
    # rounds a corner or an edge by millimetres, up to 2 cm where ÷5 pixels span the corner
    assert np.percentile(off[near], 99) < 2e-3
    assert np.percentile(off[~near], 90) < 5e-3
    assert np.percentile(off[~near], 99) < 2.5e-2
    for iid, pts in lifted.items():
        box = living_room.scene.object_by_id(iid).bbox
        slack = np.where(
            np.linalg.norm(pts - frame.pose[:3, 3], axis=1) < geo.SMOOTH_FROM_M, 0.01, 0.025
        )
        assert np.all(pts >= box[:3] - slack[:, None]) and np.all(pts <= box[3:] + slack[:, None])


@pytest.mark.slow
def test_both_organisations_build_maps_of_equal_quality_on_a_small_scene(encoder):
    # 160x120 with depth ÷2 keeps this fast; the bbox-area knob scales with the image area
    knobs = Knobs(min_mapping_bbox_area=125, depth_downsampling_ratio=2)
    cfg = EvalConfig(
        scene="living_room", frames=300, width=160, height=120, noise="standard", knobs=knobs
    )
    result = run_eval(
        cfg, encoder, progress=lambda _: None, variants={"again": ("semanticxr", knobs)}
    )
    sx, bl = result["modes"]["semanticxr"], result["modes"]["baseline"]
    # engines mapped side by side stay independent: the same knobs give the same map
    again = result["variants"]["again"]
    assert (again["F_mIoU"], again["objects"]) == (sx["F_mIoU"], sx["objects"])
    stages = {"decode", "perception", "lift", "associate", "merge", "publish", "update"}
    assert set(sx["stages_ms"]) == set(bl["stages_ms"]) == stages
    assert sx["objects"] >= 15 and bl["objects"] >= 15
    assert sx["F_mIoU"] > 35 and bl["F_mIoU"] > 35
    # semanticxr may map more than the baseline (depth patches), never much less
    assert sx["F_mIoU"] > bl["F_mIoU"] - 3.0
    assert sx["mAcc"] > bl["mAcc"] - 6.0


def test_a_variant_named_like_a_mode_is_refused_before_any_work(encoder):
    with pytest.raises(ValueError, match="baseline"):
        run_eval(
            EvalConfig(),
            encoder,
            progress=lambda _: None,
            variants={"baseline": ("baseline", Knobs())},
        )


def test_a_query_for_a_category_returns_an_object_of_that_category(living_room, encoder):
    engine = MappingEngine(encoder, Knobs(min_mapping_bbox_area=100), backend=make_perception())
    for frame in living_room.frames(every=3):
        from app.protocol import FrameInput

        engine.integrate(
            FrameInput(
                seq=frame.index,
                t=frame.t,
                pose=frame.pose,
                intrinsics=frame.intrinsics,
                rgb_size=(SMALL.width, SMALL.height),
                depth_m=downsample_depth(frame.depth_m, 2),
                instance_ids=frame.instance_ids,
                instances=frame.instances,
            )
        )
    mapped = {o.label for o in engine.confirmed_objects()}
    assert {"sofa", "bookshelf"} <= mapped
    for category in ("sofa", "bookshelf"):
        hit = engine.query(category, k=1)[0].object
        centre = hit.centroid
        truth = [o for o in living_room.scene.objects if o.category == category]
        assert any(
            np.all(centre >= o.bbox[:3] - 0.1) and np.all(centre <= o.bbox[3:] + 0.1) for o in truth
        )


@pytest.mark.slow
def test_semanticxr_eval_writes_the_documented_json(tmp_path):
    out = tmp_path / "eval.json"
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "app.cli",
            "eval",
            "--scene",
            "kitchen",
            "--frames",
            "60",
            "--width",
            "160",
            "--height",
            "120",
            "--min-mapping-bbox-area",
            "150",
            "--json",
            str(out),
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "keyframes" in proc.stderr  # progress is shown
    doc = json.loads(out.read_text())
    assert {"scene", "frames", "keyframes", "noise", "modes", "speedup_p50"} <= doc.keys()
    for mode in ("semanticxr", "baseline"):
        m = doc["modes"][mode]
        assert {"mAcc", "F_mIoU", "objects", "latency_ms", "query_top1"} <= m.keys()
        assert {"p50", "p95", "mean"} <= m["latency_ms"].keys()
        assert 0 <= m["mAcc"] <= 100 and 0 <= m["F_mIoU"] <= 100


def test_eval_refuses_a_bad_knob_with_a_clear_message():
    proc = subprocess.run(
        [sys.executable, "-m", "app.cli", "eval", "--min-observations", "zero"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 2 and "min_observations" in proc.stderr

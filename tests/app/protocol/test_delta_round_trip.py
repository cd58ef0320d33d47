"""One delta round trip without a server: the engine maps a few analytic frames, publish
builds the update, msgpack carries it, and the device's local map and the viewer's scene
both end up holding the engine's confirmed objects."""

from __future__ import annotations

import msgpack
import numpy as np
import pytest
from analytic_world import Rect, render_rects

from app.config import Knobs
from app.mapping.engine import MappingEngine, make_perception
from app.mapping.publish import update_message
from client_sim.local_map import LocalMap
from viewer.scene import SceneModel

CHAIR = Rect(1, "chair", -0.6, -0.3, -0.1, 0.3, 2.0)
TABLE = Rect(2, "table", 0.1, -0.3, 0.7, 0.3, 2.2)
LAMP = Rect(3, "lamp", 0.8, -0.6, 1.0, 0.2, 2.6)


class _NoSink:
    """A scene sink that draws nothing (the nodes are SceneModel's own tests' business)."""

    def __getattr__(self, name):
        return lambda *args, **kwargs: None


def _wire(message: dict) -> dict:
    return msgpack.unpackb(msgpack.packb(message, use_bin_type=True), raw=False)


@pytest.mark.parametrize("mode", ["semanticxr", "baseline"])
def test_engine_updates_give_the_local_map_and_the_viewer_the_confirmed_map(encoder, mode):
    knobs = Knobs(min_mapping_bbox_area=100, min_observations=2, max_object_points_client=50)
    engine = MappingEngine(encoder, knobs, mode=mode, backend=make_perception(mode=mode))
    local = LocalMap(dim=encoder.dim, max_points_per_object=knobs.max_object_points_client)
    scene = SceneModel(_NoSink())
    since = 0
    for step, rects in enumerate([[CHAIR, TABLE], [CHAIR, TABLE, LAMP], [CHAIR, LAMP], [LAMP]]):
        engine.integrate(render_rects(rects, cam_xy=(0.02 * step, 0.0), seq=step))
        message = _wire(update_message(engine, since))
        local.apply_delta(message)
        scene.apply_delta(message)
        since = message["seq"]

    confirmed = {o.id: o for o in engine.confirmed_objects()}
    assert {o.label for o in confirmed.values()} == {"chair", "table", "lamp"}
    assert local.snapshot() == {oid: (o.version, o.label) for oid, o in confirmed.items()}
    assert local.seq == scene.seq == engine.log.seq
    assert {oid: (v.version, v.label) for oid, v in scene.objects.items()} == local.snapshot()
    for oid, obj in confirmed.items():
        np.testing.assert_allclose(local.get(oid)["bbox"], obj.bbox, atol=1e-5)
        np.testing.assert_allclose(scene.objects[oid].bbox, obj.bbox, atol=1e-9)
        assert local.get(oid)["n_obs"] == scene.objects[oid].n_obs == obj.n_obs
        if mode == "semanticxr":
            assert len(scene.objects[oid].points) <= knobs.max_object_points_client

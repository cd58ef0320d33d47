"""The `models` backend as one Ray Serve deployment (app/cluster/serve_models.py), on the
test session's local Ray and the tiny random models: keyframes from many shards share
forward passes, and a backend on the deployment detects as the local one does.

The Serve application is deleted at the end of the module; Serve itself stays (other
modules share this Ray, and `local_ray` shuts it all down at the end of the session).
"""

from __future__ import annotations

import asyncio
import threading

import httpx
import numpy as np
import pytest
from analytic_world import Rect, render_rects

from app.server.settings import ServerSettings

pytestmark = [pytest.mark.cluster, pytest.mark.slow, pytest.mark.timeout(180)]

RESULT_TIMEOUT_S = 60.0
BATCH_WAIT_S = 0.5
"""Generous, so the threads' requests meet in a batch however the test machine schedules
them (a batch leaves as soon as it holds its most crops)."""
MAX_BATCH_CROPS = 32
"""The tiny models' max_objects (the default), the least the deployment allows."""


@pytest.fixture(scope="module")
def tiny_models_dir(tmp_path_factory) -> str:
    from app.perception.models.tiny import write_tiny_models

    return str(write_tiny_models(tmp_path_factory.mktemp("serve-models")))


@pytest.fixture(scope="module")
def local_models(tiny_models_dir):
    """The backend on models loaded in this process (before any remote one replaces it as
    this process's backend for the folder)."""
    from app.perception.models.backend import load_models_backend

    return load_models_backend(tiny_models_dir)


@pytest.fixture(scope="module")
def models_app(local_ray, tiny_models_dir, local_models) -> object:
    """The models deployment's name; deleted after the module."""
    from ray import serve

    from app.cluster.serve_models import start_models

    settings = ServerSettings(perception="models", models_dir=tiny_models_dir)
    name = start_models(
        settings, max_batch_crops=MAX_BATCH_CROPS, batch_wait_s=BATCH_WAIT_S, timeout_s=120
    )
    try:
        yield name
    finally:
        serve.delete(name)


def stats(name: str) -> dict[str, int]:
    from ray import serve

    return serve.get_app_handle(name).stats.remote().result(timeout_s=RESULT_TIMEOUT_S)


def crops_of(keyframe: int, n: int) -> list[np.ndarray]:
    rng = np.random.default_rng(keyframe)
    return [
        rng.integers(0, 256, rng.integers(8, 120, 2).tolist() + [3], np.uint8) for _ in range(n)
    ]


def test_keyframes_from_many_shards_share_forward_passes(models_app, local_models):
    from ray import serve

    shards, keyframes_each, crops_each = 4, 3, 8
    handle = serve.get_app_handle(models_app)
    before = stats(models_app)
    start = threading.Barrier(shards, timeout=RESULT_TIMEOUT_S)
    answers: dict[int, np.ndarray] = {}

    def shard(index: int) -> None:
        start.wait()
        for k in range(keyframes_each):
            keyframe = index * keyframes_each + k
            crops = crops_of(keyframe, crops_each)
            answers[keyframe] = handle.embed_crops.remote(crops).result(timeout_s=RESULT_TIMEOUT_S)

    threads = [threading.Thread(target=shard, args=(i,)) for i in range(shards)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(RESULT_TIMEOUT_S)
    assert len(answers) == shards * keyframes_each

    after = stats(models_app)
    requests = after["requests"] - before["requests"]
    passes = after["forward_passes"] - before["forward_passes"]
    assert requests == shards * keyframes_each
    assert after["crops"] - before["crops"] == requests * crops_each
    assert passes <= requests / 2, f"{requests} keyframes in {passes} forward passes"
    for keyframe, rows in answers.items():
        expected = local_models.embedder.embed_crops_batched(crops_of(keyframe, crops_each))
        np.testing.assert_allclose(rows, expected, atol=1e-5)


SCENE = [
    Rect(1, "chair", -0.6, -0.3, -0.1, 0.3, 2.0),
    Rect(2, "table", 0.1, -0.2, 0.7, 0.4, 2.6),
    Rect(3, "wall", -3.0, -3.0, 3.0, 3.0, 4.0),
]
KNOBS = {"keyframe_interval": 1, "min_observations": 1, "min_mapping_bbox_area": 16}


def textured_frame(seq: int = 0):
    frame = render_rects(SCENE, ratio=2, seq=seq)
    width, height = frame.rgb_size
    frame.rgb = np.random.default_rng(seq).integers(0, 256, (height, width, 3), np.uint8)
    frame.instance_ids, frame.instances = None, []
    return frame


@pytest.mark.parametrize("mode", ["semanticxr", "baseline"])
def test_a_backend_on_the_deployment_detects_a_frame_as_the_local_one_does(
    models_app, tiny_models_dir, local_models, mode
):
    from app.cluster.serve_models import use_models_service
    from app.perception import BackendOptions, make_backend

    remote_models = use_models_service(tiny_models_dir, models_app)
    assert make_backend("models", BackendOptions(models_dir=tiny_models_dir)) is remote_models
    frame = textured_frame()

    local = local_models.for_mode(mode).detect(frame, None)
    remote = remote_models.for_mode(mode).detect(frame, None)

    assert remote.detections, "threshold 0 (the tiny models' setting) keeps boxes"
    np.testing.assert_array_equal(remote.instance_image, local.instance_image)
    assert [(d.instance_id, d.label, d.bbox_px) for d in remote.detections] == [
        (d.instance_id, d.label, d.bbox_px) for d in local.detections
    ]
    np.testing.assert_allclose(
        [d.score for d in remote.detections], [d.score for d in local.detections], atol=1e-5
    )
    np.testing.assert_allclose(
        np.stack([d.embedding for d in remote.detections]),
        np.stack([d.embedding for d in local.detections]),
        atol=1e-5,
    )
    query = "the red chair by the window"
    np.testing.assert_allclose(
        remote_models.text_encoder.encode_query(query),
        local_models.text_encoder.encode_query(query),
        atol=1e-5,
    )


def test_a_map_shard_maps_keyframes_through_the_deployment(
    local_ray, pg_cluster, models_app, tiny_models_dir
):
    from devices import frame_message, stream_in_step

    from app.cluster.shards import NAMESPACE, _actor_class, shard_fields

    settings = ServerSettings(
        port=0,
        perception="models",
        models_dir=tiny_models_dir,
        store=pg_cluster.url(pg_cluster.create_database("models")),
        cluster="auto",
        models_service=models_app,
        log_level="warning",
    )
    name = "models-shard-test"  # not mapshard-N: the cluster fixture's shards may be running
    shard = (
        _actor_class().options(name=name, namespace=NAMESPACE).remote(name, shard_fields(settings))
    )
    try:
        url = local_ray.get(shard.address.remote(), timeout=RESULT_TIMEOUT_S)
        before = stats(models_app)
        created = httpx.post(
            f"{url}/v1/sessions", json={"mode": "semanticxr", "knobs": KNOBS}, timeout=30
        ).json()
        frames = []
        for seq in range(3):
            frame = frame_message(SCENE, seq, cam_xy=(0.02 * seq, 0.0))
            del frame["detections"]  # the models backend finds the objects
            frames.append(frame)
        stream = f"{url.replace('http', 'ws', 1)}/v1/sessions/{created['session_id']}/stream"
        replies = asyncio.run(stream_in_step(stream, frames))
    finally:
        local_ray.kill(shard)

    assert [r["type"] for r in replies] == ["ack"] * 3
    after = stats(models_app)
    assert after["requests"] - before["requests"] == 3, "each keyframe's crops, one request"


def test_starting_the_deployment_again_finds_the_running_one(models_app, tiny_models_dir):
    from app.cluster.serve_models import start_models

    before = stats(models_app)
    settings = ServerSettings(perception="models", models_dir=tiny_models_dir)
    assert start_models(settings, timeout_s=30) == models_app
    assert stats(models_app) == before, "the same replica, not a new one"


def test_a_missing_model_stops_the_deployment_with_its_fix(local_ray, tmp_path):
    from ray import serve

    from app.cluster.serve_models import ModelsDeploymentError, start_models

    settings = ServerSettings(
        perception="models",
        models_dir=str(tmp_path),
        cluster="auto",
        store="postgresql://semanticxr@127.0.0.1/unused",
        models_service="semanticxr-models-missing",
    )
    try:
        with pytest.raises(ModelsDeploymentError) as failed:
            start_models(settings, timeout_s=60)
    finally:
        serve.delete("semanticxr-models-missing")
    assert "semanticxr models tiny" in str(failed.value)


def test_only_a_cluster_with_the_models_backend_takes_a_models_service():
    from app.server.settings import SettingsError

    cluster = {"cluster": "auto", "store": "postgresql://semanticxr@127.0.0.1/unused"}
    with pytest.raises(SettingsError, match="models_service"):
        ServerSettings(perception="detections", models_service="semanticxr-models", **cluster)
    with pytest.raises(SettingsError, match="models_service"):
        ServerSettings(perception="models", models_service="semanticxr-models")
    ServerSettings(perception="detections,models", models_service="semanticxr-models", **cluster)

"""The `models` backend on tiny random models: the real loading and inference code, end to
end (plumbing, not quality: random weights detect and label nothing in particular)."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest
from analytic_world import Rect, render_rects

from app.perception import BackendOptions, make_backend
from app.perception.models import masks
from app.perception.models.backend import load_vocabulary
from app.perception.models.tiny import TINY_PREFIX
from app.perception.models.weights import CPU_PROFILE, MissingModelsError, resolve_models

pytestmark = pytest.mark.timeout(180)

SCENE = [
    Rect(1, "chair", -0.6, -0.3, -0.1, 0.3, 2.0),
    Rect(2, "table", 0.1, -0.2, 0.7, 0.4, 2.6),
    Rect(3, "wall", -3.0, -3.0, 3.0, 3.0, 4.0),
]


def textured_frame(seq: int = 0):
    """An analytic RGB-D keyframe (depth at half resolution) with a random texture."""
    frame = render_rects(SCENE, ratio=2, seq=seq)
    width, height = frame.rgb_size
    frame.rgb = np.random.default_rng(seq).integers(0, 256, (height, width, 3), np.uint8)
    frame.instance_ids, frame.instances = None, []
    return frame


def test_the_default_vocabulary_has_a_few_hundred_distinct_indoor_tags():
    tags = load_vocabulary()
    assert 200 <= len(tags) <= 1000
    assert len(set(tags)) == len(tags)
    assert {"chair", "table", "sofa", "refrigerator"} <= set(tags)


def test_tiny_models_detect_objects_with_masks_of_the_frames_shape(models_backend):
    frame = textured_frame()
    found = models_backend.detect(frame, None)

    width, height = frame.rgb_size
    assert found.instance_image.shape == (height, width)
    assert found.instance_image.dtype == np.uint16
    assert found.detections, "threshold 0 (the tiny models' setting) keeps boxes"
    vocabulary = set(models_backend.vocabulary)
    for det in found.detections:
        mask = found.mask(det)
        rows, cols = np.nonzero(mask)
        assert (cols.min(), rows.min(), cols.max() + 1, rows.max() + 1) == det.bbox_px
        assert det.label in vocabulary and 0 <= det.score <= 1


def test_embeddings_are_unit_rows_of_the_announced_dimension(models_backend):
    found = models_backend.detect(textured_frame(), None)
    encoder = models_backend.text_encoder
    embeddings = np.stack([d.embedding for d in found.detections])

    assert embeddings.dtype == np.float32
    assert embeddings.shape == (len(found.detections), encoder.dim)
    np.testing.assert_allclose(np.linalg.norm(embeddings, axis=1), 1.0, atol=1e-5)
    query = encoder.encode_query("the red chair by the window")
    assert query.shape == (encoder.dim,)
    np.testing.assert_allclose(np.linalg.norm(query), 1.0, atol=1e-5)
    assert encoder.model_id == TINY_PREFIX + CPU_PROFILE.embedder.folder


def test_one_batch_equals_one_by_one(models_backend):
    rng = np.random.default_rng(1)
    crops = [rng.integers(0, 256, (s, s, 3), np.uint8) for s in (12, 40, 64, 97, 150)]
    batched = models_backend.embed(crops, batched=True)
    one_by_one = models_backend.embed(crops, batched=False)
    np.testing.assert_allclose(batched, one_by_one, atol=1e-5)


def test_a_baseline_session_embeds_one_at_a_time_with_the_same_models(models_backend):
    baseline = models_backend.for_mode("baseline")
    assert not baseline.batched and models_backend.for_mode("semanticxr").batched
    assert baseline.embedder is models_backend.embedder
    frame = textured_frame(2)
    ours, theirs = models_backend.detect(frame, None), baseline.detect(frame, None)
    np.testing.assert_array_equal(ours.instance_image, theirs.instance_image)
    np.testing.assert_allclose(
        np.stack([d.embedding for d in ours.detections]),
        np.stack([d.embedding for d in theirs.detections]),
        atol=1e-5,
    )


def test_the_backend_is_loaded_once_per_process(models_backend, tiny_models_dir):
    again = make_backend("models", BackendOptions(models_dir=tiny_models_dir))
    assert again is models_backend


def test_a_depth_mode_mask_keeps_the_near_object_not_the_wall_behind():
    depth = np.full((40, 40), 3.0, np.float32)
    depth[5:35, 5:35] = 1.0  # the object fills most of the box
    depth[0, 0] = 0.0  # invalid depth is never in a mask
    mask = masks.depth_mode_mask(depth)
    assert mask.sum() == 30 * 30 and mask[5:35, 5:35].all()


def test_upsampled_depth_has_the_rgb_size():
    depth = np.arange(12, dtype=np.float32).reshape(3, 4)
    full = masks.upsample_depth(depth, (8, 6))
    assert full.shape == (6, 8) and full[5, 7] == depth[2, 3] and full[0, 1] == depth[0, 0]


def test_a_missing_model_names_the_folders_and_the_commands_that_fetch_them(tmp_path):
    with pytest.raises(MissingModelsError) as raised:
        resolve_models(CPU_PROFILE, str(tmp_path))
    message = str(raised.value)
    for spec in CPU_PROFILE.models:
        assert str(tmp_path / spec.folder) in message
        assert f"hf download {spec.hub_id} --local-dir {tmp_path / spec.folder}" in message
    assert f"semanticxr models tiny --out {tmp_path}" in message


def test_serve_exits_2_with_the_fix_when_a_model_is_missing(tmp_path):
    done = subprocess.run(
        [sys.executable, "-m", "app.cli", "serve", "--perception", "models"]
        + ["--models-dir", str(tmp_path), "--port", "0", "--data-dir", str(tmp_path / "data")],
        capture_output=True,
        text=True,
        timeout=60,
        env={**os.environ, "HF_HUB_OFFLINE": "1"},
    )
    assert done.returncode == 2
    assert str(tmp_path / CPU_PROFILE.detector.folder) in done.stderr
    assert "hf download" in done.stderr and "models tiny" in done.stderr

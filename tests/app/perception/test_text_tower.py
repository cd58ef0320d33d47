"""The device's text tower: CLIP's text tower alone, read from the same folder as the
server's CLIP, embeds texts as the server's does (so local queries rank as server queries)."""

import numpy as np

from app.perception.models.weights import CPU_PROFILE, text_towers_in

TEXTS = ["a chair", "where is the big red sofa", "kettle"]


def test_the_text_tower_alone_embeds_as_the_servers_clip(models_backend, tiny_models_dir):
    from app.perception.models.embedder import load_text_encoder

    (tower,) = text_towers_in(tiny_models_dir)
    assert tower.source.endswith(CPU_PROFILE.embedder.folder)
    encoder = load_text_encoder(tower.source, tower.local_only, tower.model_id)
    assert (encoder.model_id, encoder.dim) == (
        models_backend.text_encoder.model_id,
        models_backend.text_encoder.dim,
    )
    # text tower only: no vision weights in memory
    assert not any("vision" in name for name, _ in encoder._embedder.model.named_parameters())
    device_rows = encoder.encode(TEXTS)
    np.testing.assert_allclose(device_rows, models_backend.text_encoder.encode(TEXTS), atol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(device_rows, axis=1), 1.0, atol=1e-5)


def test_a_models_dir_without_clip_holds_no_text_tower(tmp_path):
    assert text_towers_in(str(tmp_path)) == []

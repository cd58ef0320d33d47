"""The tiny random models (`semanticxr models tiny`), written once per test session."""

import os

import pytest

os.environ.setdefault("HF_HUB_OFFLINE", "1")


@pytest.fixture(scope="session")
def tiny_models_dir(tmp_path_factory):
    from app.perception.models.tiny import write_tiny_models

    return str(write_tiny_models(tmp_path_factory.mktemp("models")))


@pytest.fixture(scope="session")
def models_backend(tiny_models_dir):
    from app.perception import BackendOptions, make_backend

    return make_backend("models", BackendOptions(models_dir=tiny_models_dir))

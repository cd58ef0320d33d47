"""The tiny random models (`semanticxr models tiny`) for the device's text tower, written
once per test session (as tests/app/perception/conftest.py does for the server's side)."""

import os

import pytest

os.environ.setdefault("HF_HUB_OFFLINE", "1")


@pytest.fixture(scope="session")
def tiny_models_dir(tmp_path_factory):
    from app.perception.models.tiny import write_tiny_models

    return str(write_tiny_models(tmp_path_factory.mktemp("models")))

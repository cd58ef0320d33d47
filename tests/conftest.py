"""Shared fixtures: the real text encoder, loaded once per test session."""

import os

import pytest

os.environ.setdefault("HF_HUB_OFFLINE", "1")


@pytest.fixture(scope="session")
def encoder():
    from app.semantics import get_text_encoder

    return get_text_encoder()

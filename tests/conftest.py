"""Shared pytest fixtures for carapost."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]


def shared_fixtures_dir() -> Path:
    """Folder of third-party fixture files (never committed into this repository).

    ``CARAPOST_FIXTURES`` overrides the default ``../shared/fixtures`` beside the checkout.
    """
    env = os.environ.get("CARAPOST_FIXTURES")
    return Path(env) if env else REPO.parent / "shared" / "fixtures"


@pytest.fixture
def fixtures_dir() -> Path:
    """Path to ``shared/fixtures``; skips the test with a clear reason when absent."""
    path = shared_fixtures_dir()
    if not path.is_dir():
        pytest.skip(f"third-party fixtures not found at {path} (set CARAPOST_FIXTURES)")
    return path


@pytest.fixture
def rng() -> np.random.Generator:
    """A fixed-seed random generator, fresh for every test."""
    return np.random.default_rng(12345)

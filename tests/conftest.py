"""Shared pytest fixtures for carapost."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
UI_TESTS = REPO / "tests" / "ui"

try:  # property tests check behaviour, never speed: no per-example deadline
    from hypothesis import HealthCheck as _HealthCheck
    from hypothesis import settings as _hypothesis_settings

    _hypothesis_settings.register_profile(
        "carapost", deadline=None, suppress_health_check=[_HealthCheck.too_slow])
    _hypothesis_settings.load_profile("carapost")
except ImportError:  # pragma: no cover - hypothesis is a test dependency
    pass


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Mark every test under ``tests/ui`` as ``gui`` (a conftest ``pytestmark`` is inert)."""
    for item in items:
        if item.path.is_relative_to(UI_TESTS):
            item.add_marker(pytest.mark.gui)


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
        pytest.skip(f"needs the third-party fixture files, which are not in this repository: "
                    f"{path} is absent (set CARAPOST_FIXTURES to their folder)")
    return path


@pytest.fixture(autouse=True, scope="session")
def _autosaves_in_a_temporary_folder(tmp_path_factory: pytest.TempPathFactory) -> None:
    """Autosaves of never-saved projects go to a temporary folder, never the user's."""
    os.environ["CARAPOST_AUTOSAVE_DIR"] = str(tmp_path_factory.mktemp("autosave"))


@pytest.fixture(autouse=True, scope="session")
def _user_cache(tmp_path_factory: pytest.TempPathFactory) -> None:
    """Keyframe indexes and playback proxies of test videos go to a temporary cache."""
    os.environ["CARAPOST_CACHE_DIR"] = str(tmp_path_factory.mktemp("user_cache"))


@pytest.fixture
def rng() -> np.random.Generator:
    """A fixed-seed random generator, fresh for every test."""
    return np.random.default_rng(12345)


@pytest.fixture(scope="session")
def synth_take(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A short rendered synthetic take (8 frames, 4 cameras, 1280x720), made once per run.

    Returns the path of its ``<take>.json``; ``truth.npz`` lies beside it.
    """
    from carapost.synth import SynthConfig, generate_take

    folder = tmp_path_factory.mktemp("synth_take")
    return Path(generate_take(folder, SynthConfig(preset="speech", frames=8, seed=11),
                              workers=1))

"""Small synthetic takes for the batch and scripting tests (rendered once, copied)."""

from __future__ import annotations

import shutil
from pathlib import Path

from carapost.synth import SynthConfig, generate_take

#: The smallest take the whole pipeline still processes: 640x360 images (at 320x180 the
#: automatic initialisation finds too few seeds), 35 markers, 4 cameras.
SMALL = {"size": (640, 360), "markers": "sparse35"}


def render_take(folder: Path, frames: int, *, seed: int = 3, name: str = "Take00",
                preset: str = "speech") -> Path:
    """Render one small take; returns its ``<take>.json``."""
    return Path(generate_take(folder, SynthConfig(frames=frames, seed=seed, take_name=name,
                                                  preset=preset, **SMALL), workers=1))


def copy_take(json_path: Path, folder: Path, name: str) -> Path:
    """Copy a take under another name (every ``<take>*`` file renamed)."""
    src = json_path.parent
    old = json_path.stem
    folder.mkdir(parents=True, exist_ok=True)
    for f in src.iterdir():
        if f.name.startswith(old):
            shutil.copy2(f, folder / (name + f.name[len(old):]))
    return folder / f"{name}.json"

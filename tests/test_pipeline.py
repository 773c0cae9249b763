"""Headless pipeline: bad input is refused before anything is written; end to end (slow)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from carapost.io.errors import CaraFileError
from carapost.pipeline import process_take


def tiny_take(folder: Path, frames: int = 3) -> Path:
    """Two blank FFV1 videos named like a take, with no XCP calibration."""
    folder.mkdir()
    for ch in ("cam0", "cam1"):
        w = cv2.VideoWriter(str(folder / f"tiny_{ch}.mkv"), cv2.VideoWriter_fourcc(*"FFV1"),
                            60.0, (64, 48), False)
        assert w.isOpened()
        for _ in range(frames):
            w.write(np.full((48, 64), 128, np.uint8))
        w.release()
    return folder


def test_missing_take_is_refused(tmp_path):
    with pytest.raises(CaraFileError, match="no such file"):
        process_take(tmp_path / "nope", output=tmp_path / "out.cara")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("kw, match", [
    ({"output": "out.txt"}, "must be a .cara"),
    ({"output": "missing/out.cara"}, "does not exist"),
    ({"output": "out.cara", "c3d": "x.fbx"}, "must be a .c3d"),
    ({"output": "out.cara", "rom": "rom.cara"}, "ROM project not found"),
    ({"output": "out.cara", "brim": "brim.txt"}, "brim model not found"),
])
def test_bad_arguments_are_refused_before_work(tmp_path, kw, match):
    take = tiny_take(tmp_path / "take")
    kw = {k: tmp_path / v for k, v in kw.items()}
    with pytest.raises(CaraFileError, match=match):
        process_take(take, **kw)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["take"]


def test_output_that_is_a_folder_is_refused_before_work(tmp_path):
    take = tiny_take(tmp_path / "take")
    (tmp_path / "out.cara").mkdir()
    with pytest.raises(CaraFileError, match="is a folder"):
        process_take(take, output=tmp_path / "out.cara")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.cara", "take"]
    assert list((tmp_path / "out.cara").iterdir()) == []


def test_bad_brim_csv_is_refused(tmp_path):
    take = tiny_take(tmp_path / "take")
    brim = tmp_path / "brim.csv"
    brim.write_text("label,x,y,z\nA,1,2\n")
    with pytest.raises(CaraFileError, match="line 2"):
        process_take(take, output=tmp_path / "out.cara", brim=brim)
    assert not (tmp_path / "out.cara").exists()


def test_take_without_xcp_or_rom_is_refused(tmp_path):
    take = tiny_take(tmp_path / "take")
    with pytest.raises(ValueError, match="no XCP calibration and no ROM"):
        process_take(take, output=tmp_path / "out.cara", c3d=tmp_path / "out.c3d")
    assert not (tmp_path / "out.cara").exists() and not (tmp_path / "out.c3d").exists()


@pytest.mark.slow
@pytest.mark.parametrize("patch_tracking", [False, True])
def test_pipeline_on_rendered_speech_take(tmp_path, patch_tracking):
    from carapost.api import evaluate, open_project
    from carapost.model.project import SOURCE_PATCH
    from carapost.synth import SynthConfig, generate_take

    take = tmp_path / "take"
    generate_take(take, SynthConfig(preset="speech", frames=40, seed=1, take_name="speech"))
    out = tmp_path / "speech.cara"
    info = process_take(take, output=out, c3d=tmp_path / "speech.c3d",
                        patch_tracking=patch_tracking)
    assert out.is_file() and (tmp_path / "speech.c3d").is_file()
    # the C3D's uncertainty sidecar, and no marker of the standard set taken for spurious
    assert info["sigma_csv"] == str(tmp_path / "speech.sigma.csv")
    assert (tmp_path / "speech.sigma.csv").is_file()
    assert info["removed_points"] == []
    pts = open_project(out).points
    face = pts.kind == 0
    tri = pts.recon[:, face] == 1  # triangulated, the initialised frame included
    assert np.isfinite(pts.arrays["sigma"][:, face][tri]).mean() > 0.99
    assert np.isfinite(pts.arrays["sigma"][0, face][tri[0]]).all()
    patched = int((open_project(out).points.source == SOURCE_PATCH).sum())
    assert (patched > 0) == patch_tracking
    assert info["initialised"] > 50
    ev = evaluate(out, take / "truth.npz")
    assert ev["swaps"] == 0
    # the triangulated brim carries the XCP cameras' error into every frame's solve
    assert ev["rmse_mm"] <= 0.4
    # every initialised marker is followed through the take
    assert info["tracked_fraction"] >= 0.95


@pytest.mark.slow
def test_pipeline_triangulates_brim_when_no_model(tmp_path):
    from carapost.api import evaluate
    from carapost.synth import SynthConfig, generate_take

    take = tmp_path / "take"
    # the brim is told from the face by staying put: a take long enough for the face to move
    generate_take(take, SynthConfig(preset="speech", frames=300, seed=2, take_name="speech"))
    (take / "speech_brim.csv").unlink()
    out = tmp_path / "speech.cara"
    info = process_take(take, output=out)
    assert info["brim_source"] == "triangulated from the take"
    assert info["brim_points"] >= 15
    ev = evaluate(out, take / "truth.npz")
    assert ev["swaps"] == 0
    # the triangulated brim carries the XCP cameras' error into every frame's solve
    assert ev["rmse_mm"] <= 0.4


@pytest.mark.slow
@pytest.mark.parametrize("variant", [2, 3])
def test_pipeline_on_other_rigs(tmp_path, variant):
    """Takes of other rigs (camera placement, lenses, brim layout, marker placement and
    sizes drawn at random): nothing may depend on our standard rig's numbers. Variant 3
    has a camera that sees only 8-9 brim dots, one of them cut by the image border."""
    from carapost.api import evaluate
    from carapost.synth import SynthConfig, generate_take

    take = tmp_path / "take"
    generate_take(take, SynthConfig(preset="speech", frames=90, seed=1, take_name="t",
                                    variant=variant))
    out = tmp_path / "t.cara"
    process_take(take, output=out)
    ev = evaluate(out, take / "truth.npz")
    assert ev["swaps"] == 0
    assert ev["coverage"] >= 0.95
    assert ev["rmse_mm"] <= 0.3


def test_process_exports_ignore_the_stabilized_property(tmp_path, rng):
    """`carapost process` pins its export options: a take whose Properties ask for
    stabilised coordinates (which needs Stabilize) still gets its plain C3D."""
    from carapost.pipeline import PROCESS_EXPORT
    from carapost.session import Session
    from tests.commands.test_edit_commands import make_project

    s = Session(make_project(rng))
    s.set_property("Export", "Export Stabilized Coordinates", True)
    with pytest.raises(ValueError, match="stabilis"):
        s.export_c3d(tmp_path / "asked.c3d")
    assert s.export_c3d(tmp_path / "take.c3d", **PROCESS_EXPORT).is_file()

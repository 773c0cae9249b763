"""The example scripts of examples/ on a 20-frame synthetic take: what each prints and
writes is checked against the project and the take's truth, not just its exit status."""

from __future__ import annotations

import csv
import importlib.util
import io
import shutil
import subprocess
import sys
from contextlib import redirect_stdout
from pathlib import Path

import numpy as np
import pytest

from carapost.io.cara import load_project
from carapost.model.project import KIND_BRIM, KIND_FACE
from tests.small_takes import copy_take, render_take
from tests.ufbx_child import call_in_child

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
SCRIPTS = sorted(p.stem for p in EXAMPLES.glob("*.py"))


def load(name: str):
    spec = importlib.util.spec_from_file_location(f"example_{name}", EXAMPLES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def call(name: str, *args) -> tuple[int, str]:
    buf = io.StringIO()
    with redirect_stdout(buf):
        rc = load(name).main([str(a) for a in args])
    return rc, buf.getvalue()


def csv_rows(text: str) -> list[dict[str, str]]:
    lines = [ln for ln in text.splitlines() if ln and not ln.startswith("#")]
    return list(csv.DictReader(lines))


@pytest.fixture(scope="module")
def take(tmp_path_factory) -> Path:
    return render_take(tmp_path_factory.mktemp("ex") / "Take00", frames=20, seed=5)


@pytest.fixture(scope="module")
def projects(take, tmp_path_factory) -> dict[str, Path]:
    """process_setup_ROM.py, then process_track.py on its result: the two projects the
    export scripts read."""
    out = tmp_path_factory.mktemp("projects")
    rc, text = call("process_setup_ROM", take, "-o", out / "rom.cara")
    assert rc == 0, text
    rc, text = call("process_track", out / "rom.cara", "-o", out / "tracked.cara")
    assert rc == 0, text
    return {"setup": out / "rom.cara", "tracked": out / "tracked.cara", "log": text}


def test_the_ten_scripts_are_there_and_answer_help():
    assert SCRIPTS == sorted([
        "cara_fbx_export", "export_3d_simple", "export_brim", "export_general",
        "export_timecode", "process_batch_detect_blobs", "process_detect_blobs",
        "process_properties", "process_setup_ROM", "process_track"])
    for name in SCRIPTS:
        buf = io.StringIO()
        with redirect_stdout(buf), pytest.raises(SystemExit) as exc:
            load(name).main(["--help"])
        assert exc.value.code == 0 and buf.getvalue().startswith("usage:"), name
    # and as programs (one of them: the others share the same argparse shape)
    res = subprocess.run([sys.executable, str(EXAMPLES / "export_timecode.py"), "-h"],
                         capture_output=True, text=True, check=True)
    assert "burnt-in" in res.stdout


def test_setup_rom_and_track(projects):
    setup = load_project(projects["setup"])
    face = setup.points.kind == KIND_FACE
    assert setup.calibration.solved[0]
    assert (setup.points.kind == KIND_BRIM).sum() > 10
    assert np.isfinite(setup.points.positions[0, face, 0]).sum() >= 25
    assert not np.isfinite(setup.points.positions[1:, face, 0]).any()  # not tracked yet
    tracked = load_project(projects["tracked"])
    has = np.isfinite(tracked.points.positions[:, tracked.points.kind == KIND_FACE, 0])
    assert has[1:].mean() > 0.9
    assert f"{has.mean():.1%} of point-frames" in projects["log"]


def test_track_a_take_from_a_rom(take, projects, tmp_path):
    other = copy_take(take, tmp_path / "Take01", "Take01")
    rc, text = call("process_track", other, "--rom", projects["tracked"])
    assert rc == 0, text
    p = load_project(tmp_path / "Take01" / "Take01_t.cara")
    has = np.isfinite(p.points.positions[:, p.points.kind == KIND_FACE, 0])
    assert has.shape == (20, 35) or has.shape[1] >= 25
    assert has.mean() > 0.9
    rc, text = call("process_track", other)  # a take without a ROM: refused, exit 2
    assert rc == 2


def test_detect_blobs_and_the_batch_version(take, tmp_path):
    folder = tmp_path / "jobs"
    a = copy_take(take, folder / "A", "RomA")
    copy_take(take, folder / "deep/B", "RomB")
    rc, text = call("process_detect_blobs", a, "--workers", "1")
    assert rc == 0, text
    p = load_project(folder / "A" / "RomA_b.cara")
    assert text.startswith(f"{p.detections.total} detections in 20 frames x 4 cameras")
    per_image = [len(p.detections.centres(f, c)) for f in range(20) for c in range(4)]
    assert min(per_image) >= 20  # the face markers and brim dots of every image
    rc, text = call("process_batch_detect_blobs", folder)
    assert rc == 0 and "1 made, 1 skipped, 0 failed" in text
    assert (folder / "deep/B/RomB_b.cara").is_file()
    rc, text = call("process_batch_detect_blobs", f"{folder}/*/*/*.json", f"{folder}/A")
    assert "0 made, 2 skipped" in text
    rc, _ = call("process_batch_detect_blobs", tmp_path / "nothing_here")
    assert rc == 2


def test_fbx_export_with_face_points_under_other_nodes(projects, tmp_path):
    pytest.importorskip("ufbx")
    out = tmp_path / "out.fbx"
    rc, text = call("cara_fbx_export", projects["tracked"], "-o", out,
                    "--group", "mouth=Point 2*,*Lip*", "--group", "nose=Point 3*")
    assert rc == 0, text
    p = load_project(projects["tracked"])  # unlabelled: "Point 24", ...
    labels = [p.point_label(int(c)) for c in np.flatnonzero(p.points.kind == KIND_FACE)]
    n_mouth = sum(s.startswith("Point 2") or "Lip" in s for s in labels)
    n_nose = sum(s.startswith("Point 3") and "Lip" not in s for s in labels)
    assert n_mouth and n_nose and n_mouth + n_nose < len(labels)
    parents, kids = call_in_child(_groups, out)
    assert parents == {"mouth": "face", "nose": "face"}
    assert len(kids["mouth"]) == n_mouth and len(kids["nose"]) == n_nose
    assert f"/face/mouth: {n_mouth} points" in text


def _groups(path) -> tuple[dict[str, str], dict[str, list[str]]]:
    """The mouth and nose nodes' parents and children, read with ufbx (in a child
    process: `tests.ufbx_child`)."""
    import ufbx

    scene = ufbx.load_file(str(path), strict=True)
    nodes = list(scene.nodes)
    by_name = {n.name: n for n in nodes}
    groups = ("mouth", "nose")
    parents = [by_name[name].parent for name in groups]
    children = [list(by_name[name].children) for name in groups]
    return ({name: str(p.name) for name, p in zip(groups, parents, strict=True)},
            {name: [str(c.name) for c in cs] for name, cs in zip(groups, children, strict=True)})


def test_properties_listing_and_setting(projects, tmp_path):
    from carapost.model.properties import SECTIONS, defaults

    rc, text = call("process_properties")
    assert rc == 0
    assert all(f"[{s}]" in text for s in SECTIONS)
    d = defaults()
    assert f"White Min Radius (white_min_radius) = {d['white_min_radius']!r}" in text
    out = tmp_path / "changed.cara"
    rc, text = call("process_properties", projects["setup"], "--section", "Blob Parameters",
                    "--set", "white_min_radius=2.5", "-o", out)
    assert rc == 0, text
    assert load_project(out).properties["white_min_radius"] == 2.5
    assert " * White Min Radius (white_min_radius) = 2.5" in text
    assert "[Tracking Parameters]" not in text
    rc, _ = call("process_properties", "--set", "white_min_radius=-1")
    assert rc == 2


def test_export_3d_and_brim_print_the_project(projects, take):
    p = load_project(projects["tracked"])
    rc, text = call("export_3d_simple", projects["tracked"], "--frames", 3, 5)
    assert rc == 0
    rows = csv_rows(text)
    cols = {p.point_label(int(c)): int(c) for c in np.flatnonzero(p.points.kind == KIND_FACE)}
    want = np.isfinite(p.points.positions[3:6][:, list(cols.values()), 0]).sum()
    assert len(rows) == want
    for r in rows[::7]:
        xyz = p.points.positions[int(r["frame"]), cols[r["label"]]]
        assert np.allclose([float(r[k]) for k in ("x_mm", "y_mm", "z_mm")], xyz, atol=1e-4)
    rc, text = call("export_brim", projects["tracked"])
    assert rc == 0
    brim = {r["label"]: [float(r[k]) for k in ("x_mm", "y_mm", "z_mm")]
            for r in csv_rows(text)}
    from carapost.io.take_import import read_brim_csv

    labels, xyz = read_brim_csv(take.parent / "Take00_brim.csv")
    assert sorted(brim) == sorted(labels)
    for lab, v in zip(labels, xyz, strict=True):
        assert np.allclose(brim[lab], v, atol=1e-3)
    assert text.count("brim dots observed") == 4


def test_export_general_table_and_plot(projects, tmp_path):
    pytest.importorskip("matplotlib")  # the examples extra
    from carapost.model import queries

    png = tmp_path / "tracks.png"
    rc, text = call("export_general", projects["tracked"], "--camera", 1, "--points", 4,
                    "-o", png)
    assert rc == 0, text
    p = load_project(projects["tracked"])
    rows = csv_rows(text.split("wrote")[0])
    face = np.flatnonzero(p.points.kind == KIND_FACE)
    assert len(rows) == len(face)
    present = queries.present(p)
    assert [int(r["frames"]) for r in rows] == present[:, face].sum(0).tolist()
    import matplotlib.image

    img = matplotlib.image.imread(png)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and img.shape[0] > 100
    assert img[..., :3].std() > 0.05  # something was drawn


def test_export_timecode_conversions(projects):
    rc, text = call("export_timecode", projects["tracked"], "--frame", 0, "--frame", 61,
                    "--timecode", "00:00:01:01", "--burnt-in", 5)
    assert rc == 0
    rows = csv_rows(text)
    got = [(int(r["frame_index"]), int(r["burnt_in"]), r["timecode"], r["in_take"])
           for r in rows]
    assert got == [(0, 1, "00:00:00:00", "yes"), (61, 62, "00:00:01:01", "no"),
                   (4, 5, "00:00:00:04", "yes"), (61, 62, "00:00:01:01", "no")]
    rc, _ = call("export_timecode", projects["tracked"], "--timecode", "nonsense")
    assert rc == 2


def test_examples_refuse_a_missing_project(tmp_path, capsys):
    for name in ("export_3d_simple", "export_brim", "export_general", "export_timecode"):
        rc, _ = call(name, tmp_path / "missing.cara")
        assert rc == 2, name
    assert "missing.cara" in capsys.readouterr().err
    shutil.rmtree(tmp_path, ignore_errors=True)

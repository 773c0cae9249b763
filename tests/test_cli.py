"""The ``carapost`` command, run in-process through ``main(argv)``."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from carapost import __version__, api, demo
from carapost.cli import main
from carapost.model.project import RECON_TRIANGULATED, new_project

SUBCOMMANDS = ("gui", "demo", "synth", "import", "process", "evaluate", "export-c3d",
               "export-fbx", "export-xcp")


def _take(folder: Path, n: int = 5, channels=("cam0", "cam1")) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for c in channels:
        w = cv2.VideoWriter(str(folder / f"T_{c}.mkv"), cv2.VideoWriter_fourcc(*"FFV1"), 25.0,
                            (64, 48), isColor=False)
        for i in range(n):
            w.write(np.full((48, 64), i, np.uint8))
        w.release()
    return folder / f"T_{channels[0]}.mkv"


def test_help_lists_subcommands(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    for name in SUBCOMMANDS:
        assert name in out


def test_version(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    assert capsys.readouterr().out.strip() == f"carapost {__version__}"


def test_import_writes_a_project(tmp_path, capsys):
    cam0 = _take(tmp_path / "take")
    out = tmp_path / "x.cara"
    assert main(["import", str(cam0), "-o", str(out)]) == 0
    assert f"wrote {out}" in capsys.readouterr().out
    project = api.open_project(out)
    assert project.n_cameras == 2 and project.n_frames == 5 and project.take.fps == 25.0


@pytest.mark.parametrize(
    "argv, message",
    [
        (["import", "{tmp}/nothing_cam0.mkv", "-o", "{tmp}/x.cara"], "nothing_cam0.mkv"),
        (["import", "{tmp}/Rom_0.pico", "-o", "{tmp}/x.cara"], "proprietary"),
        (["evaluate", "{tmp}/none.cara", "{tmp}/truth.npz"], "none.cara"),
        (["export-c3d", "{tmp}/none.cara", "{tmp}/o.c3d"], "none.cara"),
    ],
)
def test_bad_input_exits_2_with_a_message(tmp_path, capsys, argv, message):
    (tmp_path / "Rom_0.pico").write_bytes(b"x")
    argv = [a.format(tmp=tmp_path) for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"carapost {argv[0]}: error:") and message in err
    assert not (tmp_path / "x.cara").exists()


def test_unknown_option_exits_2(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["import"])
    assert exc.value.code == 2


def test_export_and_evaluate_commands(tmp_path, capsys):
    F, M = 8, 3
    X = np.random.default_rng(3).normal(0, 30, (F, M, 3))
    np.savez(tmp_path / "truth.npz", points3d=X, labels=np.array(["a", "b", "c"]))
    p = new_project(F, 2)
    cols = p.points.append(M, labels=["a", "b", "c"])
    p.points.positions[:, cols] = X
    p.points.recon[:, cols] = RECON_TRIANGULATED
    proj = api.save_project(p, tmp_path / "p.cara")
    assert main(["evaluate", str(proj), str(tmp_path / "truth.npz")]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["n_matched"] == 3 and report["rmse_mm"] == pytest.approx(0, abs=1e-4)
    assert main(["export-c3d", str(proj), str(tmp_path / "o.c3d"), "--range", "all"]) == 0
    assert (tmp_path / "o.c3d").is_file()
    assert main(["export-fbx", str(proj), str(tmp_path / "o.fbx"), "--up", "z"]) == 0
    assert (tmp_path / "o.fbx").is_file()
    assert main(["export-xcp", str(proj), str(tmp_path / "o.xcp")]) == 2  # not calibrated
    assert "no camera calibration" in capsys.readouterr().err
    assert not (tmp_path / "o.xcp").exists()


def test_process_command(tmp_path, capsys, synth_take):
    assert main(["process", str(synth_take), "-o", str(tmp_path / "r.cara"),
                 "--c3d", str(tmp_path / "r.c3d")]) == 0
    out = capsys.readouterr().out
    assert "project:" in out and (tmp_path / "r.cara").is_file()
    assert (tmp_path / "r.c3d").is_file()


def test_process_command_bad_input_exits_2(tmp_path, capsys):
    cam0 = _take(tmp_path / "take")  # videos only: no XCP, no ROM
    assert main(["process", str(cam0), "-o", str(tmp_path / "r.cara")]) == 2
    assert "no XCP calibration" in capsys.readouterr().err
    assert not (tmp_path / "r.cara").exists()


def test_demo_headless_ends_labelled(tmp_path, capsys, monkeypatch, synth_take):
    """The headless demo on a short take standing in for the generated ones: the ROM is
    labelled from its truth, the take processed with it; every face point of the C3D
    (read with ezc3d) and the FBX (read with ufbx) carries its truth label, the summary
    says how many, and a second run reuses the results."""
    import ezc3d

    from carapost.synth.evaluation import load_truth
    from tests.ufbx_child import fbx_node_names

    truth = synth_take.parent / "truth.npz"
    monkeypatch.setattr(demo, "ensure_demo_take", lambda frames: (synth_take, truth))
    monkeypatch.setattr(demo, "ensure_rom_take", lambda: (synth_take, truth))
    out = tmp_path / "results"
    assert main(["demo", "--headless", "--frames", "4", "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert f"Project:     {out / 'demo.cara'}" in text and "C3D:" in text
    assert (out / "demo.cara").is_file() and (out / "demo.c3d").is_file()
    assert "Evaluation:" in text and (out / "evaluation.json").is_file()
    names = set(load_truth(truth)["labels"])
    c3d = ezc3d.c3d(str(out / "demo.c3d"))
    c3d_labels = list(c3d["parameters"]["POINT"]["LABELS"]["value"])
    assert len(c3d_labels) >= 0.75 * len(names)   # an 8-frame take: a few stay unseen
    assert set(c3d_labels) <= names                   # no "Point 24": every one labelled
    n = len(c3d_labels)
    assert f"Labelled:    {n} of {n} face points" in text and f"{n} agree with the truth" in text
    nodes = fbx_node_names(out / "demo.fbx")
    assert set(c3d_labels) <= set(nodes)
    assert not any(name.startswith("Point ") for name in nodes)
    assert main(["demo", "--headless", "--frames", "4", "-o", str(out)]) == 0
    captured = capsys.readouterr()
    assert "Using the demo results" in captured.err and f"Labelled:    {n} of {n}" in captured.out


def test_demo_without_display_says_so(tmp_path, capsys, monkeypatch, synth_take):
    monkeypatch.setattr(demo, "ensure_demo_take", lambda frames: (synth_take, None))
    monkeypatch.setattr(demo, "ensure_rom_take", lambda: (synth_take, None))
    for key in ("DISPLAY", "WAYLAND_DISPLAY", "QT_QPA_PLATFORM"):
        monkeypatch.delenv(key, raising=False)
    assert demo.run_demo(frames=3, out=str(tmp_path / "r")) == 0
    assert "No display found" in capsys.readouterr().err


def test_demo_without_generator_exits_1(tmp_path, capsys, monkeypatch):
    def missing(frames):
        raise ImportError("cannot import name 'generate_take'")

    monkeypatch.setattr(demo, "ensure_demo_take", missing)
    assert demo.run_demo(headless=True, frames=10, out=str(tmp_path)) == 1
    assert "not available yet" in capsys.readouterr().err
    assert main(["demo", "--frames", "1"]) == 2


def test_every_subcommand_help_shows_defaults_and_positional_help(capsys):
    for name in SUBCOMMANDS:
        with pytest.raises(SystemExit):
            main([name, "--help"])
        out = capsys.readouterr().out
        assert "positional arguments:" not in out or all(
            line.strip() == "" or len(line.split()) > 1 or line.strip().endswith(":")
            for line in out.split("positional arguments:")[1].split("options:")[0]
            .splitlines()), f"{name}: a positional argument without help"
    with pytest.raises(SystemExit):
        main(["synth", "--help"])
    assert "(default: speech)" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        main(["demo", "--help"])
    assert "(default: 120)" in capsys.readouterr().out


def test_demo_cache_folder_follows_xdg(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert demo.demo_cache_dir(50) == tmp_path / "carapost" / f"demo-{__version__}-50"


@pytest.mark.slow
def test_demo_generates_and_processes_the_take(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    assert demo.run_demo(headless=True, frames=6, out=str(tmp_path / "r")) == 0
    assert (tmp_path / "r" / "demo.cara").is_file()
    # second run reuses the cache
    assert demo.run_demo(headless=True, frames=6, out=str(tmp_path / "r")) == 0
    assert "Using the demo take cached" in capsys.readouterr().err


def test_console_progress_plain_lines_and_bars():
    import io

    from carapost.progress import ConsoleProgress

    out = io.StringIO()
    with ConsoleProgress(out, bars=False) as bars:
        tick = bars.stage("Detect blobs")
        for i in range(1, 1001):
            assert tick(i, 1000)
        bars.stage("Track")(5, 10)
    lines = out.getvalue().splitlines()
    assert lines[0].startswith("Detect blobs: ") and "%" in lines[0]
    assert len([x for x in lines if x.startswith("Detect blobs:")]) <= 11   # not 1000
    assert any(x.startswith("Detect blobs: done in") for x in lines)
    assert lines[-1].startswith("Track: done in")
    quiet = io.StringIO()
    with ConsoleProgress(quiet, quiet=True) as bars:
        bars.stage("Detect blobs")(1, 2)
    assert quiet.getvalue() == ""
    drawn = io.StringIO()
    with ConsoleProgress(drawn, bars=True) as bars:
        bars.stage("Detect blobs")(50, 100)
    assert "Detect blobs" in drawn.getvalue()



def test_synth_reports_a_write_failure_in_one_line(tmp_path, capsys, monkeypatch):
    import errno

    from carapost.synth import cli as synth_cli

    def full_disk(outdir, config, progress=None, workers=1):
        raise OSError(errno.ENOSPC, "No space left on device", str(tmp_path / "cam0.mkv"))

    monkeypatch.setattr(synth_cli, "generate_take", full_disk)
    assert main(["synth", str(tmp_path / "take"), "--frames", "2", "--quiet"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"carapost synth: error: {tmp_path / 'cam0.mkv'}: No space left on device"]

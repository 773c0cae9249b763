"""``carapost demo``: generate a synthetic take, process it labelled, show it.

The demo works the way a studio does: label a ROM once, then process every take with
it. Two takes are generated once per carapost version and length into the user cache
folder (``$XDG_CACHE_HOME/carapost/demo-<version>-<frames>`` and
``demo-rom-<version>-<frames>``, by default under ``~/.cache``) and reused afterwards:
a short ROM take (neutral face, then every expression in turn) and the demo take
(speech, standard marker set, seed 0). The ROM is processed and labelled from its
synthetic truth, as an artist would label it by hand (``rom.cara``); the demo take is
then processed with ``--rom rom.cara`` (`carapost.pipeline.process_take`: import,
detect, solve, initialise from the ROM, track, save, export), so its points, C3D and
FBX carry the marker names. The results are reused while they are up to date (same
carapost version and takes). The summary gives the paths, how many points are labelled
and an evaluation against the truth; with a display the main window then opens on the
project.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from carapost import __version__
from carapost.model.project import KIND_FACE

log = logging.getLogger("carapost.demo")

__all__ = ["ROM_FRAMES", "demo_cache_dir", "display_available", "ensure_demo_take",
           "ensure_rom_take", "run_demo"]

_COMPLETE = "complete.json"
_RESULTS = "demo-results.json"
# How the cached demo's videos are written: a cache of another layout is generated again
# (FFV1 with a keyframe on every frame since "ffv1-intra": jumps decode one frame).
_VIDEOS = "ffv1-intra"


def demo_cache_dir(frames: int, name: str = "demo") -> Path:
    """Cache folder of the demo take (or ``name``: the ROM take) of ``frames`` frames."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "carapost" / f"{name}-{__version__}-{int(frames)}"


def display_available() -> bool:
    """Whether a window can be shown (X11/Wayland display, or a Qt platform chosen)."""
    return any(os.environ.get(k) for k in ("DISPLAY", "WAYLAND_DISPLAY", "QT_QPA_PLATFORM"))


def _say(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


#: Length of the demo's ROM take (frames): enough for every expression mode to show.
ROM_FRAMES = 60


def ensure_rom_take(frames: int = ROM_FRAMES) -> tuple[Path, Path | None]:
    """Generate the demo's ROM take into the cache, or reuse it (see `ensure_demo_take`).

    Same rig and marker set as the demo take; another seed (another session's slip).
    """
    return ensure_demo_take(frames, preset="rom", seed=7, name="demo-rom")


def ensure_demo_take(frames: int, *, preset: str = "speech", seed: int = 0,
                     name: str = "demo") -> tuple[Path, Path | None]:
    """Generate the demo take into the cache, or reuse it.

    Returns
    -------
    take : Path
        What `carapost.Session.import_take` accepts (a camera file or the take folder).
    truth : Path or None
        The take's ``truth.npz`` when the generator wrote one.

    Raises
    ------
    ImportError
        If the synthetic take generator is not available.
    """
    from carapost.synth import SynthConfig, generate_take

    folder = demo_cache_dir(frames, name)
    marker = folder / _COMPLETE
    if marker.is_file():
        try:
            info = json.loads(marker.read_text(encoding="utf-8"))
            take = folder / info["take"]
            truth = folder / info["truth"] if info.get("truth") else None
            if take.exists() and info.get("videos") == _VIDEOS:
                _say(f"Using the demo take cached in {folder}")
                return take, truth
        except (ValueError, KeyError, OSError):
            pass
        log.info("The cached demo take in %s is incomplete or of an older layout; "
                 "generating it again", folder)
    config = SynthConfig(preset=preset, markers="standard", frames=int(frames), seed=seed,
                         take_name=name.replace("-", "_"))
    folder.parent.mkdir(parents=True, exist_ok=True)
    # Generate beside the cache folder and rename at the end, so an interrupted run
    # never leaves a half-written take that looks complete.
    tmp = Path(tempfile.mkdtemp(prefix=f".{folder.name}.", dir=folder.parent))
    from carapost.progress import ConsoleProgress

    _say(f"Generating the {preset} take ({frames} frames) into {folder} ...")
    started = time.monotonic()
    bars = ConsoleProgress()
    try:
        with bars:
            produced = Path(generate_take(tmp, config,
                                          progress=bars.stage(f"Render {name}")))
        rel_take = produced.relative_to(tmp) if produced != tmp else Path(".")
        truth = next(iter(sorted(tmp.rglob("truth.npz"))), None)
        info = {"take": str(rel_take), "videos": _VIDEOS,
                "truth": str(truth.relative_to(tmp)) if truth is not None else None}
        (tmp / _COMPLETE).write_text(json.dumps(info), encoding="utf-8")
        if folder.exists():
            shutil.rmtree(folder)
        os.replace(tmp, folder)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    _say(f"Generated in {time.monotonic() - started:.0f} s")
    return folder / rel_take, (folder / info["truth"]) if info["truth"] else None


def _stamp(*paths: Path | None) -> dict:
    """What the results depend on: carapost's version and the takes' cache markers."""
    stamp: dict = {"version": __version__}
    for i, p in enumerate(paths):
        folder = None if p is None else (p if p.is_dir() else p.parent)
        marker = None if folder is None else folder / _COMPLETE
        stamp[f"take{i}"] = (str(p), marker.stat().st_mtime_ns
                             if marker is not None and marker.is_file() else None)
    return stamp


def _reusable(results: Path, stamp: dict) -> dict | None:
    """The saved summary of an up-to-date earlier run, or None."""
    path = results / _RESULTS
    try:
        saved = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if saved.get("stamp") != json.loads(json.dumps(stamp)):
        return None
    result = saved.get("result") or {}
    if not all(result.get(k) and Path(result[k]).is_file() for k in ("project", "c3d", "fbx")):
        return None
    return saved


def _label_rom(rom_take: Path, rom_truth: Path | None, results: Path, bars) -> Path | None:
    """Process the ROM take and label it from its truth (as an artist labels a ROM)."""
    from carapost.pipeline import process_take
    from carapost.session import Session
    from carapost.synth.evaluation import truth_labels

    if rom_truth is None or not rom_truth.is_file():
        return None
    rom_path = results / "rom.cara"
    bars.say("Processing the ROM take, then labelling it from its truth ...")
    process_take(rom_take, output=rom_path, stages=bars.stage)
    bars.stage("Label the ROM")
    with Session.open(rom_path) as session:
        mapping = truth_labels(session.project, rom_truth)
        session.set_point_labels(mapping, description="Label ROM from its truth")
        session.save(rom_path)
    return rom_path


def _process(take: Path, project_path: Path, results: Path, rom: Path | None,
             bars) -> dict:
    """Run the headless pipeline on the demo take (with the ROM when there is one: it
    initialises the take, and labels the markers found later by Label From Template)."""
    from carapost.pipeline import process_take

    bars.say("Processing the demo take: detect blobs, solve the brim, initialise"
             + (" from the ROM" if rom else "") + ", track, export ...")
    return process_take(take, output=project_path, c3d=results / "demo.c3d",
                        fbx=results / "demo.fbx", rom=rom, label_template=rom,
                        stages=bars.stage)


def _label_summary(project_path: Path, truth: Path | None) -> dict:
    """Labelled face points of the project, and how many agree with the truth."""
    from carapost.session import Session

    project = Session.open(project_path).project
    face = np.flatnonzero(project.points.kind == KIND_FACE)
    has = np.isfinite(project.points.positions[:, face, 0]).any(0)
    face = face[has]
    labelled = [int(c) for c in face if project.points.labels[c]]
    out = {"face_points": int(len(face)), "labelled": len(labelled), "correct": None}
    if truth is not None and truth.is_file() and labelled:
        from carapost.synth.evaluation import truth_labels

        names = truth_labels(project, truth)
        out["correct"] = sum(1 for c in labelled if names.get(int(project.points.ids[c]))
                             == project.points.labels[c])
    return out


def _summary(take: Path, result: dict, labels: dict, evaluation: str | None) -> None:
    print(f"Demo take:   {take}")
    print(f"Project:     {result['project']}")
    print(f"Points:      {result['points']} face markers ({result['initialised']} initialised"
          f" at frame 0), {result['brim_points']} brim dots; brim from "
          f"{result['brim_source']}")
    print(f"Tracked:     {100 * result['tracked_fraction']:.1f} % of face point-frames")
    line = f"Labelled:    {labels['labelled']} of {labels['face_points']} face points"
    if result.get("rom"):
        line += f" (from the ROM {result['rom']})"
    if labels.get("correct") is not None:
        line += f"; {labels['correct']} agree with the truth"
    print(line)
    for kind in ("c3d", "fbx"):
        print(f"{kind.upper() + ':':<12} {result[kind]}")
    if evaluation:
        print(evaluation)


def run_demo(*, headless: bool = False, frames: int = 120, out: str | None = None,
             rebuild: bool = False) -> int:
    """Run the demo.

    Parameters
    ----------
    headless : bool
        Never open a window; only print the summary.
    frames : int
        Length of the demo take (>= 2).
    out : str, optional
        Folder for the project and exports (default: ``results`` in the cache folder).
    rebuild : bool
        Process the takes again even when the results are up to date.

    Returns
    -------
    int
        Exit status: 0 on success, 1 when the demo cannot run here.

    Raises
    ------
    ValueError
        For a bad number of frames.
    """
    from carapost.progress import ConsoleProgress

    frames = int(frames)
    if frames < 2:
        raise ValueError(f"--frames must be at least 2, got {frames}")
    try:
        take, truth = ensure_demo_take(frames)
        rom_take, rom_truth = ensure_rom_take()
    except ImportError as exc:
        _say("carapost demo: the demo take generator (carapost.synth) is not available yet "
             f"in this build ({exc}); import your own take with `carapost import` instead.")
        return 1
    results = Path(out) if out else demo_cache_dir(frames) / "results"
    results.mkdir(parents=True, exist_ok=True)
    project_path = results / "demo.cara"
    gui = None
    if not headless:
        if display_available():
            try:
                from carapost.ui.app import run_gui as gui
            except ImportError as exc:
                _say(f"The main window is not available in this build ({exc}); running the "
                     "headless pipeline instead.")
        else:
            _say("No display found (DISPLAY and WAYLAND_DISPLAY are not set), so no window "
                 "can open; running the headless pipeline instead.")

    stamp = _stamp(take, rom_take)
    saved = None if rebuild else _reusable(results, stamp)
    if saved is not None:
        _say(f"Using the demo results in {results} (up to date; --rebuild processes again)")
        result, labels, evaluation = saved["result"], saved["labels"], saved["evaluation"]
    else:
        with ConsoleProgress() as bars:
            rom = _label_rom(rom_take, rom_truth, results, bars)
            result = _process(take, project_path, results, rom, bars)
            bars.stage("Evaluate")
            result["rom"] = str(rom) if rom else None
            labels = _label_summary(Path(result["project"]), truth)
            evaluation = _evaluate(Path(result["project"]), truth, results)
        (results / _RESULTS).write_text(json.dumps(
            {"stamp": stamp, "result": result, "labels": labels, "evaluation": evaluation},
            indent=1, default=str), encoding="utf-8")
    _summary(take, result, labels, evaluation)
    if gui is not None:
        _say(f"Opening {result['project']}")
        return int(gui(str(result["project"])) or 0)
    return 0


def _evaluate(project_path: Path, truth: Path | None, results: Path) -> str | None:
    """The evaluation line of the summary (the report goes to ``evaluation.json``)."""
    if truth is None or not truth.is_file():
        return None
    from carapost.session import Session
    from carapost.synth.evaluation import evaluate

    project = Session.open(project_path).project
    if not project.n_points:
        return f"Truth:       {truth} (no 3D points to evaluate yet)"
    report = evaluate(project, truth)
    eval_path = results / "evaluation.json"
    eval_path.write_text(json.dumps(report, indent=1), encoding="utf-8")
    return (f"Evaluation:  {eval_path} (RMSE {report['rmse_mm']:.3f} mm, "
            f"coverage {report['coverage']:.3f}, {report['swaps']} identity swaps)")

"""``carapost demo``: generate a synthetic take, import it and show it (or process it).

The demo take (speech motion, standard marker set, seed 0) is generated once per
carapost version and length into the user cache folder
(``$XDG_CACHE_HOME/carapost/demo-<version>-<frames>``, by default ``~/.cache/...``) and
reused afterwards. With a display the main window opens on the imported project;
without one (or with ``--headless``) the headless pipeline runs on it
(`carapost.pipeline.process_take`: import, detect, solve, initialise, track, save, export)
and the paths of the results are printed, followed by an evaluation against the
take's ground truth when the project holds 3D points.
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

from carapost import __version__

log = logging.getLogger("carapost.demo")

__all__ = ["demo_cache_dir", "display_available", "ensure_demo_take", "run_demo"]

_COMPLETE = "complete.json"


def demo_cache_dir(frames: int) -> Path:
    """Cache folder of the demo take of ``frames`` frames."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "carapost" / f"demo-{__version__}-{int(frames)}"


def display_available() -> bool:
    """Whether a window can be shown (X11/Wayland display, or a Qt platform chosen)."""
    return any(os.environ.get(k) for k in ("DISPLAY", "WAYLAND_DISPLAY", "QT_QPA_PLATFORM"))


def _say(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def ensure_demo_take(frames: int) -> tuple[Path, Path | None]:
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

    folder = demo_cache_dir(frames)
    marker = folder / _COMPLETE
    if marker.is_file():
        try:
            info = json.loads(marker.read_text(encoding="utf-8"))
            take = folder / info["take"]
            truth = folder / info["truth"] if info.get("truth") else None
            if take.exists():
                _say(f"Using the demo take cached in {folder}")
                return take, truth
        except (ValueError, KeyError, OSError):
            pass
        log.info("The cached demo take in %s is incomplete; generating it again", folder)
    config = SynthConfig(preset="speech", markers="standard", frames=int(frames), seed=0,
                         take_name="demo")
    folder.parent.mkdir(parents=True, exist_ok=True)
    # Generate beside the cache folder and rename at the end, so an interrupted run
    # never leaves a half-written take that looks complete.
    tmp = Path(tempfile.mkdtemp(prefix=f".{folder.name}.", dir=folder.parent))
    _say(f"Generating the demo take ({frames} frames) into {folder} ...")
    started = time.monotonic()
    last = [0.0]

    def progress(done: int, total: int) -> bool:
        now = time.monotonic()
        if now - last[0] >= 2.0 or done == total:
            last[0] = now
            _say(f"  {done}/{total}")
        return True

    try:
        produced = Path(generate_take(tmp, config, progress=progress))
        rel_take = produced.relative_to(tmp) if produced != tmp else Path(".")
        truth = next(iter(sorted(tmp.rglob("truth.npz"))), None)
        info = {"take": str(rel_take),
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


def _process(take: Path, project_path: Path, results: Path) -> dict:
    """Run the headless pipeline on the demo take, printing its progress."""
    _say("Processing the demo take: detect blobs, solve the brim, initialise, track ...")
    last = [-1]

    def progress(done: int, total: int) -> bool:
        pct = 100 * done // max(total, 1)
        if pct // 10 != last[0]:
            last[0] = pct // 10
            _say(f"  {pct} %")
        return True

    from carapost.pipeline import process_take

    return process_take(take, output=project_path, c3d=results / "demo.c3d",
                        fbx=results / "demo.fbx", progress=progress)


def run_demo(*, headless: bool = False, frames: int = 120, out: str | None = None) -> int:
    """Run the demo.

    Parameters
    ----------
    headless : bool
        Never open a window; run the headless pipeline.
    frames : int
        Length of the demo take (>= 2).
    out : str, optional
        Folder for the project and exports (default: ``results`` in the cache folder).

    Returns
    -------
    int
        Exit status: 0 on success, 1 when the demo cannot run here.

    Raises
    ------
    ValueError
        For a bad number of frames.
    """
    frames = int(frames)
    if frames < 2:
        raise ValueError(f"--frames must be at least 2, got {frames}")
    try:
        take, truth = ensure_demo_take(frames)
    except ImportError as exc:
        _say("carapost demo: the demo take generator (carapost.synth) is not available yet "
             f"in this build ({exc}); import your own take with `carapost import` instead.")
        return 1
    results = Path(out) if out else demo_cache_dir(frames) / "results"
    results.mkdir(parents=True, exist_ok=True)
    project_path = results / "demo.cara"

    if not headless:
        if display_available():
            try:
                from carapost.ui.app import run_gui
            except ImportError as exc:
                _say(f"The main window is not available in this build ({exc}); running the "
                     "headless pipeline instead.")
            else:
                result = _process(take, project_path, results)
                _say(f"Opening {result['project']}")
                return int(run_gui(str(result["project"])) or 0)
        else:
            _say("No display found (DISPLAY and WAYLAND_DISPLAY are not set), so no window "
                 "can open; running the headless pipeline instead.")

    result = _process(take, project_path, results)
    print(f"Demo take:   {take}")
    print(f"Project:     {result['project']}")
    print(f"Points:      {result['points']} face markers ({result['initialised']} initialised"
          f" at frame 0), {result['brim_points']} brim dots; brim from "
          f"{result['brim_source']}")
    print(f"Tracked:     {100 * result['tracked_fraction']:.1f} % of face point-frames")
    for kind in ("c3d", "fbx"):
        print(f"{kind.upper() + ':':<12} {result[kind]}")
    if truth is not None and truth.is_file():
        from carapost.session import Session
        from carapost.synth.evaluation import evaluate

        project = Session.open(result["project"]).project
        if project.n_points:
            report = evaluate(project, truth)
            eval_path = results / "evaluation.json"
            eval_path.write_text(json.dumps(report, indent=1), encoding="utf-8")
            print(f"Evaluation:  {eval_path} (RMSE {report['rmse_mm']:.3f} mm, "
                  f"coverage {report['coverage']:.3f}, {report['swaps']} identity swaps)")
        else:
            print(f"Truth:       {truth} (no 3D points to evaluate yet)")
    return 0

"""The ``carapost`` command line.

Subcommands import their machinery lazily, so ``carapost --help`` is instant and the
headless commands never import Qt.
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Callable, Sequence
from typing import Any

from carapost import __version__

log = logging.getLogger("carapost")


class _HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Show each option's default, except where there is none (None, an off flag)."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        if action.default in (None, False, argparse.SUPPRESS) or action.required:
            return action.help
        return super()._get_help_string(action)


class CliError(Exception):
    """A problem the user can fix; printed without a traceback, exit status 2."""


def _cmd_gui(args: argparse.Namespace) -> int:
    from carapost.ui.app import run_gui

    return run_gui(args.project)


def _cmd_demo(args: argparse.Namespace) -> int:
    from carapost.demo import run_demo

    return run_demo(headless=args.headless, frames=args.frames, out=args.output,
                    rebuild=args.rebuild)


def _cmd_synth(args: argparse.Namespace) -> int:
    from carapost.synth.cli import main_synth

    return main_synth(args.rest)


def _cmd_evaluate(args: argparse.Namespace) -> int:
    import json

    from carapost.api import evaluate

    with _open_session(args) as session:
        print(json.dumps(evaluate(session.project, args.truth), indent=1))
    return 0


def _open_session(args: argparse.Namespace) -> Any:
    """Session.open of ``args.project``; a newer autosave copy is reported on stderr."""
    import warnings

    from carapost.session import Session
    from carapost.session.recovery import NewerAutosaveWarning

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NewerAutosaveWarning)
        session = Session.open(args.project, recover=True if args.recover else None)
    if session.newer_autosave is not None:
        print(f"carapost {args.command}: warning: {args.project} has a newer autosave copy "
              f"({session.newer_autosave}); the file was used. Pass --recover to use the "
              "copy.", file=sys.stderr)
    return session


def _cmd_export_c3d(args: argparse.Namespace) -> int:
    with _open_session(args) as session:
        session.export_c3d(args.output, frame_range=args.range, include_brim=args.brim,
                           stabilized=args.stabilized)
    print(f"wrote {args.output}")
    return 0


def _cmd_export_fbx(args: argparse.Namespace) -> int:
    with _open_session(args) as session:
        session.export_fbx(args.output, frame_range=args.range, include_brim=args.brim,
                           up_axis=args.up, include_cameras=args.cameras,
                           include_sticks=args.sticks, stabilized=args.stabilized)
    print(f"wrote {args.output}")
    return 0


def _cmd_export_xcp(args: argparse.Namespace) -> int:
    with _open_session(args) as session:
        session.export_xcp(args.output, frame=args.frame)
    print(f"wrote {args.output}")
    return 0


def _cmd_import(args: argparse.Namespace) -> int:
    from carapost.session import Session

    with Session.import_take(args.take) as session:
        out = session.save(args.output)
    print(f"wrote {out}")
    return 0


def _cmd_process(args: argparse.Namespace) -> int:
    from carapost.pipeline import process_take
    from carapost.progress import ConsoleProgress

    with ConsoleProgress(quiet=args.quiet) as bars:
        result = process_take(
            args.take,
            output=args.output,
            rom=args.rom,
            brim=args.brim,
            c3d=args.c3d,
            fbx=args.fbx,
            patch_tracking=args.patch_tracking,
            stabilize=args.stabilize,
            label_template=args.label_template,
            stages=bars.stage,
        )
    for key, value in result.items():
        print(f"{key}: {value}")
    return 0


def _cmd_batch(args: argparse.Namespace) -> int:
    from carapost.batch import run, terminal_progress

    report = run(args.inputs, args.output, rom=args.rom, brim=args.brim, c3d=args.c3d,
                 fbx=args.fbx, patch_tracking=args.patch_tracking, stabilize=args.stabilize,
                 scheduler=args.scheduler,
                 workers=args.workers, retries=args.retries, force=args.force,
                 progress=None if args.quiet else terminal_progress())
    s = report["summary"]
    print(f"{s['done']} done, {s['failed']} failed, {s['skipped']} skipped of {s['total']} "
          f"takes in {report['seconds']:.1f} s; report: {args.output}/batch_report.json")
    for row in report["takes"]:
        if row["status"] == "failed":
            print(f"  failed: {row['take']}: {row['error']}", file=sys.stderr)
    return 1 if s["failed"] else 0


def _cmd_history(args: argparse.Namespace) -> int:
    from pathlib import Path

    from carapost.io.cara import load_project
    from carapost.session.script import to_python

    project = load_project(args.project)
    if not args.python:
        steps = project.script or []
        for i, step in enumerate(s for s in steps if "import" not in s):
            print(f"{i + 1:3d}. {step.get('call') or 'group ' + repr(step.get('group'))}")
        return 0
    if project.script is None:
        raise CliError(f"{args.project}: the project holds no record of its History (it "
                       "was not made by a Session of this version)")
    print(to_python(project.script, name=Path(args.project).name), end="")
    return 0


def _cmd_replay(args: argparse.Namespace) -> int:
    from carapost.session.script import replay

    out = replay(args.script, args.take, args.output)
    print(f"wrote {out}")
    return 0


RECOVER_HELP = ("when an autosave copy newer than the project exists (the program stopped "
                "before saving), use the copy")


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


def _quiet_stdout() -> int:
    """The reader of our output went away (``carapost evaluate ... | head``): not an
    error of ours; point stdout at devnull so the interpreter's flush stays quiet."""
    import os

    os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    return 0


def _cmd_fill_gaps(args: argparse.Namespace) -> int:
    from carapost.session.gapfill import fill_gaps_file

    rep = fill_gaps_file(args.input, args.output, method=args.method, max_gap=args.max_gap,
                         report=args.report)
    gaps = rep["gaps"]
    done = sum(1 for g in gaps if g["method"])
    print(f"filled {done} of {len(gaps)} gaps ({rep['filled_samples']} samples); "
          f"wrote {args.output}")
    for m in rep["messages"]:
        print(f"  {m}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``carapost`` command."""
    p = argparse.ArgumentParser(
        prog="carapost",
        description="Post-processing of head-mounted facial motion capture.",
        formatter_class=_HelpFormatter,
    )
    p.add_argument("--version", action="version", version=f"carapost {__version__}")
    p.add_argument("-v", "--verbose", action="count", default=0,
                   help="log progress messages (-v) or debug messages too (-vv); without "
                        "it only warnings and errors are logged")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")

    def add(name: str, func: Callable[[argparse.Namespace], int], help: str):
        sp = sub.add_parser(name, help=help, description=help,
                            formatter_class=_HelpFormatter)
        sp.set_defaults(func=func)
        return sp

    sp = add("gui", _cmd_gui, "open the main window (optionally on a project or take)")
    sp.add_argument("project", nargs="?", help=".cara project or take file/folder")

    sp = add("demo", _cmd_demo, "generate a demo take, process it and open it (or run headless)")
    sp.add_argument("--headless", action="store_true", help="never open a window")
    sp.add_argument("--frames", type=int, default=120, help="length of the demo take")
    sp.add_argument("-o", "--output",
                    help="folder for the demo results (default: beside the cached take)")
    sp.add_argument("--rebuild", action="store_true",
                    help="process the takes again even when the results are up to date")

    sp = add("synth", _cmd_synth, "generate a synthetic take with ground truth")
    sp.add_argument("rest", nargs=argparse.REMAINDER, help="OUTDIR and generator options")

    sp = add("import", _cmd_import, "import a take's camera files into a new .cara project")
    sp.add_argument("take", help="one camera file of the take, or its folder")
    sp.add_argument("-o", "--output", required=True, help="project file to write")

    sp = add("process", _cmd_process,
             "headless pipeline: import, detect, solve, initialise, track, export")
    sp.add_argument("take", help="one camera file of the take, or its folder")
    sp.add_argument("--rom", help="ROM .cara project to initialise from")
    sp.add_argument("--brim", help="brim model (.csv label,x,y,z in mm, or .svg)")
    sp.add_argument("-o", "--output", required=True, help="project file to write")
    sp.add_argument("--c3d", help="also export C3D here")
    sp.add_argument("--fbx", help="also export FBX here")
    sp.add_argument("--label-template", metavar="T.cara",
                    help="labelled take of the same marker set (a ROM or another take): "
                         "label the tracked points from it (Label From Template)")
    sp.add_argument("-q", "--quiet", action="store_true", help="no progress bars or lines")
    sp.add_argument("--patch-tracking", action="store_true",
                    help="patch track point-cameras without a blob (a little more "
                         "coverage, about 2.5x slower: every image is decoded again "
                         "while tracking)")
    sp.add_argument("--stabilize", choices=("auto", "assisted"),
                    help="stabilise the tracked take (Stabilize Data [Automatic], or "
                         "[Assisted] seeded with the automatically chosen stable points "
                         "and base frame 0); the exports are then stabilised")

    sp = add("batch", _cmd_batch,
             "process many takes on Dask (a local cluster, or --scheduler); resumable")
    sp.add_argument("inputs", nargs="+", metavar="INPUT",
                    help="take file, folder (searched recursively) or wildcard")
    sp.add_argument("-o", "--output", required=True, metavar="OUTDIR",
                    help="folder for <take>.cara (.c3d, .fbx), the manifest and the report")
    sp.add_argument("--rom", help="ROM .cara project to initialise every take from")
    sp.add_argument("--brim", help="brim model for every take (.csv or .svg)")
    sp.add_argument("--c3d", action="store_true", help="also export <take>.c3d")
    sp.add_argument("--fbx", action="store_true", help="also export <take>.fbx")
    sp.add_argument("--patch-tracking", action="store_true",
                    help="patch track point-cameras without a blob (slower)")
    sp.add_argument("--stabilize", choices=("auto", "assisted"),
                    help="stabilise every tracked take (exports in stabilised coordinates)")
    sp.add_argument("--scheduler", metavar="ADDRESS",
                    help="use a running Dask scheduler (tcp://host:8786) instead of a "
                         "local cluster")
    sp.add_argument("--workers", type=int, metavar="N",
                    help="local cluster workers (default: one per core)")
    sp.add_argument("--retries", type=int, default=1, metavar="K",
                    help="times a take is rerun when its worker dies (default 1)")
    sp.add_argument("--force", action="store_true",
                    help="process every take, also those already up to date")
    sp.add_argument("-q", "--quiet", action="store_true", help="no progress bar")

    sp = add("history", _cmd_history,
             "list the History a project was made with (--python: as a script)")
    sp.add_argument("project", help=".cara project")
    sp.add_argument("--python", action="store_true",
                    help="print it as a Python script of Session calls (for replay)")

    sp = add("replay", _cmd_replay, "run a history script on a take and save the project")
    sp.add_argument("script", help="script written by carapost history --python")
    sp.add_argument("take", help="one camera file of the take, or its folder")
    sp.add_argument("-o", "--output", required=True, help="project file to write")

    sp = add("evaluate", _cmd_evaluate, "compare a project with a synthetic take's truth.npz")
    sp.add_argument("project", help=".cara project to evaluate")
    sp.add_argument("truth", help="truth.npz of the synthetic take")
    sp.add_argument("--recover", action="store_true", help=RECOVER_HELP)

    for name, func, what in (
        ("export-c3d", _cmd_export_c3d, "C3D"),
        ("export-fbx", _cmd_export_fbx, "FBX"),
    ):
        sp = add(name, func, f"export a project's points as {what}")
        sp.add_argument("project", help=".cara project to export")
        sp.add_argument("--recover", action="store_true", help=RECOVER_HELP)
        sp.add_argument("output", help=f"{what} file to write")
        sp.add_argument("--range", choices=("active", "all"), default="all",
                        help="frames to export: the active range or the whole take")
        sp.add_argument("--brim", action="store_true", help="include brim points")
        sp.add_argument("--stabilized", action="store_true",
                        help="export stabilised (and aligned) coordinates; the project must "
                             "be stabilised")
        if name == "export-fbx":
            sp.add_argument("--up", choices=("y", "z"), default="y", help="up axis")
            sp.add_argument("--cameras", action="store_true", help="include animated cameras")
            sp.add_argument("--sticks", action="store_true", help="include the stick mesh")

    sp = add("fill-gaps", _cmd_fill_gaps,
             "fill the gaps of a .c3d or .cara file (any vendor's C3D) and write one")
    sp.add_argument("input", help="a .c3d or .cara file")
    sp.add_argument("-o", "--output", required=True, help=".c3d or .cara file to write")
    sp.add_argument("--method", choices=("auto", "guide", "lowrank", "spline"), default="guide",
                    help="fill method (default: guide, the neighbour prediction; auto, the "
                         "best method per gap by a hold-out test, is recommended for faces)")
    sp.add_argument("--max-gap", type=int, default=None, metavar="N",
                    help="leave gaps longer than N frames (default: fill all)")
    sp.add_argument("--report", metavar="REPORT.json",
                    help="write each gap's method, estimated error (mm) and status")

    sp = add("export-xcp", _cmd_export_xcp, "export the cameras of one frame as XCP")
    sp.add_argument("project", help=".cara project to export")
    sp.add_argument("--recover", action="store_true", help=RECOVER_HELP)
    sp.add_argument("output", help="XCP file to write")
    sp.add_argument("--frame", type=int, default=None,
                    help="frame (default: the project's current frame)")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``carapost`` console script."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["synth"]:
        # the generator owns its options (and its --help)
        from carapost.synth.cli import main_synth

        return main_synth(argv[1:])
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=(logging.WARNING, logging.INFO, logging.DEBUG)[min(int(args.verbose), 2)],
        format="%(levelname)s %(name)s: %(message)s",
    )
    if args.command is None:
        parser.print_help()
        return 0
    from carapost.commands.stack import CommandError
    from carapost.io.errors import CaraFileError

    try:
        return int(args.func(args) or 0)
    except BrokenPipeError:
        return _quiet_stdout()
    except (CliError, CaraFileError, CommandError, OSError, ValueError) as exc:
        print(f"carapost {args.command}: error: {_one_line(exc)}", file=sys.stderr)
        return 2
    except MemoryError:
        print(f"carapost {args.command}: error: out of memory", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("carapost: cancelled", file=sys.stderr)
        return 130
    except Exception as exc:
        if args.verbose:
            raise
        print(f"carapost {args.command}: error: unexpected {type(exc).__name__}: "
              f"{_one_line(exc)} (run with -v for the details)", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())

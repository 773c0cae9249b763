"""``carapost synth``: write a synthetic take from the command line."""

from __future__ import annotations

import argparse
import sys
import time

from carapost.io.errors import CaraFileError
from carapost.synth.face import MARKER_SETS
from carapost.synth.motion import PRESETS
from carapost.synth.scene import SynthConfig
from carapost.synth.take import SynthCancelled, generate_take


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"size must be WIDTHxHEIGHT, got {text!r}") from None
    return w, h


class _Defaults(argparse.ArgumentDefaultsHelpFormatter):
    """Show each option's default, except where there is none (None, an off flag)."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        if action.default in (None, False, argparse.SUPPRESS) or action.required:
            return action.help
        return super()._get_help_string(action)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``carapost synth``."""
    p = argparse.ArgumentParser(
        prog="carapost synth",
        description="Render a synthetic head-rig take with exact ground truth (truth.npz).",
        formatter_class=_Defaults)
    p.add_argument("outdir", help="take folder to write")
    p.add_argument("--preset", choices=PRESETS, default="speech", help="motion preset")
    p.add_argument("--markers", choices=sorted(MARKER_SETS), default="standard",
                   help="marker set")
    p.add_argument("--frames", type=int, default=300, help="number of frames")
    p.add_argument("--seed", type=int, default=0, help="random seed")
    p.add_argument("--size", type=_size, default="1280x720", help="image size WxH")
    p.add_argument("--fps", type=float, default=60.0, help="frame rate (Hz)")
    p.add_argument("--cameras", type=int, default=4, help="number of cameras")
    p.add_argument("--codec", choices=("ffv1", "mp4v"), default="ffv1",
                   help="ffv1: lossless .mkv; mp4v: small lossy .mp4")
    p.add_argument("--timecode", default="00:00:00:00", help="start timecode HH:MM:SS:FF")
    p.add_argument("--noise", type=float, default=2.0, help="sensor noise (grey levels)")
    p.add_argument("--blur", type=float, default=0.6, help="optical blur sigma (px)")
    p.add_argument("--motion-blur", action="store_true", help="half-frame shutter blur")
    p.add_argument("--highlights", action="store_true", help="saturated skin highlights")
    p.add_argument("--merge-pair", action="store_true",
                   help="add a marker that merges with a neighbour in camera 0")
    p.add_argument("--out-of-sync", type=int, default=None, metavar="CAMERA",
                   help="this camera's video lags by one frame")
    p.add_argument("--variant", type=int, default=0,
                   help="0: the standard rig; N > 0: another rig, brim layout and marker "
                        "placement drawn from N")
    p.add_argument("--partial-occlusion", action="store_true",
                   help="an eyelid fold and curling lips cover part of the lid and lip "
                        "markers (truth: the visible part's centroid)")
    p.add_argument("--missed-markers", type=int, default=0, metavar="N",
                   help="N markers fade to a low contrast over one stretch each (the blob "
                        "detector misses them there)")
    p.add_argument("--take", default="synth", help="take name (file stem)")
    p.add_argument("--workers", type=int, default=2, help="processes rendering in parallel")
    p.add_argument("--quiet", action="store_true", help="no progress output")
    return p


def main_synth(argv: list[str]) -> int:
    """Run ``carapost synth`` with ``argv`` (without the program/command name).

    Returns the exit status: 0 on success, 2 for bad arguments, 1 if writing failed.
    """
    parser = build_parser()
    args = parser.parse_args(argv)
    config = SynthConfig(
        preset=args.preset, markers=args.markers, frames=args.frames, seed=args.seed,
        size=args.size, fps=args.fps, n_cameras=args.cameras, noise=args.noise,
        blur=args.blur, motion_blur=args.motion_blur, highlights=args.highlights,
        merge_pair=args.merge_pair, out_of_sync_camera=args.out_of_sync, codec=args.codec,
        timecode_start=args.timecode, take_name=args.take, variant=args.variant,
        partial_occlusion=args.partial_occlusion, missed_markers=args.missed_markers,
    )
    try:
        config.validate()
    except ValueError as exc:
        parser.print_usage(sys.stderr)
        print(f"carapost synth: error: {exc}", file=sys.stderr)
        return 2
    start = time.perf_counter()
    last = [0.0]

    def progress(done: int, total: int) -> bool:
        now = time.perf_counter()
        if not args.quiet and (now - last[0] > 1.0 or done == total):
            last[0] = now
            print(f"\rrendered {done}/{total} images", end="", file=sys.stderr, flush=True)
        return True

    try:
        path = generate_take(args.outdir, config, progress=progress, workers=args.workers)
    except (CaraFileError, SynthCancelled) as exc:
        print(f"\ncarapost synth: error: {exc}", file=sys.stderr)
        return 1
    except OSError as exc:
        # the same one line as every other subcommand (an unwritable or full folder)
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"\ncarapost synth: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("\ncarapost: cancelled", file=sys.stderr)
        return 130
    if not args.quiet:
        print(f"\nwrote {path} in {time.perf_counter() - start:.1f} s", file=sys.stderr)
    print(path)
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main_synth(sys.argv[1:]))

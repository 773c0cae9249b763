#!/usr/bin/env python3
"""Query the point data of a ``.cara`` project and plot 2D tracks.

Prints, per face point, its label, the frames with a 3D position, the number of gaps,
the mean residual (mm) and how many cameras contribute on average; then plots the 2D
track (image x and y in pixels against frame) of some points in one camera to a PNG.
Needs matplotlib (``pip install carapost[examples]``).

    python export_general.py Example.cara --camera 0 --points 5 -o tracks.png
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from carapost.io.cara import load_project
from carapost.io.errors import CaraFileError
from carapost.model import queries
from carapost.model.project import KIND_FACE


def point_table(project) -> list[dict]:
    """One row per face point: label, frames with 3D, gaps, mean residual, cameras."""
    cols = np.flatnonzero(project.points.kind == KIND_FACE)
    present = queries.present(project)  # (F, P) bool
    gaps = queries.gap_counts(project)  # (P,)
    cams = queries.contribution_count(project)  # (F, P)
    rows = []
    for c in cols:
        res = project.points.residual[:, c]
        res = res[np.isfinite(res)]
        here = present[:, c]
        rows.append({"label": project.point_label(int(c)), "column": int(c),
                     "frames": int(here.sum()), "gaps": int(gaps[c]),
                     "mean_residual_mm": float(res.mean()) if res.size else float("nan"),
                     "mean_cameras": float(cams[here, c].mean()) if here.any() else 0.0})
    return rows


def plot_tracks(project, columns: list[int], camera: int, path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")  # no display needed
    import matplotlib.pyplot as plt

    frames = np.arange(project.n_frames)
    fig, (ax_x, ax_y) = plt.subplots(2, 1, sharex=True, figsize=(8, 5))
    for c in columns:
        obs = project.points.obs[:, c, camera]  # (F, 2) px, NaN where not seen
        label = project.point_label(int(c))
        ax_x.plot(frames, obs[:, 0], label=label)
        ax_y.plot(frames, obs[:, 1], label=label)
    ax_x.set_ylabel("x (px)")
    ax_y.set_ylabel("y (px)")
    ax_y.set_xlabel("frame")
    ax_y.invert_yaxis()  # image y grows downwards
    name = project.take.cameras[camera].name
    ax_x.set_title(f"{project.take.name}: 2D tracks in {name}")
    ax_x.legend(fontsize="small", loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("project", help=".cara project")
    ap.add_argument("--camera", type=int, default=0, help="camera to plot (default 0)")
    ap.add_argument("--points", type=int, default=6,
                    help="plot the first N face points (default 6)")
    ap.add_argument("-o", "--output", help="PNG to write (default: no plot)")
    args = ap.parse_args(argv)
    try:
        p = load_project(args.project)
    except CaraFileError as exc:
        print(f"{ap.prog}: error: {exc}", file=sys.stderr)
        return 2
    if not 0 <= args.camera < p.n_cameras:
        print(f"{ap.prog}: error: no camera {args.camera} (0-{p.n_cameras - 1})",
              file=sys.stderr)
        return 2
    rows = point_table(p)
    print("label,frames,gaps,mean_residual_mm,mean_cameras")
    for r in rows:
        print(f"{r['label']},{r['frames']},{r['gaps']},{r['mean_residual_mm']:.4f},"
              f"{r['mean_cameras']:.2f}")
    if args.output:
        try:
            import matplotlib  # noqa: F401
        except ImportError:
            print(f"{ap.prog}: error: plotting needs matplotlib "
                  "(pip install carapost[examples])", file=sys.stderr)
            return 2
        plot_tracks(p, [r["column"] for r in rows[:args.points]], args.camera, args.output)
        print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

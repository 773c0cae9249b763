"""Every sample of a processed rendered take above a threshold, with its cause.

    python benchmarks/variety_tail.py TAKE_FOLDER PROJECT.cara [--threshold 0.5] [--list 40]

For each face point matched to a truth marker (one-to-one, as the accuracy scores), every
frame where its 3D error is above ``--threshold`` mm is listed with what it was made
from: the reconstruction (triangulated or single sensor), the cameras that observed it
and those the truth says see the marker, whether both caddies see it, the stored
residual (mm) and sigma (mm), the length of the run of such frames it belongs to, and the
2D error (px) of each observation against the truth projection of the marker's centre.
The cause is named from those:

- ``single-sensor``: one camera, depth from the prediction;
- ``wrong-match``: an observation more than 2 px from its marker's projection;
- ``biased-Ncam``: an observation 0.4-2 px off (a blob merged with a neighbour, cut by an
  occluding edge or at a grazing angle);
- ``depth-Ncam``: every observation within 0.4 px: the geometry (short baseline,
  camera pose) and the 2D noise.

Prints one JSON line per listed sample (the worst ``--list``) and a summary line
``{"metric": "variety_tail", "causes": {cause: [count, max_mm]}, ...}`` over all of them.
Only the take folder's ``truth.npz`` is read besides the project.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np


def _runs(mask: np.ndarray) -> np.ndarray:
    """(F,) length of the run of True each frame belongs to (0 where False)."""
    out = np.zeros(mask.shape, int)
    edges = np.flatnonzero(np.diff(np.r_[0, mask.astype(int), 0]))
    for a, b in zip(edges[::2], edges[1::2], strict=True):
        out[a:b] = b - a
    return out


def tail(take: Path, cara: Path, threshold: float = 0.5) -> list[dict]:
    """The samples above ``threshold`` mm, worst first (see the module doc)."""
    from carapost.api import open_project
    from carapost.model.project import KIND_FACE
    from carapost.synth.scoring import score_tracks

    tr = np.load(take / "truth.npz")
    pj = open_project(cara)
    face = pj.points.kind == KIND_FACE
    A = pj.points.arrays
    pos = A["positions"][:, face].astype(np.float64)
    obs = A["obs"][:, face].astype(np.float64)
    recon, res, sig = A["recon"][:, face], A["residual"][:, face], A["sigma"][:, face]
    X, vis, uv = tr["points3d"], tr["visible"].astype(bool), tr["uv"]
    C = vis.shape[-1]
    caddy = np.arange(C) // ((C + 1) // 2)
    present = np.flatnonzero(np.isfinite(pos[..., 0]).any(0))
    s = score_tracks(pos[:, present], X, vis)
    rows = []
    for k, i in enumerate(present):
        m = int(s.match[k])
        if m < 0:
            continue
        e = np.linalg.norm(pos[:, i] - X[:, m], axis=-1)
        bad = np.nan_to_num(e) > threshold
        run = _runs(bad)
        for f in np.flatnonzero(bad):
            has = np.isfinite(obs[f, i]).all(-1)
            cams = np.flatnonzero(has)
            d2 = np.linalg.norm(obs[f, i, cams] - uv[f, m, cams], axis=-1)
            worst = float(np.nanmax(d2)) if d2.size else np.nan
            if recon[f, i] == 2:
                cause = "single-sensor"
            elif worst > 2.0:
                cause = "wrong-match"
            elif worst > 0.4:
                cause = f"biased-{cams.size}cam"
            else:
                cause = f"depth-{cams.size}cam"
            seen = np.flatnonzero(vis[f, m])
            rows.append({
                "error_mm": round(float(e[f]), 3), "cause": cause, "point": int(i),
                "marker": m, "frame": int(f), "recon": int(recon[f, i]),
                "cameras": cams.tolist(), "truth_cameras": seen.tolist(),
                "caddies": int(np.unique(caddy[seen]).size),
                "residual_mm": round(float(res[f, i]), 3),
                "sigma_mm": None if not np.isfinite(sig[f, i]) else round(float(sig[f, i]), 3),
                "run_frames": int(run[f]),
                "error_2d_px": [round(float(v), 2) for v in d2],
            })
    rows.sort(key=lambda r: -r["error_mm"])
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("take", type=Path)
    ap.add_argument("project", type=Path)
    ap.add_argument("--threshold", type=float, default=0.5)
    ap.add_argument("--list", type=int, default=40)
    args = ap.parse_args(argv)
    rows = tail(args.take, args.project, args.threshold)
    for r in rows[:args.list]:
        print(json.dumps(r))
    causes: dict[str, list] = {}
    for r in rows:
        c = causes.setdefault(r["cause"], [0, 0.0])
        c[0] += 1
        c[1] = max(c[1], r["error_mm"])
    print(json.dumps({"metric": "variety_tail", "take": str(args.take),
                      "threshold_mm": args.threshold, "samples": len(rows),
                      "over_1mm": sum(r["error_mm"] > 1.0 for r in rows),
                      "causes": causes}))
    return 0


if __name__ == "__main__":
    sys.exit(main())

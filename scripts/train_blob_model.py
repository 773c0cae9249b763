"""Fit the blob detector's probability model on synthetic images with known truth.

Renders views of ``carapost.synth`` takes (all marker sets and motion presets, noise,
optical and motion blur, highlights, merged pair) plus images of the detector's own
renderer ``carapost.algorithms._blob_synth`` (white markers, dark exposure), collects
every blob candidate with its features, labels it true when it lies on a
truth marker centre, and fits two logistic regressions (Newton / IRLS with a small
ridge): one for candidates from ordinary seeds, one for candidates from seeds found by
splitting an over-size region (the ``split`` feature). The weights go to
``src/carapost/resources/blob_model.json``. A held-out set of images
gives the reliability table (predicted probability vs observed fraction of true
candidates) printed here and drawn to ``docs/blob-reliability.png``.

Run from the repository root::

    python scripts/train_blob_model.py            # ~1-2 minutes on 2 cores
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import numpy as np

from carapost.algorithms._blob_eval import _match, synth_scene, synth_view
from carapost.algorithms._blob_synth import match_to_truth, render_face
from carapost.algorithms.blobs import (
    BLACK,
    FEATURE_NAMES,
    MODEL_INPUTS,
    MODEL_KINDS,
    WHITE,
    blob_candidates,
    expand_features,
)

ROOT = Path(__file__).resolve().parents[1]
MODEL_PATH = ROOT / "src" / "carapost" / "resources" / "blob_model.json"
PLOT_PATH = ROOT / "docs" / "blob-reliability.png"


def _synth_config(i: int, rng: np.random.Generator) -> dict:
    """Options of the i-th carapost.synth training scene (all marker sets and presets)."""
    return {
        "markers": ("standard", "dense156", "sparse35")[i % 3],
        "preset": ("speech", "fast", "rom", "blink")[(i // 3) % 4],
        "noise": float(rng.choice([1.0, 2.0, 2.0, 3.5, 6.0])),
        "blur": float(rng.choice([0.4, 0.6, 0.6, 0.9])),
        "motion_blur": bool(rng.random() < 0.35),
        "highlights": bool(rng.random() < 0.35),
        "merge_pair": bool(rng.random() < 0.3),
    }


def _own_scenario(i: int, rng: np.random.Generator) -> dict:
    """Options of the i-th image of the detector's own renderer (white / dark cases)."""
    return {"preset": ("standard", "dense156")[i % 2], "noise": float(rng.choice([1.0, 3.0])),
            "white": i % 4 < 2, "dark": i % 4 >= 2, "highlights": bool(rng.random() < 0.3)}


def _label(c, centre: np.ndarray, minor: np.ndarray, spread: np.ndarray) -> np.ndarray:
    """True for candidates on a truth blob centre (one candidate per blob)."""
    tol = np.clip(0.5 * minor, 1.0, 3.0) + spread
    d2t, _ = _match(c.centre, centre, tol)
    return d2t >= 0


def collect(n_scenes: int, seed: int, views: int = 6) -> tuple[np.ndarray, np.ndarray]:
    """Features [N, F] and true/false labels [N] of all candidates.

    ``n_scenes`` carapost.synth scenes, ``views`` random (frame, camera) images of each,
    plus one image of the detector's own renderer per two scenes for white markers and
    dark exposure (carapost.synth draws only dark markers at normal exposure).
    """
    rng = np.random.default_rng(seed)
    feats, labels = [], []
    for i in range(n_scenes):
        scene = synth_scene(seed=seed * 1000 + i, frames=180, **_synth_config(i, rng))
        for _ in range(views):
            v = synth_view(scene, int(rng.integers(0, 180)), int(rng.integers(0, 4)),
                           regions=False)
            for pol in (BLACK, WHITE):  # white candidates of a dark-marker image: negatives
                c = blob_candidates(v.image, pol, 2.0, 50.0)
                feats.append(c.features)
                if pol == BLACK:
                    labels.append(_label(c, v.centre, v.axes[:, 1], v.spread))
                else:
                    labels.append(np.zeros(len(c.centre), bool))
    for i in range(n_scenes // 2):
        s = render_face(rng, **_own_scenario(i, rng))
        for pol in (BLACK, WHITE):
            c = blob_candidates(s.image, pol, 2.0, 50.0)
            truth = s.colour == pol
            d2t, _ = match_to_truth(c.centre, s.centre[truth], s.axes[truth, 1])
            feats.append(c.features)
            labels.append(d2t >= 0)
    return np.vstack(feats), np.concatenate(labels)


def fit_logistic(x: np.ndarray, y: np.ndarray, ridge: float = 1e-3, iters: int = 50):
    """Newton's method for L2-regularised logistic regression; returns (w, b)."""
    n, f = x.shape
    xa = np.hstack([x, np.ones((n, 1))])
    beta = np.zeros(f + 1)
    reg = np.full(f + 1, ridge * n)
    reg[-1] = 0.0
    for _ in range(iters):
        z = np.clip(xa @ beta, -40, 40)
        p = 1 / (1 + np.exp(-z))
        g = xa.T @ (p - y) + reg * beta
        hess = (xa * (p * (1 - p))[:, None]).T @ xa + np.diag(reg)
        step = np.linalg.solve(hess, g)
        beta -= step
        if np.abs(step).max() < 1e-8:
            break
    return beta[:-1], float(beta[-1])


def reliability(p: np.ndarray, y: np.ndarray, n_bins: int = 10):
    edges = np.linspace(0, 1, n_bins + 1)
    rows = []
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        sel = (p >= lo) & (p < hi if hi < 1 else p <= hi)
        if sel.sum():
            rows.append((lo, hi, int(sel.sum()), float(p[sel].mean()), float(y[sel].mean())))
    return rows


def draw_plot(rows, path: Path) -> None:
    """Reliability diagram drawn with OpenCV (matplotlib is not a dependency)."""
    size, m = 480, 60
    img = np.full((size + 2 * m, size + 2 * m, 3), 255, np.uint8)

    def pt(px, py):
        return int(m + px * size), int(m + (1 - py) * size)

    for t in np.linspace(0, 1, 6):
        cv2.line(img, pt(t, 0), pt(t, 1), (225, 225, 225), 1)
        cv2.line(img, pt(0, t), pt(1, t), (225, 225, 225), 1)
        cv2.putText(img, f"{t:.1f}", (pt(t, 0)[0] - 12, pt(t, 0)[1] + 20),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
        cv2.putText(img, f"{t:.1f}", (pt(0, t)[0] - 40, pt(0, t)[1] + 5),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.rectangle(img, pt(0, 1), pt(1, 0), (0, 0, 0), 1)
    cv2.line(img, pt(0, 0), pt(1, 1), (150, 150, 150), 1, cv2.LINE_AA)
    prev = None
    for _lo, _hi, count, pm, frac in rows:
        c = pt(pm, frac)
        r = int(3 + 2 * np.log10(max(count, 1)))
        cv2.circle(img, c, r, (200, 80, 0), -1, cv2.LINE_AA)
        if prev is not None:
            cv2.line(img, prev, c, (200, 80, 0), 2, cv2.LINE_AA)
        prev = c
    cv2.putText(img, "Blob score reliability (held-out synthetic candidates)", (m - 20, 35),
                cv2.FONT_HERSHEY_SIMPLEX, 0.55, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(img, "mean predicted probability", (m + size // 2 - 110, size + 2 * m - 12),
                cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(img, "fraction true", (8, m - 12), cv2.FONT_HERSHEY_SIMPLEX, 0.5,
                (0, 0, 0), 1, cv2.LINE_AA)
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), img)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--train-scenes", type=int, default=24)
    ap.add_argument("--test-scenes", type=int, default=12)
    ap.add_argument("--no-write", action="store_true", help="report only, keep the model")
    args = ap.parse_args()

    x_tr, y_tr = collect(args.train_scenes, seed=1)
    x_te, y_te = collect(args.test_scenes, seed=2)
    print(f"train: {len(y_tr)} candidates ({y_tr.mean():.1%} true); "
          f"test: {len(y_te)} ({y_te.mean():.1%} true)")
    models = {}
    p = np.zeros(len(y_te))
    for k, kind in enumerate(MODEL_KINDS):
        tr = (x_tr[:, -1] > 0.5) == bool(k)
        te = (x_te[:, -1] > 0.5) == bool(k)
        n_in = MODEL_INPUTS[kind]
        e_tr = expand_features(x_tr[tr], n_in)
        mean = e_tr.mean(axis=0)
        scale = e_tr.std(axis=0) + 1e-9
        w, b = fit_logistic((e_tr - mean) / scale, y_tr[tr].astype(float))
        z = ((expand_features(x_te[te], n_in) - mean) / scale) @ w + b
        p[te] = 1 / (1 + np.exp(-np.clip(z, -40, 40)))
        print(f"{kind}: train {int(tr.sum())} candidates ({y_tr[tr].mean():.1%} true), "
              f"test {int(te.sum())}")
        models[kind] = {
            "weights": [round(float(v), 6) for v in w],
            "bias": round(b, 6),
            "mean": [round(float(v), 6) for v in mean],
            "scale": [round(float(v), 6) for v in scale],
        }
    eps = 1e-12
    ll = -np.mean(y_te * np.log(p + eps) + (1 - y_te) * np.log(1 - p + eps))
    brier = float(np.mean((p - y_te) ** 2))
    print(f"held-out log-loss {ll:.4f}, Brier {brier:.4f}")
    rows = reliability(p, y_te.astype(float))
    print("| predicted p bin | candidates | mean predicted | fraction true |")
    print("|---|---|---|---|")
    for lo, hi, cnt, pm, fr in rows:
        print(f"| {lo:.1f}-{hi:.1f} | {cnt} | {pm:.3f} | {fr:.3f} |")
    for th in (0.2, 0.4, 0.5, 0.8):
        acc = p >= th
        print(f"threshold {th}: recall {np.mean(acc[y_te]):.4f}, "
              f"precision {np.mean(y_te[acc]):.4f}")
    sp = x_te[:, -1] > 0.5
    if sp.any():
        acc = p[sp] >= 0.4
        print(f"split candidates at 0.4: recall {np.mean(acc[y_te[sp]]):.4f}, "
              f"precision {np.mean(y_te[sp][acc]) if acc.any() else float('nan'):.4f}")
    if not args.no_write:
        model = {
            "features": list(FEATURE_NAMES),
            "models": models,
            "trained_on": f"{args.train_scenes} carapost.synth scenes x 6 views + "
                          f"{args.train_scenes // 2} own-renderer images "
                          "(scripts/train_blob_model.py)",
        }
        MODEL_PATH.write_text(json.dumps(model, indent=1) + "\n")
        draw_plot(rows, PLOT_PATH)
        print(f"wrote {MODEL_PATH.relative_to(ROOT)} and {PLOT_PATH.relative_to(ROOT)}")


if __name__ == "__main__":
    main()

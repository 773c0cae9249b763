"""Fit the blob detector's probability model on synthetic images with known truth.

Renders views of ``carapost.synth`` takes (all marker sets and motion presets, noise,
optical and motion blur, highlights, merged pair) plus images of the detector's own
renderer ``carapost.synth.blob_images`` (white markers, dark exposure), collects
every blob candidate with its features (measured ones and the appearance of its
surroundings), labels it true when it lies on a truth marker centre, and fits two
small neural networks (one hidden layer of ``MODEL_HIDDEN`` tanh units, log-loss with
an L2 penalty, L-BFGS): one for candidates from ordinary seeds, one for candidates
from seeds found by splitting an over-size region (the ``split`` feature). Besides
carapost.synth views and the detector's own renderer, the training images include
markers touching a nostril-like dark feature and printed dot grids (calibration
targets, half of them staggered). The weights go to
``src/carapost/resources/blob_model.json``. A held-out set of images gives the
reliability table (predicted probability vs observed fraction of true candidates)
printed here and drawn to ``docs/blob-reliability.png``.

Run from the repository root::

    python scripts/train_blob_model.py            # ~4 minutes (one core)
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import numpy as np
from scipy.optimize import minimize

from carapost.algorithms.blobs import (
    BLACK,
    FEATURE_NAMES,
    MODEL_HIDDEN,
    MODEL_INPUTS,
    MODEL_KINDS,
    WHITE,
    ScoreNet,
    blob_candidates,
    net_logit,
)
from carapost.algorithms.blobs.score import load_model, use_model
from carapost.synth.blob_eval import synth_scene, synth_view
from carapost.synth.blob_images import (
    ellipse_coverage,
    match_nearest,
    match_to_truth,
    paint,
    render_face,
)

ROOT = Path(__file__).resolve().parents[1]
MODEL_PATH = ROOT / "src" / "carapost" / "resources" / "blob_model.json"
PLOT_PATH = ROOT / "docs" / "blob-reliability.png"
#: Min / Max Radius (major-axis length, px) of the candidates trained on: from the
#: default Min Radius up to twice the default Max Radius.
TRAIN_RANGE = (4.0, 100.0)
#: Images of markers touching a large dark feature (_touching_scene) per synth scene.
TOUCHING_PER_SCENE = 2


def _synth_config(i: int, rng: np.random.Generator) -> dict:
    """Options of the i-th carapost.synth training scene (all marker sets and presets)."""
    return {
        "markers": ("standard", "dense156", "sparse35")[i % 3],
        "preset": ("speech", "fast", "rom", "blink")[(i // 3) % 4],
        "noise": float(rng.choice([1.0, 2.0, 2.0, 3.5, 6.0])),
        "blur": float(rng.choice([0.4, 0.6, 0.6, 0.9])),
        # the fast preset's long streaks are rare otherwise: always blurred
        "motion_blur": bool(rng.random() < 0.5) or (i // 3) % 4 == 1,
        "highlights": bool(rng.random() < 0.35),
        "merge_pair": bool(rng.random() < 0.3),
    }


def _own_scenario(i: int, rng: np.random.Generator) -> dict:
    """Options of the i-th image of the detector's own renderer (white / dark cases)."""
    return {"preset": ("standard", "dense156")[i % 2], "noise": float(rng.choice([1.0, 3.0])),
            "white": i % 4 < 2, "dark": i % 4 >= 2, "highlights": bool(rng.random() < 0.3)}


def _touching_scene(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A small image of markers touching a large dark feature (a nostril or an eye),
    the case split seeds are for, which the face renderers draw only now and then.

    Returns the uint8 image, the marker centres [M, 2] and their minor semi-axes [M].
    """
    h, w = 160, 220
    skin = rng.uniform(110, 210)
    img = skin + np.linspace(-1, 1, w)[None, :] * rng.uniform(0, 25) + np.zeros((h, 1))
    cx, cy = rng.uniform(80, 140), rng.uniform(60, 100)
    fa, fb, fth = rng.uniform(12, 26), rng.uniform(7, 14), rng.uniform(-np.pi / 2, np.pi / 2)
    x0, y0, cov = ellipse_coverage(cx, cy, fa, fb, fth)
    paint(img, x0, y0, cov, skin * rng.uniform(0.15, 0.5))
    centres, minors = [], []
    for _ in range(int(rng.integers(2, 5))):
        # A marker just outside the feature's outline, gap -0.5 to 1.5 px.
        t = rng.uniform(0, 2 * np.pi)
        a = rng.uniform(2.8, 6.0)
        b = a * rng.uniform(0.4, 1.0)
        ex, ey = fa * np.cos(t), fb * np.sin(t)
        nx, ny = ex / fa ** 2, ey / fb ** 2
        nn = np.hypot(nx, ny)
        c, s_ = np.cos(fth), np.sin(fth)
        px, py = cx + ex * c - ey * s_, cy + ex * s_ + ey * c
        ux, uy = (nx * c - ny * s_) / nn, (nx * s_ + ny * c) / nn
        r = b + rng.uniform(-0.5, 1.5)
        mx, my = px + ux * r, py + uy * r
        mth = np.arctan2(uy, ux) + np.pi / 2  # long axis along the feature's outline
        if not (8 < mx < w - 8 and 8 < my < h - 8):
            continue
        x0, y0, cov = ellipse_coverage(mx, my, a, b, mth)
        paint(img, x0, y0, cov, skin * rng.uniform(0.05, 0.3))
        centres.append((mx, my))
        minors.append(b)
    img += rng.standard_normal(img.shape) * rng.uniform(1.0, 4.0)
    img = cv2.GaussianBlur(img, (0, 0), rng.uniform(0.4, 0.8))
    return (np.clip(np.rint(img), 0, 255).astype(np.uint8), np.array(centres).reshape(-1, 2),
            np.array(minors))


def _dot_grid_scene(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A printed dot grid (calibration target) seen at an angle: high-contrast round
    dots on lit paper, often darker in the middle than at the rim (uneven ink or
    light), with more optical blur than the face renderers use (the blur widens a dot's
    moments, which the fill features measure).

    Returns the uint8 image, the dot centres [M, 2] and their minor semi-axes [M].
    """
    h, w = 360, 480
    paper = rng.uniform(150, 245)
    yy, xx = np.mgrid[0:h, 0:w]
    img = paper * (1 - rng.uniform(0, 0.25) * (xx / w) - rng.uniform(0, 0.2) * (yy / h))
    r = rng.uniform(3.0, 16.0)
    # Half the grids are staggered (asymmetric circle grids): every other row shifted by
    # half a step, rows closer together, so diagonal neighbours sit ~1.5 radii apart.
    stagger = rng.random() < 0.5
    step = r * (rng.uniform(4.0, 6.0) if stagger else rng.uniform(3.0, 5.0))
    pitch = step * (rng.uniform(0.55, 0.75) if stagger else 1.0)
    squeeze, rot = rng.uniform(0.55, 1.0), rng.uniform(-np.pi / 2, np.pi / 2)
    ink = rng.uniform(5, 60) if rng.random() < 0.7 else paper * rng.uniform(0.4, 0.8)
    inner = rng.uniform(0.4, 0.8) if rng.random() < 0.6 else 0.0
    inner_level = rng.uniform(0.2, 0.8)
    centres, minors = [], []
    for i in range(-6, 7):  # at most 13 x 25 dots
        for j in range(-12, 13):
            u, v = (i + 0.5 * (j % 2 and stagger)) * step, j * pitch * squeeze
            x = w / 2 + u * np.cos(rot) - v * np.sin(rot)
            y = h / 2 + u * np.sin(rot) + v * np.cos(rot)
            if not (r + 4 < x < w - r - 4 and r + 4 < y < h - r - 4):
                continue
            x0, y0, cov = ellipse_coverage(x, y, r, r * squeeze, rot + np.pi / 2)
            paint(img, x0, y0, cov, ink)
            if inner > 0:  # ink or lighting not even: a darker middle
                x0, y0, cov = ellipse_coverage(x, y, inner * r, inner * r * squeeze,
                                                rot + np.pi / 2)
                paint(img, x0, y0, cov, ink * inner_level)
            centres.append((x, y))
            minors.append(r * squeeze)
    img = cv2.GaussianBlur(img, (0, 0), rng.uniform(0.5, 2.5))
    # Mostly clean prints (a real photo of a target has little noise: log-SNR 5-6).
    img += rng.standard_normal(img.shape) * rng.choice([0.0, 0.3, 0.6, 1.0, 2.0])
    return (np.clip(np.rint(img), 0, 255).astype(np.uint8), np.array(centres).reshape(-1, 2),
            np.array(minors))


def _label(c, centre: np.ndarray, minor: np.ndarray, spread: np.ndarray) -> np.ndarray:
    """True for candidates on a truth blob centre (one candidate per blob)."""
    tol = np.clip(0.5 * minor, 1.0, 3.0) + spread
    d2t, _ = match_nearest(c.centre, centre, tol)
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
                c = blob_candidates(v.image, pol, *TRAIN_RANGE)
                feats.append(c.features)
                if pol == BLACK:
                    labels.append(_label(c, v.centre, v.axes[:, 1], v.spread))
                else:
                    labels.append(np.zeros(len(c.centre), bool))
    extra = [_touching_scene] * (TOUCHING_PER_SCENE * n_scenes) + [_dot_grid_scene] * (
        n_scenes // 2)
    for make in extra:
        img, centre, minor = make(rng)
        c = blob_candidates(img, BLACK, *TRAIN_RANGE)
        feats.append(c.features)
        labels.append(_label(c, centre, minor, np.zeros(len(centre))))
    for i in range(n_scenes // 2):
        s = render_face(rng, **_own_scenario(i, rng))
        for pol in (BLACK, WHITE):
            c = blob_candidates(s.image, pol, *TRAIN_RANGE)
            truth = s.colour == pol
            d2t, _ = match_to_truth(c.centre, s.centre[truth], s.axes[truth, 1])
            feats.append(c.features)
            labels.append(d2t >= 0)
    return np.vstack(feats), np.concatenate(labels)


def fit_net(x: np.ndarray, y: np.ndarray, hidden: int = MODEL_HIDDEN, l2: float = 2e-4,
            seed: int = 0, iters: int = 2000) -> tuple[np.ndarray, ...]:
    """One-hidden-layer tanh network for P(true | x) by minimising the mean log-loss plus
    ``l2`` times the squared weights (L-BFGS, analytic gradient).

    Parameters
    ----------
    x : ndarray [N, n], normalised features
    y : ndarray [N], 0 / 1 labels

    Returns
    -------
    w1 [n, H], b1 [H], w2 [H], b2 (0-d)
    """
    n, f = x.shape
    rng = np.random.default_rng(seed)
    shapes = [(f, hidden), (hidden,), (hidden,), ()]
    sizes = [int(np.prod(sh)) for sh in shapes]

    def unpack(th):
        out, k = [], 0
        for sh, z in zip(shapes, sizes, strict=True):
            out.append(th[k:k + z].reshape(sh))
            k += z
        return out

    th0 = np.concatenate([rng.normal(0, 1 / np.sqrt(f), sizes[0]), np.zeros(hidden),
                          rng.normal(0, 1 / np.sqrt(hidden), hidden), np.zeros(1)])

    def loss_grad(th):
        w1, b1, w2, b2 = unpack(th)
        h = np.tanh(x @ w1 + b1)
        p = 1 / (1 + np.exp(-np.clip(h @ w2 + b2, -40, 40)))
        eps = 1e-12
        loss = (-np.mean(y * np.log(p + eps) + (1 - y) * np.log(1 - p + eps))
                + l2 * (np.sum(w1 ** 2) + np.sum(w2 ** 2)))
        dz = (p - y) / n
        dh = np.outer(dz, w2) * (1 - h ** 2)
        grad = [x.T @ dh + 2 * l2 * w1, dh.sum(0), h.T @ dz + 2 * l2 * w2, [dz.sum()]]
        return loss, np.concatenate([np.ravel(g) for g in grad])

    res = minimize(loss_grad, th0, jac=True, method="L-BFGS-B", options={"maxiter": iters})
    return tuple(unpack(res.x))


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
    ap.add_argument("--train-scenes", type=int, default=60)
    ap.add_argument("--test-scenes", type=int, default=12)
    ap.add_argument("--no-write", action="store_true", help="report only, keep the model")
    ap.add_argument("--init-seed", type=int, default=0, help="seed of the initial weights")
    ap.add_argument("--l2", type=float, default=2e-4, help="L2 penalty of the weights")
    ap.add_argument("--data", type=Path, help="candidates file (.npz): loaded if it exists, "
                    "else collected and saved there (the collection is ~3/4 of the time)")
    args = ap.parse_args()

    try:
        load_model()
    except RuntimeError:
        # The shipped model does not fit the detector's features (they changed): the
        # detector only uses it to choose between two copies of one blob seen on two
        # pyramid levels, so a neutral model (every candidate 0.5: the finer level's copy
        # is kept) serves for the collection. Run the script again afterwards so the
        # collection uses the new model, as the detector will.
        print("blob_model.json does not fit the detector's features: collecting with a "
              "neutral model; run this script again once it has written the new one")
        neutral = tuple(ScoreNet(np.zeros(MODEL_INPUTS[k]), np.ones(MODEL_INPUTS[k]),
                             np.zeros((MODEL_INPUTS[k], MODEL_HIDDEN)), np.zeros(MODEL_HIDDEN),
                             np.zeros(MODEL_HIDDEN), 0.0) for k in MODEL_KINDS)
        use_model(neutral)
    if args.data is not None and args.data.exists():
        z = np.load(args.data)
        x_tr, y_tr, x_te, y_te = z["x_tr"], z["y_tr"], z["x_te"], z["y_te"]
    else:
        x_tr, y_tr = collect(args.train_scenes, seed=1)
        x_te, y_te = collect(args.test_scenes, seed=2)
        if args.data is not None:
            np.savez_compressed(args.data, x_tr=x_tr, y_tr=y_tr, x_te=x_te, y_te=y_te)
    print(f"train: {len(y_tr)} candidates ({y_tr.mean():.1%} true); "
          f"test: {len(y_te)} ({y_te.mean():.1%} true)")
    models = {}
    p = np.zeros(len(y_te))
    for k, kind in enumerate(MODEL_KINDS):
        tr = (x_tr[:, -1] > 0.5) == bool(k)
        te = (x_te[:, -1] > 0.5) == bool(k)
        n_in = MODEL_INPUTS[kind]
        f_tr = x_tr[tr][:, :n_in]
        mean = f_tr.mean(axis=0)
        scale = f_tr.std(axis=0) + 1e-9
        w1, b1, w2, b2 = fit_net((f_tr - mean) / scale, y_tr[tr].astype(float),
                                 l2=args.l2, seed=args.init_seed)
        net = ScoreNet(mean, scale, w1, b1, w2, float(b2))
        p[te] = 1 / (1 + np.exp(-np.clip(net_logit(net, x_te[te]), -40, 40)))
        print(f"{kind}: train {int(tr.sum())} candidates ({y_tr[tr].mean():.1%} true), "
              f"test {int(te.sum())}")
        models[kind] = {name: np.round(np.asarray(v, np.float64), 6).tolist()
                        for name, v in net._asdict().items()}
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
            "model": f"per kind: features normalised by mean / scale, log-odds "
                     f"tanh(x w1 + b1) w2 + b2 ({MODEL_HIDDEN} hidden units)",
            "trained_on": f"{args.train_scenes} carapost.synth scenes x 6 views + "
                          f"{args.train_scenes // 2} own-renderer images "
                          "(scripts/train_blob_model.py)",
        }
        MODEL_PATH.write_text(json.dumps(model, indent=1) + "\n")
        draw_plot(rows, PLOT_PATH)
        print(f"wrote {MODEL_PATH.relative_to(ROOT)} and {PLOT_PATH.relative_to(ROOT)}")


if __name__ == "__main__":
    main()

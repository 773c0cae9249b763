"""Label From Template: give a tracked take the labels of a labelled take of the same
marker set, by registering the two face point clouds.

Both takes are in their brim (head-rig) frame, so the faces are already close; what
differs is the helmet's placement on the head (a few mm and degrees of rigid motion, more
for another session), the expression and the marker slip. The steps:

Reference clouds
    Each take is reduced to one cloud, each point at its median position over a few
    well-tracked frames (the frames where most points have 3D, spread through the take):
    the median of several expressions is close to the neutral face and ignores a few
    wrong samples.

Rigid registration
    Trimmed ICP (iterative closest point) from the identity and from the centroid
    alignment: mutual nearest neighbours within a gate, each fitted by Kabsch
    (`carapost.algorithms.rigid.fit_rigid`) with Huber weights, the gate shrinking
    from 3 to 1 marker spacing. When neither start explains half of the points (another
    rig, or a template far from the take) the triplet search
    `carapost.algorithms.rigid.register_model` proposes more starts.

Non-rigid registration
    One-to-one assignment of the registered template to the take (the Hungarian method,
    `scipy.optimize.linear_sum_assignment`, on the distances with a gate), then a smooth
    displacement field (Gaussian-kernel regression of the matched displacements, its
    width shrinking over the iterations) moves the template onto the take's expression
    and slip, and the assignment is repeated.

Confidence
    For a label assigned to a point at distance ``d``, with ``d2`` the distance to the
    nearest competitor (another take point for the template point, another template
    point for the take point), the confidence is ``(1 - d / d2) * exp(-(d / g)^2 / 2)``
    with ``g`` the Maximum Label Distance: 1 for an unambiguous close match, 0 when
    another point is as close. Labels below the threshold are left unassigned.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import linear_sum_assignment
from scipy.spatial import cKDTree

from carapost.algorithms.params import param, validate
from carapost.algorithms.rigid import fit_rigid, register_model

__all__ = [
    "LABEL_FROM_TEMPLATE",
    "LabelAssignment",
    "LabellingParameters",
    "label_from_template",
    "reference_cloud",
    "well_tracked_frames",
]

#: Properties section of the Label From Template parameters (beyond the reference guide).
LABEL_FROM_TEMPLATE = "Label From Template Parameters"

#: Cost of a pair outside the gate: never chosen over a pair inside it.
_FAR = 1e6


@dataclass(frozen=True)
class LabellingParameters:
    """Parameters of :func:`label_from_template`."""

    confidence_threshold: float = param(
        0.5, label="Label Confidence Threshold", section=LABEL_FROM_TEMPLATE, unit="0-1",
        min=0.0, max=1.0,
        help="Labels assigned with a lower confidence are left unassigned and listed.")
    max_distance_mm: float = param(
        6.0, label="Maximum Label Distance", section=LABEL_FROM_TEMPLATE, unit="mm",
        min=0.1, max=100.0,
        help="A point farther than this from its registered template marker gets no label.")
    reference_frames: int = param(
        9, label="Reference Frames", section=LABEL_FROM_TEMPLATE, unit="frames", min=1,
        max=1000, help="Well-tracked frames of each take whose median positions are "
                       "registered.")
    nonrigid_iterations: int = param(4, min=0, max=20)
    kernel_start_mm: float = param(40.0, min_exclusive=True, min=0.0)
    kernel_end_mm: float = param(12.0, min_exclusive=True, min=0.0)

    def __post_init__(self) -> None:
        validate(self)


@dataclass
class LabelAssignment:
    """What :func:`label_from_template` found.

    Attributes
    ----------
    template_index : ndarray of int, shape (P,)
        Template row assigned to each take point, -1 where none (or below the threshold).
    candidate : ndarray of int, shape (P,)
        The template row each take point was matched to before the threshold, -1 where
        nothing was within the gate.
    confidence : ndarray of float, shape (P,)
        Confidence of the candidate (0-1; 0 where there is none).
    distance_mm : ndarray of float, shape (P,)
        Distance between the take point and its registered candidate (mm; inf if none).
    R, t : ndarray, shape (3, 3), (3,)
        The rigid part of the registration, ``take ~ template @ R.T + t``.
    rejected : ndarray of int
        Template rows matched with a confidence below the threshold.
    unmatched : ndarray of int
        Template rows with no take point within the gate.
    """

    template_index: NDArray[np.int64]
    candidate: NDArray[np.int64]
    confidence: NDArray[np.float64]
    distance_mm: NDArray[np.float64]
    R: NDArray[np.float64]
    t: NDArray[np.float64]
    rejected: NDArray[np.int64]
    unmatched: NDArray[np.int64]

    @property
    def n_labelled(self) -> int:
        """Take points given a label."""
        return int((self.template_index >= 0).sum())


def well_tracked_frames(present: NDArray[np.bool_], count: int) -> NDArray[np.intp]:
    """Up to ``count`` frames, spread through the take, where most points have 3D.

    Parameters
    ----------
    present : ndarray of bool, shape (F, P)
        Which point has a 3D position at which frame.
    count : int
        Most frames returned.

    Returns
    -------
    ndarray of int
        Sorted frame indices among those with at least 95 % of the best frame's points.

    Examples
    --------
    >>> present = np.ones((10, 4), bool); present[3, :2] = False
    >>> well_tracked_frames(present, 3).tolist()
    [0, 5, 9]
    """
    n = present.sum(axis=1)
    if n.size == 0 or n.max() == 0:
        return np.zeros(0, dtype=np.intp)
    good = np.flatnonzero(n >= 0.95 * n.max())
    if len(good) <= count:
        return good.astype(np.intp)
    pick = np.linspace(0, len(good) - 1, count).round().astype(np.intp)
    return good[np.unique(pick)].astype(np.intp)


def reference_cloud(positions: NDArray, count: int) -> NDArray[np.float64]:
    """Each point's median position over a few well-tracked frames.

    Parameters
    ----------
    positions : ndarray, shape (F, P, 3)
        3D positions (mm), NaN where missing.
    count : int
        Frames used (`well_tracked_frames`); a point missing in all of them falls back to
        its median over the whole take.

    Returns
    -------
    ndarray, shape (P, 3)
        NaN for a point without any 3D.
    """
    X = np.asarray(positions)  # not converted as a whole: a long take is big
    present = np.isfinite(X[..., 0])
    frames = well_tracked_frames(present, count)
    out = np.full((X.shape[1], 3), np.nan)
    if frames.size:
        sub = X[frames].astype(np.float64)
        ok = np.isfinite(sub).all(-1).any(0)
        if ok.any():
            out[ok] = np.nanmedian(sub[:, ok], axis=0)
    rest = np.flatnonzero(~np.isfinite(out).all(-1) & present.any(0))
    for col in rest:  # points missing from every chosen frame (few)
        out[col] = np.median(X[present[:, col], col].astype(np.float64), axis=0)
    return out


def _icp(A: NDArray, B: NDArray, R: NDArray, t: NDArray, spacing: float,
         iterations: int = 30) -> tuple[NDArray, NDArray, float, int]:
    """Trimmed ICP of ``A`` onto ``B`` from ``(R, t)``; returns R, t, score, inliers."""
    tree_b = cKDTree(B)
    n_in = 0
    score = np.inf
    for it in range(iterations):
        gate = spacing * max(1.0, 3.0 - it / 5.0)
        moved = A @ R.T + t
        d, j = tree_b.query(moved)
        # mutual nearest neighbours only: a marker missing on one side pulls nothing
        back = cKDTree(moved).query(B[j])[1]
        ok = (back == np.arange(len(A))) & (d < gate)
        if ok.sum() < 3:
            break
        w = np.minimum(1.0, 0.5 * spacing / np.maximum(d[ok], 1e-9))  # Huber
        fit = fit_rigid(A[ok], B[j[ok]], w)
        change = np.abs(fit.R - R).max() + np.abs(fit.t - t).max()
        R, t = fit.R, fit.t
        if change < 1e-7 and gate <= spacing:
            break
    d, _ = tree_b.query(A @ R.T + t)
    inl = d < spacing
    n_in = int(inl.sum())
    score = float(np.mean(np.minimum(d, spacing)))
    return R, t, score, n_in


def _assign(A: NDArray, B: NDArray, gate: float) -> tuple[NDArray, NDArray]:
    """Hungarian assignment of template rows ``A`` to take rows ``B`` within ``gate``.

    Returns ``match`` (B,) template row per take row (-1 none) and the distances."""
    D = np.linalg.norm(B[:, None, :] - A[None, :, :], axis=-1)
    cost = np.where(D < gate, D, _FAR)
    rows, cols = linear_sum_assignment(cost)
    keep = cost[rows, cols] < _FAR
    match = np.full(len(B), -1, dtype=np.int64)
    match[rows[keep]] = cols[keep]
    dist = np.full(len(B), np.inf)
    dist[rows[keep]] = D[rows[keep], cols[keep]]
    return match, dist


def _field(src: NDArray, disp: NDArray, weights: NDArray, at: NDArray,
           width: float) -> NDArray:
    """Gaussian-kernel regression of displacements ``disp`` at ``src`` onto ``at``."""
    d2 = np.sum((at[:, None, :] - src[None, :, :]) ** 2, axis=-1)
    k = np.exp(-0.5 * d2 / width ** 2) * weights[None, :]
    s = k.sum(1, keepdims=True)
    return np.where(s > 1e-12, (k @ disp) / np.maximum(s, 1e-12), 0.0)


def label_from_template(
    template: NDArray,
    target: NDArray,
    params: LabellingParameters | None = None,
    progress: Callable[[int, int], bool] | None = None,
    *,
    template_frames: NDArray | None = None,
) -> LabelAssignment:
    """Assign the labels of a template take's points to a tracked take's points.

    Parameters
    ----------
    template : ndarray, shape (Ft, M, 3) or (M, 3)
        Labelled points of the template take (mm, brim frame, NaN where missing); a
        (M, 3) array is used as the reference cloud itself.
    target : ndarray, shape (F, P, 3) or (P, 3)
        Points of the take to label (mm, brim frame, NaN where missing).
    params : LabellingParameters, optional
    progress : callable, optional
        ``progress(done, total)``; returning False cancels (`label_from_template` then
        returns no labels).
    template_frames : ndarray, shape (K, M, 3), optional
        Single frames of the template (a ROM's expressions) to try besides its reference
        cloud: the one the take's cloud fits best after the rigid registration is used
        (a take of mostly open-mouth speech fits a ROM frame better than the ROM's
        median). When ``template`` is (Ft, M, 3), up to 24 of its well-tracked frames are
        tried.

    Returns
    -------
    LabelAssignment
        Per take point: the template row, its confidence and distance.

    Raises
    ------
    ValueError
        Fewer than 3 points with 3D on either side.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> face = rng.uniform(-60, 60, (40, 3)) * [1, 1, 0.4]
    >>> take = (face + [2.0, -1.0, 0.5])[rng.permutation(40)]   # moved and shuffled
    >>> out = label_from_template(face, take)
    >>> bool(np.all(face[out.template_index] + [2.0, -1.0, 0.5] - take < 1e-6))
    True
    """
    p = params or LabellingParameters()
    if template.ndim == 3 and template_frames is None:
        present = np.isfinite(template[..., 0])
        template_frames = template[well_tracked_frames(present, 24)]
    A = template if template.ndim == 2 else reference_cloud(template, p.reference_frames)
    B = target if target.ndim == 2 else reference_cloud(target, p.reference_frames)
    A = np.asarray(A, dtype=np.float64)
    B = np.asarray(B, dtype=np.float64)
    P = len(B)
    a_ok = np.flatnonzero(np.isfinite(A).all(-1))
    b_ok = np.flatnonzero(np.isfinite(B).all(-1))
    if len(a_ok) < 3 or len(b_ok) < 3:
        raise ValueError(f"Label From Template: need 3 points with 3D on both sides (the "
                         f"template has {len(a_ok)}, the take {len(b_ok)})")
    Aa, Bb = A[a_ok], B[b_ok]
    total = 2 + p.nonrigid_iterations

    def tick(done: int) -> bool:
        return progress is None or progress(done, total) is not False

    # typical marker spacing: median nearest-neighbour distance of the template
    spacing = float(np.median(cKDTree(Aa).query(Aa, k=2)[0][:, 1]))
    spacing = max(spacing, 1e-3)
    starts = [(np.eye(3), np.zeros(3)), (np.eye(3), Bb.mean(0) - Aa.mean(0))]
    fits = [_icp(Aa, Bb, R0, t0, spacing) for R0, t0 in starts]
    best = max(fits, key=lambda f: (f[3], -f[2]))
    if template_frames is not None and len(template_frames):
        # the template expression closest to the take's: each frame (its missing points
        # from the reference cloud) refitted from the best pose, lowest residual wins
        cands = np.asarray(template_frames, dtype=np.float64)[:, a_ok]
        cands = np.where(np.isfinite(cands), cands, Aa[None])
        for cand in cands:
            fit = _icp(cand, Bb, best[0], best[1], spacing, iterations=8)
            if fit[2] < best[2] and fit[3] >= best[3]:
                Aa, best = cand, fit
        fits = [best]
    if best[2] > 0.2 * spacing or best[3] < 0.8 * min(len(Aa), len(Bb)):
        # no start explains most points closely: ask the triplet search for more starts
        # (on a spread subset of the template: the search is quadratic in its points)
        sub = Aa[np.linspace(0, len(Aa) - 1, min(len(Aa), 40)).round().astype(np.intp)]
        for _, R0, t0 in register_model(sub, Bb, tolerance=max(1.0, 0.3 * spacing),
                                        samples=150, seed=0):
            fits.append(_icp(Aa, Bb, R0, t0, spacing))
        best = max(fits, key=lambda f: (f[3], -f[2]))
    R, t = best[0], best[1]
    if not tick(1):
        return _empty(P, R, t)
    gate = max(p.max_distance_mm, spacing)
    moved = Aa @ R.T + t
    widths = np.geomspace(p.kernel_start_mm, p.kernel_end_mm, max(p.nonrigid_iterations, 1))
    for it in range(p.nonrigid_iterations):
        match, dist = _assign(moved, Bb, gate * (1.5 if it == 0 else 1.0))
        m = match >= 0
        if m.sum() < 3:
            break
        disp = Bb[m] - moved[match[m]]
        # pairs far from the local consensus of their neighbours count less
        w = 1.0 / (1.0 + (dist[m] / (0.5 * spacing)) ** 2)
        local = _field(moved[match[m]], disp, w, moved[match[m]], widths[it])
        resid = np.linalg.norm(disp - local, axis=1)
        w = w / (1.0 + (resid / (0.3 * spacing)) ** 2)
        moved = moved + _field(moved[match[m]], disp, w, moved, widths[it])
        if not tick(2 + it):
            return _empty(P, R, t)
    match, dist = _assign(moved, Bb, gate)
    conf = np.zeros(len(Bb))
    m = match >= 0
    if m.any():
        # the nearest competitor of each pair, on either side
        Dab = np.linalg.norm(Bb[:, None, :] - moved[None, :, :], axis=-1)
        rows = np.flatnonzero(m)
        other_a = Dab[rows].copy()
        other_a[np.arange(len(rows)), match[rows]] = np.inf
        other_b = Dab[:, match[rows]].copy()
        other_b[rows, np.arange(len(rows))] = np.inf
        d2 = np.minimum(other_a.min(1), other_b.min(0))
        d1 = dist[rows]
        conf[rows] = np.clip(1.0 - d1 / np.maximum(d2, 1e-9), 0.0, 1.0) * np.exp(
            -0.5 * (d1 / p.max_distance_mm) ** 2)
    cand = np.full(P, -1, dtype=np.int64)
    cand[b_ok[m]] = a_ok[match[m]]
    confidence = np.zeros(P)
    confidence[b_ok] = conf
    distance = np.full(P, np.inf)
    distance[b_ok] = dist
    accepted = (cand >= 0) & (confidence >= p.confidence_threshold)
    index = np.where(accepted, cand, -1)
    rejected = np.sort(cand[(cand >= 0) & ~accepted])
    unmatched = np.setdiff1d(a_ok, cand[cand >= 0])
    tick(total)
    return LabelAssignment(index, cand, confidence, distance, R, t, rejected.astype(np.int64),
                           unmatched.astype(np.int64))


def _empty(P: int, R: NDArray, t: NDArray) -> LabelAssignment:
    none = np.full(P, -1, dtype=np.int64)
    return LabelAssignment(none, none.copy(), np.zeros(P), np.full(P, np.inf), R, t,
                           np.zeros(0, np.int64), np.zeros(0, np.int64))

"""Which disc is the tracked marker: the first step of a Target Tracker run.

The first step of a run is taken before the marker's motion is known. On a fast
expression a lip marker moves 20-35 px between two frames while its neighbours move
about as far, so a neighbour may arrive next to the place the tracked marker left and
match the pattern better than the marker itself, which is now farther away. Looking at
the tracked marker alone cannot tell them apart (both are discs like the pattern's).

Looking at all the discs can: every disc like the pattern's near the marker in the
previous frame (the tracked one among them) must go somewhere in the new frame, and
the discs found there must come from somewhere. :func:`assign_first_step` matches the
two sets (:func:`scipy.optimize.linear_sum_assignment`, squared displacement, a disc
may also appear or vanish at a fixed price) and takes the tracked marker's match from
the best joint assignment. A neighbour that moved into the marker's place is then
explained by the neighbour's own move, and the marker by the longer one. When the best
assignment that gives the marker another disc (or none) costs nearly as much, the step
is ambiguous and the run stops there: no position is better than a neighbour's.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.optimize import linear_sum_assignment

__all__ = ["assign_first_step", "best_assignments", "candidates", "first_step"]

#: Candidates whose marker-weighted NCC with the pattern is below this are not discs
#: like the tracked marker (texture, shading, half a lid edge).
SIMILAR_NCC = 0.75
#: Only candidates this close (in NCC) to the new frame's best one take part, in both
#: frames: discs like the marker, not texture spots (a spot the departing neighbour
#: uncovers must not stand in for it, and a spot that has to vanish must not take a
#: disc).
NCC_BELOW_BEST = 0.2
#: The runner-up assignment (another match for the tracked marker, or none) must cost
#: more than the best by at least this fraction of the tracked marker's own squared
#: move in the best, and by at least MIN_GAP_PX2 (the other discs' costs, the same in
#: both, do not count).
GAP_FRACTION = 0.25
MIN_GAP_PX2 = 25.0
#: A choice whose disc matches the pattern this much worse (NCC) than the best choice's
#: is no rival for the ambiguity test.
RIVAL_NCC = 0.1
#: The common shift of the discs costs this times its squared distance from the expected
#: motion (px^2 per px^2): under one disc's price (``unmatched``) for a move of the
#: search region's half, so that two or three neighbours moving with the marker outweigh
#: a short move of the marker alone, and a lone marker still prefers the expected place.
PRIOR_WEIGHT = 0.5
#: A candidate's price for appearing or vanishing is the full price for one that matches
#: the pattern within ``RIVAL_NCC`` of the new frame's best, falling linearly to this
#: fraction of it at the least similar candidate kept.
MIN_PRICE = 0.05

def _forced(d2: NDArray[np.float64], own: int, choice: int,
            unmatched: tuple[NDArray[np.float64], NDArray[np.float64]]
            ) -> tuple[float, list[tuple[int, int]]]:
    """The best joint assignment with the tracked disc's match forced to ``choice``.

    ``d2`` (D, C) are the squared residuals of every disc pair, ``unmatched`` the price
    of each previous disc vanishing (D,) and of each new one appearing (C,); returns the
    cost and the matched (previous, new) pairs (a cost of 1e12 or more: none)."""
    D, C = d2.shape
    gone, came = unmatched
    big = 1e12
    n = D + C
    # the augmented square problem: D discs x (C matches + D "vanished"), and C
    # "appeared" rows; the tracked disc's row is forced to its choice
    m = np.full((n, n), big)
    m[:D, :C] = np.minimum(d2, big)
    m[:D, C:] = np.where(np.eye(D, dtype=bool), gone[:, None], big)
    m[D:, :C] = np.where(np.eye(C, dtype=bool), came[None, :], big)
    m[D:, C:] = 0.0
    m[own, :] = big
    if choice >= 0:
        m[:, choice] = big
        m[own, choice] = d2[own, choice]
    else:
        m[own, C + own] = gone[own]
    r, c = linear_sum_assignment(m)
    pairs = [(int(i), int(j)) for i, j in zip(r, c, strict=True) if i < D and j < C]
    return float(m[r, c].sum()), pairs


def best_assignments(prev: NDArray[np.float64], new: NDArray[np.float64], own: int,
                     shift: NDArray[np.float64],
                     unmatched: float | tuple[NDArray[np.float64], NDArray[np.float64]],
                     prior_weight: float | None = None) -> list[tuple[float, int]]:
    """The cost of the best joint assignment for each choice of the tracked disc's match.

    Parameters
    ----------
    prev : ndarray, shape (D, 2)
        Disc positions in the previous frame (px); ``prev[own]`` is the tracked marker.
    new : ndarray, shape (C, 2)
        Disc positions in the new frame (px).
    own : int
        Index of the tracked marker in ``prev``.
    shift : ndarray, shape (2,)
        Expected motion of every disc (px; zero when unknown).
    unmatched : float or (ndarray (D,), ndarray (C,))
        Cost of a disc that vanishes or appears (px^2), one for all or one per disc
        (previous, new): a match costs its squared residual, so no match is longer than
        the square root of the two discs' sum; discs rarely vanish between two frames,
        so this is high (the caller passes an eighth of the search region's size
        squared, less for a candidate that is hardly a disc like the marker).
    prior_weight : float, optional
        None: every disc's residual is its displacement from ``shift`` (the expected
        place). A number: the discs share a *common shift* ``s`` (neighbouring markers on
        a face move together over one frame), found for each choice, and a match costs
        its squared displacement from ``s``; ``s`` itself costs ``prior_weight`` times
        its squared distance from ``shift``. Each choice tries ``s`` = the tracked
        disc's own move, then the least-squares shift of the matched pairs. A neighbour
        that arrived in the tracked marker's place while every disc moved 30 px is then
        the neighbour, whatever the length of the move.

    Returns
    -------
    list of (cost, choice)
        Sorted by cost, one entry per choice: ``choice`` is the index in ``new`` of the
        tracked marker's match, or -1 for none.

    Examples
    --------
    Two discs 25 px apart both move 30 px down: the tracked one (index 0) is matched to
    the far disc, because its neighbour explains the near one.

    >>> prev = np.array([[0.0, 0.0], [0.0, -25.0]])
    >>> new = np.array([[0.0, 30.0], [0.0, 5.0]])
    >>> best_assignments(prev, new, 0, np.zeros(2), 40.0 ** 2)[0][1]
    0

    Moving 45 px with the neighbour 30 px behind it, the nearest moves prefer the
    neighbour's arrival (15 px) to two moves of 45 px; the common shift does not:

    >>> prev = np.array([[0.0, 0.0], [0.0, -30.0]])
    >>> new = np.array([[0.0, 45.0], [0.0, 15.0]])
    >>> best_assignments(prev, new, 0, np.zeros(2), 40.0 ** 2)[0][1]
    1
    >>> best_assignments(prev, new, 0, np.zeros(2), 40.0 ** 2, prior_weight=1.0)[0][1]
    0
    """
    shift = np.asarray(shift, dtype=np.float64)
    if not isinstance(unmatched, tuple):
        unmatched = (np.full(len(prev), float(unmatched)), np.full(len(new), float(unmatched)))
    disp = new[None, :, :] - prev[:, None, :]                          # (D, C, 2)

    def cost_at(s: NDArray[np.float64], choice: int
                ) -> tuple[float, list[tuple[int, int]]]:
        cost, pairs = _forced(((disp - s) ** 2).sum(-1), own, choice, unmatched)
        if prior_weight is not None:
            cost += prior_weight * float(((s - shift) ** 2).sum())
        return cost, pairs

    out = []
    for choice in range(-1, len(new)):
        if prior_weight is None:
            cost = cost_at(shift, choice)[0]
        else:
            # the shift: the tracked disc's own move (or, for no match, the expected
            # motion and every move it could have made), then refined on the pairs
            hyps = [disp[own, choice]] if choice >= 0 else [shift, *disp[own]]
            cost = np.inf
            for s in hyps:
                c0, pairs = cost_at(s, choice)
                cost = min(cost, c0)
                if pairs and c0 < 1e12:
                    d = np.array([disp[i, j] for i, j in pairs])
                    s2 = (d.sum(0) + prior_weight * shift) / (len(d) + prior_weight)
                    cost = min(cost, cost_at(s2, choice)[0])
        if cost < 1e12:
            out.append((float(cost), choice))
    out.sort()
    return out


def assign_first_step(candidates_prev: Sequence[tuple[NDArray[np.float64], float]],
                      candidates_new: Sequence[tuple[NDArray[np.float64], float]],
                      pos: NDArray[np.float64], shift: NDArray[np.float64],
                      search_half: float, own_px: float) -> NDArray[np.float64] | None:
    """The tracked marker's position in the new frame by joint assignment, or None.

    Parameters
    ----------
    candidates_prev, candidates_new : sequence of (xy, ncc)
        Discs found by the pattern in the previous and the new frame (refined
        positions in px, marker-weighted NCC), e.g. from the tracker's candidate search
        over the search region around the marker and around its prediction.
    pos : ndarray, shape (2,)
        The tracked marker in the previous frame (px).
    shift : ndarray, shape (2,)
        Expected motion (px; zero when unknown).
    search_half : float
        A disc that appears or vanishes costs its square (px^2).
    own_px : float
        A previous-frame candidate this near ``pos`` is the tracked marker itself.

    Returns
    -------
    ndarray, shape (2,) or None
        The matched disc's position; None when the tracked marker is matched to no disc,
        or when another choice costs nearly as much (ambiguous).

    Examples
    --------
    >>> prev = [(np.array([0.0, 0.0]), 1.0), (np.array([0.0, -25.0]), 0.95)]
    >>> new = [(np.array([0.0, 5.0]), 0.93), (np.array([0.0, 30.0]), 0.93)]
    >>> assign_first_step(prev, new, np.zeros(2), np.zeros(2), 40.0, 1.5).tolist()
    [0.0, 30.0]
    """
    top = max((s for _, s in candidates_new), default=0.0)
    least = max(SIMILAR_NCC, top - NCC_BELOW_BEST)
    kept_prev = [(np.asarray(xy, float), s) for xy, s in candidates_prev if s >= least]
    kept = [(np.asarray(xy, float), s) for xy, s in candidates_new if s >= least]
    new = [xy for xy, _ in kept]
    if not new:
        return None
    own = next((i for i, (xy, _) in enumerate(kept_prev) if np.hypot(*(xy - pos)) < own_px),
               None)
    if own is None:
        kept_prev.insert(0, (np.asarray(pos, float), top))
        own = 0
    prev = [xy for xy, _ in kept_prev]

    def price(ncc: float) -> float:
        # a candidate barely like the pattern (a texture spot, on skin that stays) comes
        # and goes cheaply: it must not hold the discs to its own motion
        full = top - RIVAL_NCC   # a rival of the best: a disc like the marker
        return search_half ** 2 * float(np.clip((ncc - least) / max(full - least, 1e-6),
                                                MIN_PRICE, 1.0))

    gone = np.array([price(s) for _, s in kept_prev])
    gone[own] = search_half ** 2     # the tracked marker is a disc like itself
    came = np.array([price(s) for _, s in kept])
    ranked = best_assignments(np.array(prev), np.array(new), own,
                              np.asarray(shift, float), (gone, came), PRIOR_WEIGHT)
    if not ranked or ranked[0][1] < 0:
        return None
    best = new[ranked[0][1]]
    own_cost = float(((best - prev[own] - shift) ** 2).sum())
    # the runner-up: another choice about as like the pattern as the best (a disc that
    # matches it clearly worse is no rival), or no match at all
    rivals = [cost for cost, c in ranked[1:]
              if c < 0 or kept[c][1] >= kept[ranked[0][1]][1] - RIVAL_NCC]
    if rivals and rivals[0] - ranked[0][0] < max(MIN_GAP_PX2, GAP_FRACTION * own_cost):
        return None
    return best


def candidates(image: NDArray[Any], tpl: NDArray[np.float32], centre: Any,
                params: Any, refiner: Any, n: int = 6,
                ref_gain: float | None = None, gains: list[float] | None = None
                ) -> list[tuple[NDArray[np.float64], float]]:
    """The ``n`` best NCC peaks of ``tpl`` in the search region around ``centre``,
    refined and sorted by their marker-weighted NCC (best first), scored down below half
    the contrast ``ref_gain`` (the Lucas-Kanade gain) when given; ``gains`` (a list)
    receives each candidate's gain."""
    P, S = params.pattern_size, params.search_size
    hp, hs = P // 2, S // 2
    H, W = image.shape[:2]
    cx, cy = int(round(float(centre[0]))), int(round(float(centre[1])))
    m = 3
    x0, x1 = max(cx - hs - m, 0), min(cx + hs + m + 1, W)
    y0, y1 = max(cy - hs - m, 0), min(cy + hs + m + 1, H)
    if x1 - x0 < P + 2 * m or y1 - y0 < P + 2 * m:
        return []
    crop = np.asarray(image[y0:y1, x0:x1], dtype=np.float32)
    # candidates by the NCC weighted to the marker like the refinement: a neighbour on
    # another background is a candidate too
    mask = (refiner.wt.reshape(P, P) / refiner.wt.max()).astype(np.float32)
    res = cv2.matchTemplate(crop[m:-m, m:-m], tpl, cv2.TM_CCOEFF_NORMED, mask=mask)
    res = np.nan_to_num(res, nan=-1.0, posinf=-1.0, neginf=-1.0)
    peaks = (res >= cv2.dilate(res, np.ones((5, 5), np.uint8))) & (res > 0.3)
    ys, xs = np.nonzero(peaks)
    order = np.argsort(-res[ys, xs])[:n]
    crop64 = crop.astype(np.float64)
    out = []
    for i in order:
        peak = np.array([x0 + m + xs[i] + hp, y0 + m + ys[i] + hp], dtype=np.float64)
        xy, ncc, _ = refiner.refine(crop64, (x0, y0), peak, params.max_iterations,
                                    params.tolerance_px)
        if np.all(np.isfinite(xy)) and np.hypot(*(xy - peak)) <= params.max_refine_px:
            out.append((xy, float(refiner.last_ncc_w) if ncc > 0 else 0.0,
                        refiner.last_gain))
    if ref_gain is not None and ref_gain > 0:
        # the NCC does not see contrast: a texture spot of the skin can match the
        # pattern's shape as well as another marker does. A candidate with less than
        # half the tracked marker's contrast is scored down in proportion
        out = [(xy, ncc * min(1.0, 2.0 * g / ref_gain), g) for xy, ncc, g in out]
    out.sort(key=lambda c: -c[1])
    # one entry per place: peaks refined onto the same spot count once
    uniq: list[tuple[NDArray[np.float64], float]] = []
    for xy, ncc, g in out:
        if all(np.hypot(*(xy - u[0])) > max(hp // 2, 2) for u in uniq):
            uniq.append((xy, ncc))
            if gains is not None:
                gains.append(g)
    return uniq


def first_step(img: NDArray[Any], prev_img: NDArray[Any], tpl: NDArray[np.float32],
               refiner: Any, pos: NDArray[np.float64], velocity: NDArray[np.float64],
               xy: NDArray[np.float64], score: float, params: Any
               ) -> tuple[NDArray[np.float64], float]:
    """The first step of a run (motion unknown), checked against every disc around it.

    Parameters
    ----------
    img, prev_img : ndarray (H, W)
        The new and the previous frame.
    tpl : ndarray (P, P) float32
        The pattern (zero mean, unit variance) and ``refiner`` its Lucas-Kanade refiner.
    refiner : carapost.algorithms.target_track._Refiner
    pos, velocity : ndarray, shape (2,)
        The marker in the previous frame and its expected motion (px).
    xy, score : ndarray (2,), float
        The tracker's own match in the new frame (NaN when none).
    params : TargetTrackerParameters
        With no distance penalty or ambiguity margin (the tracker's backwards settings).

    Returns
    -------
    xy, score
        The step to take: the tracker's own match when the joint assignment agrees,
        the disc it assigns to the marker otherwise (a longer move that the search
        region's best match missed), NaN and 0 when the marker's match is ambiguous or
        none.

    Notes
    -----
    Both frames are searched over 1.5 x the search region (a first step is not
    predicted; twice the region in the previous frame found no more and cost twice as
    much).
    """
    from dataclasses import replace

    from carapost.algorithms.target_track import match_patch

    def discs(image: NDArray[Any], centre: Any, size: int, ref_gain: float | None = None,
              gains: list[float] | None = None) -> list:
        return candidates(image, tpl, centre, replace(params, search_size=size), refiner,
                           n=10, ref_gain=ref_gain, gains=gains)

    if np.all(np.isfinite(xy)) and np.hypot(*(xy - pos - velocity)) <= params.check_step_px:
        # a short step needs no assignment (the tracker's own checks hold it): among
        # texture spots the joint optimum can prefer another place for a marker at rest
        return xy, score
    S = params.search_size
    wide = int(1.5 * S) | 1
    gains: list[float] = []
    prev = discs(prev_img, pos, wide, gains=gains)
    # the tracked marker's contrast (its candidate in the previous frame): a texture spot
    # far fainter than it is no disc like it, in either frame
    own = [g for (c, _), g in zip(prev, gains, strict=True)
           if np.hypot(*(c - pos)) < params.max_refine_px]
    if own:
        prev = [(c, s * min(1.0, 2.0 * g / own[0])) for (c, s), g in zip(prev, gains,
                                                                      strict=True)]
        new = discs(img, pos + velocity, wide, ref_gain=own[0])
    else:
        new = discs(img, pos + velocity, wide)
    # a disc appearing or vanishing costs half of (half the search region)^2: a match
    # is never longer than half the search region
    hit = assign_first_step(prev, new, pos, velocity, S / 2.0 / 2 ** 0.5,
                            params.max_refine_px)
    nan = np.array([np.nan, np.nan])
    if hit is None:
        return nan, 0.0
    if np.all(np.isfinite(xy)) and np.hypot(*(hit - xy)) < params.max_refine_px:
        return xy, score
    # another disc than the search region's best match: refined and scored like it
    xy2, score2 = match_patch(img, tpl, hit, replace(
        params, search_size=params.pattern_size + 6), refiner)
    if not (np.all(np.isfinite(xy2)) and np.hypot(*(xy2 - hit)) < params.max_refine_px):
        return nan, 0.0
    return xy2, score2


def consistent_backwards(img: NDArray[Any], prev_img: NDArray[Any], xy: NDArray,
                         pos: NDArray, params: Any, strict: bool = False) -> bool:
    """Whether the patch found at ``xy`` leads back to ``pos`` in the previous image.

    A long step may have landed on a neighbouring marker: searched back in the previous
    image (around ``xy``, with no motion prior), the neighbour's patch finds the
    neighbour, not the tracked marker. Only long steps are checked (the caller), so
    this costs little on slow markers.

    ``strict`` (the first step of a run, when the motion is unknown): every candidate in
    the search region is scored by the NCC weighted to the marker, and the check fails
    unless the best of them is ``pos`` and no other comes within the Ambiguity Margin.
    A neighbour that moved into the place the tracked marker left matches the pattern
    there (same background, a similar disc), but its own patch leads back to where it
    came from, whose disc is the very same one. ``params`` is the run's
    `~carapost.algorithms.target_track.TargetTrackerParameters`.
    """
    from carapost.algorithms.target_track import _normalise, _Refiner, match_patch, sample_patch

    tpl = _normalise(sample_patch(img, xy, params.pattern_size))
    if tpl is None:
        return False
    if not strict:
        back, _ = match_patch(prev_img, tpl, xy, params)
        return bool(np.all(np.isfinite(back))
                    and np.hypot(*(back - pos)) < params.max_refine_px)
    refiner = _Refiner(tpl, params.weight_fraction * params.pattern_size)
    cands = candidates(prev_img, tpl, xy, params, refiner)
    if not cands:
        return False
    return bool(np.hypot(*(cands[0][0] - pos)) < params.max_refine_px)

"""Identity repair after tracking: a point that hops onto another marker is split.

:func:`hop_segments` finds the frames where a point moves unlike its neighbours; the
pieces are split into points of their own, doubles merged, pieces of one marker that
never coexist stitched, and what is left isolated dropped.
"""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from carapost.algorithms.codes import KIND_BRIM, KIND_FACE, POINT_FILLS, RECON_TRIANGULATED
from carapost.algorithms.tracking.neighbours import marker_spacing


def hop_segments(X: ArrayLike, nb: NDArray[np.intp], w: NDArray[np.float64],
                 gate: float, rows: ArrayLike | None = None) -> NDArray[np.intp]:
    """Which marker identity each point is on, frame by frame, judged from its neighbours.

    A point that hops to a neighbouring marker moves, between two frames where it is
    seen, by about the marker spacing relative to how its neighbours moved; normal motion
    relative to the neighbours is a small fraction of it. Each such hop starts a new
    segment; segments are labelled by the summed hop vectors (a hop away and the hop back
    cancel) and grouped when their labels agree within ``gate``. Group 0 is the identity
    the point holds longest. Neighbours whose own motion disagrees with the others' (a
    neighbour hopping itself) are left out.

    Parameters
    ----------
    X : array_like, shape (F, P, 3)
        Positions (mm; NaN where absent).
    nb, w : ndarray, shape (P, k)
        Neighbour graph (:func:`neighbour_graph`; index ``P`` = padding).
    gate : float
        Smallest hop (mm), e.g. half the marker spacing.
    rows : array_like of int, optional
        Points to examine (default all; the others get group 0 where present).

    Returns
    -------
    ndarray of int, shape (F, P)
        Identity group per point-frame: -1 absent, 0 the point's own, 1, 2, ... others.
    """
    X = np.asarray(X, np.float64)
    F, P = X.shape[:2]
    pad = np.concatenate([X, np.full((F, 1, 3), np.nan)], axis=1)
    group = np.where(np.isfinite(X).all(-1), 0, -1).astype(np.intp)
    for p in (range(P) if rows is None else np.asarray(rows, np.intp).reshape(-1)):
        fr = np.flatnonzero(np.isfinite(X[:, p]).all(-1))
        if fr.size < 2:
            continue
        a, b = fr[:-1], fr[1:]
        dnb = pad[b][:, nb[p]] - pad[a][:, nb[p]]  # (n, k, 3)
        fin = np.isfinite(dnb).all(-1) & (w[p] > 0)
        # a neighbour that itself hops must not hide (or fake) this point's hop: only
        # neighbours moving like most of them count
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            med = np.nanmedian(np.where(fin[..., None], dnb, np.nan), axis=1)
        fin &= np.linalg.norm(dnb - med[:, None], axis=-1) <= 0.5 * gate
        m = fin * w[p]
        sw = m.sum(1)
        mean = (np.nan_to_num(dnb) * m[..., None]).sum(1) / np.maximum(sw, 1e-9)[:, None]
        r = X[b, p] - X[a, p] - mean
        rn = np.where(sw > 0.05, np.linalg.norm(r, axis=-1), 0.0)
        hop = rn > gate
        if not hop.any():
            continue
        # a wrong frame between right ones gives a step out and a step back of which one
        # may fall just short of the gate: a large step next to a hop counts as one too,
        # so the two cancel
        near = np.zeros_like(hop)
        near[1:] |= hop[:-1]
        near[:-1] |= hop[1:]
        hop |= near & (rn > 0.5 * gate)
        seg = np.r_[0, np.cumsum(hop)]  # segment of each frame in fr
        label = np.cumsum(np.concatenate([np.zeros((1, 3)),
                                          np.where(hop[:, None], r, 0.0)]), axis=0)
        counts = np.bincount(seg)
        # group segments by label, the longest-held identity first
        centres: list[NDArray[np.float64]] = []
        seg_group = np.zeros(counts.size, np.intp)
        for sgi in np.argsort(-counts, kind="stable"):
            lab = label[np.flatnonzero(seg == sgi)[0]]
            dist = [float(np.linalg.norm(lab - c)) for c in centres]
            if dist and min(dist) <= gate:
                seg_group[sgi] = int(np.argmin(dist))
            else:
                seg_group[sgi] = len(centres)
                centres.append(lab)
        group[fr, p] = seg_group[seg]
    return group


def _face_graph(X: NDArray[np.float64], k: int = 12, min_frames: int = 10
                ) -> tuple[NDArray, NDArray, float] | None:
    """Neighbour graph of points from their median positions over the take (or None).

    Only points present in at least ``min_frames`` frames serve as neighbours (the
    short-lived finds of a pass would otherwise be the nearest neighbours of the marker
    they double, with a random motion).
    """
    seen = np.isfinite(X[..., 0]).any(0)
    if seen.sum() < 3:
        return None
    rest = np.full((X.shape[1], 3), np.nan)
    rest[seen] = np.nanmedian(X[:, seen], axis=0)
    ref = np.flatnonzero(np.isfinite(X[..., 0]).sum(0) >= min_frames)
    if ref.size < 3:
        ref = np.flatnonzero(seen)
    P = X.shape[1]
    kk = min(k, ref.size - 1)
    d, j = cKDTree(rest[ref]).query(rest[seen], k=kk + 1)
    cols = ref[j]
    rows = np.flatnonzero(seen)
    own = cols == rows[:, None]
    # drop the point itself (or the farthest when it is not a reference)
    drop = np.where(own.any(1), np.argmax(own, axis=1), kk)
    keepc = np.ones_like(own)
    keepc[np.arange(rows.size), drop] = False
    cols = cols[keepc].reshape(rows.size, kk)
    d = d[keepc].reshape(rows.size, kk)
    spacing = marker_spacing(rest[ref])
    nb = np.full((P, kk), P, np.intp)
    w = np.zeros((P, kk))
    nb[rows] = cols
    w[rows] = np.exp(-((d / (1.5 * spacing)) ** 2))
    return nb, w, spacing


def _identity_groups(A: dict[str, NDArray[Any]], face: NDArray[np.intp]
                     ) -> NDArray[np.intp] | None:
    """:func:`hop_segments` of the ``face`` columns of a take's arrays (F, n).

    Judged on the triangulated frames only (a single-camera frame's depth can be off by
    a few millimetres without being on another marker); each single-camera frame takes
    the group of the nearest triangulated frame before it (after it at the start).
    """
    pos = A["positions"][:, face].astype(np.float64)
    tri = A["recon"][:, face] == RECON_TRIANGULATED
    X = np.where(tri[..., None], pos, np.nan)
    g = _face_graph(X)
    if g is None:
        return None
    group = hop_segments(X, g[0], g[1], 0.5 * g[2])
    other = np.isfinite(pos[..., 0]) & ~tri
    F = pos.shape[0]
    for j in np.flatnonzero(other.any(0)):
        fin = np.flatnonzero(tri[:, j])
        if fin.size == 0:
            continue
        idx = np.clip(np.searchsorted(fin, np.arange(F), side="right") - 1, 0, fin.size - 1)
        group[other[:, j], j] = group[fin[idx], j][other[:, j]]
    return group


def split_hops(A: dict[str, NDArray[Any]], kind: NDArray[np.int8], keep: NDArray[np.bool_]
                ) -> tuple[dict[str, NDArray[Any]], NDArray[np.int8], NDArray[np.bool_]]:
    """Move the frames where a face point is on another marker to new points."""
    face = np.flatnonzero((kind != KIND_BRIM) & keep)
    group = _identity_groups(A, face)
    if group is None:
        return A, kind, keep
    cols, masks = [], []
    for j in np.flatnonzero((group > 0).any(0)):
        for gi in range(1, int(group[:, j].max()) + 1):
            m = group[:, j] == gi
            if m.any():
                cols.append(face[j])
                masks.append(m)
    if not cols:
        return A, kind, keep
    mk = np.stack(masks, axis=1)  # (F, n)
    src = np.asarray(cols)
    out = {}
    for k, arr in A.items():
        piece = arr[:, src].copy()
        shape = mk.shape + (1,) * (arr.ndim - 2)
        piece = np.where(mk.reshape(shape), piece, np.asarray(POINT_FILLS[k], arr.dtype))
        arr = arr.copy()
        for i, c in enumerate(src):
            arr[mk[:, i], c] = POINT_FILLS[k]
        out[k] = np.concatenate([arr, piece.astype(arr.dtype)], axis=1)
    kind = np.r_[kind, np.full(src.size, KIND_FACE, np.int8)]
    keep = np.r_[keep, np.ones(src.size, bool)]
    return out, kind, keep


def remove_hops(A: dict[str, NDArray[Any]], kind: NDArray[np.int8],
                 keep: NDArray[np.bool_]) -> None:
    """Clear the frames where a face point sits on another marker (:func:`hop_segments`)."""
    face = np.flatnonzero((kind != KIND_BRIM) & keep)
    group = _identity_groups(A, face)
    if group is None:
        return
    bad = group > 0
    if bad.any():
        for k, arr in A.items():
            sub = arr[:, face]
            sub[bad] = POINT_FILLS[k]
            arr[:, face] = sub


def absorb(A: dict[str, NDArray[Any]], X: NDArray[np.float64], o: int, q: int) -> None:
    """Give point ``o`` point ``q``'s data in the frames where ``o`` has none."""
    gap = ~np.isfinite(X[:, o]).all(-1) & np.isfinite(X[:, q]).all(-1)
    for k in A:
        A[k][gap, o] = A[k][gap, q]
    X[gap, o] = X[gap, q]


def replace_with(A: dict[str, NDArray[Any]], X: NDArray[np.float64], o: int, q: int
                 ) -> None:
    """Give point ``o`` point ``q``'s data in every frame where ``q`` has some (``o``'s
    own data there is dropped)."""
    has = np.isfinite(X[:, q]).all(-1)
    for k in A:
        A[k][has, o] = A[k][has, q]
    X[has, o] = X[has, q]


def stitch(A: dict[str, NDArray[Any]], kind: NDArray[np.int8], keep: NDArray[np.bool_],
            P: int, merge_mm: float) -> None:
    """Join found points that are pieces of an earlier point's marker.

    A marker lost and found again several times becomes several points that rarely
    coexist, so their distance cannot be compared. A found point joins an earlier one
    whose typical position is within half the marker spacing when, wherever both exist,
    they agree within ``merge_mm``, and the joined track has no hop relative to the
    neighbours' motion (:func:`hop_segments`), i.e. continues on the same marker. Where
    both exist and disagree, the found point's frames are taken instead of the earlier
    point's (which was then off its marker), if that joined track has no hop.
    """
    X = A["positions"].astype(np.float64)
    X = np.where((A["recon"] == RECON_TRIANGULATED)[..., None], X, np.nan)
    face = np.flatnonzero((kind != KIND_BRIM) & keep)
    seen = np.isfinite(X[:, face, 0]).any(0)
    if seen.sum() < 4 or face.size == 0:
        return
    rest = np.full((X.shape[1], 3), np.nan)
    rest[face[seen]] = np.nanmedian(X[:, face[seen]], axis=0)
    has = np.isfinite(rest).all(-1)
    spacing = marker_spacing(rest[face])
    gate = 0.5 * spacing
    base = face[has[face]]
    if base.size < 4:
        return
    tree = cKDTree(rest[base])
    k = min(8, base.size - 2)
    kq = min(k + 8, base.size)
    Xall = A["positions"].astype(np.float64)
    for q in range(P, X.shape[1]):
        if not (keep[q] and has[q] and kind[q] != KIND_BRIM):
            continue
        others = face[(face < q) & keep[face] & has[face]]
        dr = np.linalg.norm(rest[others] - rest[q], axis=-1)
        order = np.argsort(dr)
        for o in others[order[dr[order] <= gate][:3]]:
            both = np.isfinite(X[:, o, 0]) & np.isfinite(X[:, q, 0])
            # Where both exist and disagree, one of them is off its marker there (a lost
            # point revived on a ghost of wrong matches while the marker was found
            # again as a new point): the found piece is tried first in those frames,
            # and the joined track must still keep to the marker (the hop test below).
            over = bool(both.any()) and float(
                np.median(np.linalg.norm(X[both, o] - X[both, q], axis=-1))) > merge_mm
            if over:
                comb = np.where(np.isfinite(X[:, q]), X[:, q], X[:, o])
            else:
                comb = np.where(np.isfinite(X[:, o]), X[:, o], X[:, q])
            # the nearest other markers (pieces of this one excluded) as references
            dd, jj = tree.query(rest[o], k=kq)
            nbp = base[jj]
            sel = (nbp != o) & (nbp != q) & (dd > gate) & keep[nbp]
            nbp, dd = nbp[sel][:k], dd[sel][:k]
            if nbp.size == 0:
                continue
            n = nbp.size
            loc = np.concatenate([comb[:, None], X[:, nbp]], axis=1)
            nb = np.full((1 + n, n), 1 + n, np.intp)
            nb[0] = np.arange(1, 1 + n)
            w = np.zeros((1 + n, n))
            w[0] = np.exp(-((dd / spacing) ** 2))
            g = hop_segments(loc, nb, w, gate, rows=[0])[:, 0]
            # a few isolated frames off (noisy first frames of a piece) are cleared later
            if (g > 0).sum() <= 0.02 * (g >= 0).sum():
                if over:
                    replace_with(A, Xall, o, q)
                    X[:, o] = np.where(np.isfinite(X[:, q]), X[:, q], X[:, o])
                else:
                    absorb(A, Xall, o, q)
                    X[:, o] = np.where(np.isfinite(X[:, o]), X[:, o], X[:, q])
                keep[q] = False
                break


def drop_isolated(A: dict[str, NDArray[Any]], kind: NDArray[np.int8], keep: NDArray[np.bool_],
                   P: int, factor: float = 2.5) -> None:
    """Drop found points far from every other face point.

    Two real markers matched across the cameras of one caddy make a "ghost" that moves
    smoothly like a marker but floats off the face: its typical position is several
    marker spacings from any other point, which no real marker of the set is.
    """
    face = np.flatnonzero((kind != KIND_BRIM) & keep)
    if face.size < 4 or not (face >= P).any():
        return
    X = A["positions"][:, face].astype(np.float64)
    seen = np.isfinite(X[..., 0]).any(0)
    rest = np.full((face.size, 3), np.nan)
    rest[seen] = np.nanmedian(X[:, seen], axis=0)
    ok = np.flatnonzero(seen)
    if ok.size < 4:
        return
    d, _ = cKDTree(rest[ok]).query(rest[ok], k=2)
    spacing = float(np.median(d[:, 1]))
    far = face[ok][d[:, 1] > factor * spacing]
    keep[far[far >= P]] = False

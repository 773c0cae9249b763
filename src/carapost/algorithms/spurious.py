"""Find tracked face points that are not markers, with the reason for each.

A point that is not a marker - a "ghost" made by matching two different markers across
the two cameras of one caddy, a highlight or a speck tracked for a while - is worse in an
export than a gap: it is animated data nobody asked for. :func:`find_spurious_points`
judges each face point over the whole take by what a marker must satisfy:

``too few frames``
    triangulated (seen by >= 2 cameras) in fewer than ``min_frames`` frames (half the
    frames on a take shorter than twice that);
``too few cameras``
    fewer than ``min_triangulated_share`` of its samples are seen by two cameras or
    more (a single-sensor depth is only a guess from the neighbours);
``moves unlike its neighbours``
    the RMS, over frames, of its displacement minus its neighbours' median displacement
    exceeds ``motion_share`` marker spacings: skin carries a marker along with the markers
    around it.

Arrays in, reasons out; nothing is changed here. Units: mm.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import cKDTree

from carapost.algorithms.codes import KIND_BRIM, RECON_SINGLE_SENSOR, RECON_TRIANGULATED

__all__ = ["SpuriousPoint", "SpuriousParameters", "find_spurious_points"]


@dataclass(frozen=True)
class SpuriousParameters:
    """Thresholds of :func:`find_spurious_points` (see the module docstring).

    The defaults keep every marker of the rendered takes (the largest motion deviation
    from the neighbours is 0.4 marker spacing on the fast preset's truth). A distance
    from the surface through the neighbours was tried as a test too and left out: the
    nose tip stands 16 mm off the patch through its neighbours on the standard set.
    """

    min_frames: int = 10
    min_triangulated_share: float = 0.1
    neighbours: int = 10
    motion_share: float = 0.75


@dataclass(frozen=True)
class SpuriousPoint:
    """One point judged not to be a marker.

    Attributes
    ----------
    index : int
        Column of the point in the arrays given.
    reason : str
        Why, in words (for the log and the report).
    """

    index: int
    reason: str


def find_spurious_points(positions: ArrayLike, recon: ArrayLike, kind: ArrayLike,
                         params: SpuriousParameters | None = None) -> list[SpuriousPoint]:
    """Face points of a tracked take that are not markers (see the module docstring).

    Parameters
    ----------
    positions : array_like, shape (F, P, 3)
        Tracked positions (mm), NaN where none.
    recon : array_like, shape (F, P) int
        ``RECON_*`` of each sample.
    kind : array_like, shape (P,)
        ``KIND_*``; brim points are never judged.
    params : SpuriousParameters, optional

    Returns
    -------
    list of SpuriousPoint
        In point order; the first reason that applies.

    Examples
    --------
    A grid of markers riding together and one point drifting across it:

    >>> import numpy as np
    >>> g = np.stack(np.meshgrid(np.arange(6.0), np.arange(6.0)), -1).reshape(-1, 2) * 12
    >>> rest = np.vstack([np.c_[g, np.zeros(len(g))], [30.0, 30.0, 0.0]])
    >>> X = rest[None] + np.linspace(0, 5, 40)[:, None, None] * [0, 1, 0]
    >>> X[:, -1, 0] += np.linspace(-25, 25, 40)
    >>> found = find_spurious_points(X, np.ones(X.shape[:2], int), np.zeros(len(rest), int))
    >>> [(s.index, s.reason.split(":")[0]) for s in found]
    [(36, 'moves unlike its neighbours')]
    """
    p = SpuriousParameters() if params is None else params
    X = np.asarray(positions, dtype=np.float64)
    rc = np.asarray(recon)
    kd = np.asarray(kind)
    face = np.flatnonzero(kd != KIND_BRIM)
    present = np.isfinite(X[..., 0])
    n_tri = (rc == RECON_TRIANGULATED).sum(0)
    n_single = (rc == RECON_SINGLE_SENSOR).sum(0)
    n_present = present.sum(0)
    # A take shorter than twice min_frames (a test take, a short pick-up) asks for
    # half its frames instead, so that a real marker of a short take is never judged.
    need = min(p.min_frames, max(2, X.shape[0] // 2))
    out: dict[int, str] = {}
    for i in face:
        if n_present[i] == 0:
            continue
        if n_tri[i] < need:
            out[int(i)] = (f"too few frames: triangulated in {int(n_tri[i])} frames "
                           f"(needs {need})")
        elif n_single[i] > (1.0 - p.min_triangulated_share) * n_present[i]:
            out[int(i)] = (f"too few cameras: {int(n_single[i])} of its {int(n_present[i])} "
                           f"samples are from one camera only")
    judged = np.array([i for i in face if n_present[i] and int(i) not in out], dtype=np.intp)
    if judged.size >= 8:
        Xj = X[:, judged]
        rest = np.nanmedian(Xj, axis=0)
        d, nb = cKDTree(rest).query(rest, k=min(p.neighbours, judged.size - 1) + 1)
        spacing = float(np.median(d[:, 1]))
        ref = np.nanmedian(Xj, axis=0)
        disp = Xj - ref[None]  # (F, n, 3)
        for j, i in enumerate(judged):
            nd = np.nanmedian(disp[:, nb[j, 1:]], axis=1)  # (F, 3)
            dev = np.linalg.norm(disp[:, j] - nd, axis=-1)
            dev = dev[np.isfinite(dev)]
            if dev.size and np.sqrt(np.mean(dev ** 2)) > p.motion_share * spacing:
                out[int(i)] = (f"moves unlike its neighbours: {np.sqrt(np.mean(dev ** 2)):.1f}"
                               f" mm RMS from their motion (limit "
                               f"{p.motion_share * spacing:.1f} mm)")
    return [SpuriousPoint(i, out[i]) for i in sorted(out)]

"""Target Tracker runs: where a frame tracked in one camera is put on its ray.

Used by :meth:`carapost.commands.target_track.TargetTrackJob.solve` with Allow Single
Sensor Tracking: the point's trusted 3D, moved by how its nearest points moved since
(:func:`neighbour_xyz`, gathered when the run is prepared), gives the depth; units are
raw pixels and mm.
"""

from __future__ import annotations

import warnings
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from carapost.algorithms.codes import RECON_TRIANGULATED
from carapost.model.project import Project

if TYPE_CHECKING:
    from carapost.commands.target_track import TargetTrackJob

__all__ = ["depth_reference", "neighbour_xyz"]


def depth_reference(job: TargetTrackJob, i: int, rows: NDArray, obs: NDArray,
                    positions: NDArray, touched: NDArray, nearest: NDArray
                    ) -> NDArray[np.float64]:
    """Where point ``i``'s one-camera frames of this run are placed on their ray.

    The point's trusted 3D (triangulated before the run, outside the frames it
    re-solves, or from two or more of this run's cameras) nearest before and after
    each frame, each moved by how its neighbours moved since (the face's motion
    over the stretch: a lip marker seen by one camera moves in depth with the
    lips, not with the frame it was keyed on), blended by distance in time
    (:func:`carapost.algorithms.single_sensor.neighbour_prediction`). Where no
    neighbour covers a frame, ``nearest`` (the nearest 3D the point had).

    Parameters
    ----------
    job : TargetTrackJob
        The run (its neighbours' 3D, block before the run, cameras).
    i : int
        The point's index in the run.
    rows : ndarray of int, shape (m,)
        Re-solved frames (indices into the run's block).
    obs : ndarray, shape (m, C, 2)
        Their observations (raw px), NaN where none.
    positions : ndarray, shape (n, 3)
        The point's 3D over the block before the run (mm).
    touched : ndarray of bool, shape (n,)
        Frames the run re-solves.
    nearest : ndarray, shape (m, 3)
        The fallback reference (mm).

    Returns
    -------
    ndarray, shape (m, 3)
        The reference per re-solved frame (mm).
    """
    from carapost.algorithms.single_sensor import neighbour_prediction
    from carapost.commands.target_track import resolve_3d

    assert job.neighbour_xyz is not None
    nbx = job.neighbour_xyz[i]
    k = nbx.shape[1]
    if k == 0:
        return nearest
    recon = job.block["recon"][:, i]
    own = np.where((np.isfinite(positions).all(-1) & (recon == RECON_TRIANGULATED)
                    & ~touched)[:, None], positions, np.nan)
    # the run's own anchors from three cameras or more: a pair of cameras on one
    # side of the face fixes the depth poorly (a lower-lid marker of seed 4: 1.1 mm
    # off from two cameras 0.1 px off each, just before a third loses it), and the
    # frames after it would inherit that depth
    multi = np.isfinite(obs).all(-1).sum(1) >= 3
    if multi.any() and job.intr is not None:
        p, _, _ = resolve_3d(obs[multi], job.R[rows[multi]], job.t[rows[multi]],
                             job.intr, np.full((int(multi.sum()), 3), np.nan), False)
        own[rows[multi]] = p
    X = np.concatenate([own[:, None], nbx], axis=1)
    nb = np.full((k + 1, k), -1, np.intp)
    nb[0] = np.arange(1, k + 1)
    pred, _ = neighbour_prediction(X, np.isfinite(X).all(-1), nb=nb)
    ref = pred[rows, 0]
    return np.where(np.isfinite(ref).all(-1)[:, None], ref, nearest)


def neighbour_xyz(project: Project, cols: NDArray, lo: int, hi: int,
                  k: int = 6, max_frames: int = 40) -> list[NDArray]:
    """Per column of ``cols``: the triangulated 3D over frames lo..hi (n, k, 3) mm of its
    ``k`` nearest points (median distance over up to ``max_frames`` frames of the take
    where both are triangulated), NaN where a neighbour is not triangulated."""
    pts = project.points
    F, P = pts.positions.shape[:2]
    tri = (pts.recon == RECON_TRIANGULATED) & np.isfinite(pts.positions).all(-1)
    sample = np.unique(np.linspace(0, F - 1, min(F, max_frames)).astype(np.intp))
    Xs = np.where(tri[sample][..., None], pts.positions[sample], np.nan)
    out = []
    for col in cols:
        d = np.full(P, np.nan)
        if np.isfinite(Xs[:, col]).any():
            with warnings.catch_warnings():   # points never triangulated: NaN, skipped
                warnings.simplefilter("ignore", RuntimeWarning)
                d = np.nanmedian(np.linalg.norm(Xs[:, None, col] - Xs, axis=-1), axis=0)
        d[col] = np.nan
        d[np.isin(np.arange(P), cols)] = np.nan   # points tracked in this run move too
        order = np.argsort(np.where(np.isfinite(d), d, np.inf))[:k]
        order = order[np.isfinite(d[order])]
        X = pts.positions[lo:hi + 1][:, order].astype(np.float64)
        out.append(np.where(tri[lo:hi + 1][:, order][..., None], X, np.nan))
    return out

"""Bundle Sequence [Unconstrained], following the processing recipe.

``prepare_bundle_sequence(project, frames)`` snapshots the observations, positions and
cameras of the range; ``job.compute(progress)`` runs the adjustment with no project;
``ApplyResult(result)`` writes it. ``BundleSequence(project, ...)`` does all three.
"""

from __future__ import annotations

import logging

import numpy as np
from numpy.typing import NDArray

from carapost.algorithms.camera import CameraIntrinsics
from carapost.commands.recipe import ApplyResult, Job, Progress, Result
from carapost.commands.stack import CommandError, Journal
from carapost.model.project import KIND_BRIM, Project

log = logging.getLogger("carapost.process")

WHAT = "Bundle Sequence [Unconstrained]"

__all__ = ["BundleSequence", "BundleSequenceJob", "BundleSequenceResult",
           "prepare_bundle_sequence"]


class BundleSequenceResult(Result):
    """Refined cameras of some frames and positions of the face points there.

    Attributes
    ----------
    frames : ndarray of int (n,)
    R, t : ndarray (n, C, 3, 3), (n, C, 3)
    ids : ndarray of int (m,)
        Face points refined.
    positions : float32 ndarray (n, m, 3)
    """

    description = WHAT

    def __init__(self, frames: NDArray[np.intp], R: NDArray, t: NDArray, ids: NDArray,
                 positions: NDArray, cancelled: bool, message: str):
        self.frames, self.R, self.t, self.ids = frames, R, t, ids
        self.positions, self.cancelled, self.message = positions, cancelled, message

    def write(self, project: Project, journal: Journal) -> None:
        cal = project.calibration
        frames = self.frames
        journal.calibration(frames)
        cal.R[frames] = self.R  # only solved frames are refined: the flags stay
        cal.t[frames] = self.t
        if len(self.ids) and len(frames):
            cols = project.points.index_of(self.ids)
            lo, hi = int(frames.min()), int(frames.max())
            journal.point_block(slice(lo, hi + 1), cols, ("positions",))
            pos = project.points.positions
            pos[np.ix_(frames, cols)] = self.positions


class BundleSequenceJob(Job):
    """Snapshot of a frame range for :func:`carapost.algorithms.bundle.bundle_sequence`."""

    description = WHAT

    def __init__(self, first: int, solved: NDArray[np.bool_], obs: NDArray, X: NDArray,
                 R: NDArray, t: NDArray, intr: CameraIntrinsics, brim: NDArray[np.bool_],
                 model: NDArray | None, ids: NDArray, old_positions: NDArray):
        self.first, self.solved, self.obs, self.X = first, solved, obs, X
        self.R, self.t, self.intr, self.brim, self.model = R, t, intr, brim, model
        self.ids, self.old_positions = ids, old_positions

    def compute(self, progress: Progress = None) -> BundleSequenceResult:
        from carapost.algorithms.bundle import bundle_sequence

        res = bundle_sequence(self.obs, self.X, self.R, self.t, self.intr,
                              brim_points_mask=self.brim, brim_model=self.model,
                              progress=progress)
        n = len(self.solved)
        done = np.zeros(n, dtype=bool)
        done[: res.frames_done] = True
        ok = (done & self.solved & np.asarray(res.success, bool)
              & np.isfinite(res.R).all((1, 2, 3)))
        face = ~self.brim
        P = res.points[ok][:, face].astype(np.float32)
        old = self.old_positions[ok]
        # only points that had a 3D position move; nothing is created where none was
        positions = np.where(np.isfinite(old), P, old)
        cancelled = res.frames_done < n
        rms0 = np.nanmedian(res.rms_before[ok]) if ok.any() else np.nan
        rms1 = np.nanmedian(res.rms_after[ok]) if ok.any() else np.nan
        message = (f"{WHAT}: {ok.sum()} frames, median RMS {rms0:.3f} -> {rms1:.3f} px"
                   + (" (cancelled)" if cancelled else ""))
        log.info("%s", message)
        return BundleSequenceResult(np.flatnonzero(ok) + self.first, res.R[ok], res.t[ok],
                                    self.ids, positions, cancelled, message)


def prepare_bundle_sequence(project: Project, frames: tuple[int, int] | None = None
                            ) -> BundleSequenceJob:
    """Refine the cameras and face points of every solved frame of a range.

    Brim points keep their model positions (they fix the gauge of each frame); face
    points with observations in two or more cameras are refined; cancelling keeps the
    frames finished so far.

    Parameters
    ----------
    project : Project
    frames : (int, int), optional
        Inclusive range (default: the active range).
    """
    cal = project.calibration
    if cal.intrinsics is None:
        raise CommandError(f"{WHAT}: the cameras have no calibration")
    a, b = project.active_range if frames is None else (int(frames[0]), int(frames[1]))
    sl = slice(a, b + 1)
    solved = cal.solved[sl].copy()
    if not solved.any():
        raise CommandError(f"{WHAT}: no frame of {a}-{b} has solved cameras")
    pts = project.points
    brim = pts.kind == KIND_BRIM
    obs = pts.obs[sl].astype(np.float64)
    X = pts.positions[sl].astype(np.float64)
    seen = (np.isfinite(obs).all(-1).sum(-1) >= 2).any(0)
    cols = np.flatnonzero(seen | brim)
    if not (seen & ~brim).any():
        raise CommandError(f"{WHAT}: no face point has observations in two cameras")
    brim_cols = brim[cols]
    model = None
    if brim_cols.any():
        first = int(np.argmax(np.isfinite(X[:, cols[brim_cols], 0]).all(1)))
        model = X[first, cols[brim_cols]]
        if not np.isfinite(model).all():
            model = None
    face = ~brim_cols
    return BundleSequenceJob(a, solved, obs[:, cols], X[:, cols], cal.R[sl].copy(),
                             cal.t[sl].copy(), cal.intrinsics.copy(), brim_cols, model,
                             pts.ids[cols[face]].copy(), pts.positions[sl][:, cols[face]])


class BundleSequence(ApplyResult):
    """Bundle Sequence [Unconstrained] over a range (default the active range) in one
    call: ``ApplyResult(prepare_bundle_sequence(project, frames).compute(progress))``."""

    def __init__(self, project: Project, frames: tuple[int, int] | None = None, *,
                 progress: Progress = None):
        super().__init__(prepare_bundle_sequence(project, frames).compute(progress))

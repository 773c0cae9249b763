"""Bundle Sequence [Unconstrained] as one undoable command."""

from __future__ import annotations

import logging
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from carapost.commands.stack import Command, CommandError, Journal
from carapost.model.project import KIND_BRIM, Project

log = logging.getLogger("carapost.process")


class BundleSequence(Command):
    """Refine the cameras and face points of every solved frame of the active range.

    Brim points keep their model positions (they fix the gauge of each frame); face
    points with observations in two or more cameras are refined. The adjustment is
    computed when the command is created (a UI does that on a worker thread);
    cancelling keeps the frames finished so far.
    """

    description = "Bundle Sequence [Unconstrained]"

    def __init__(self, project: Project, frames: tuple[int, int] | None = None, *,
                 progress: Callable[[int, int], bool] | None = None):
        from carapost.algorithms.bundle import bundle_sequence

        super().__init__()
        what = self.description
        cal = project.calibration
        if cal.intrinsics is None:
            raise CommandError(f"{what}: the cameras have no calibration")
        a, b = project.active_range if frames is None else (int(frames[0]), int(frames[1]))
        sl = slice(a, b + 1)
        solved = cal.solved[sl]
        if not solved.any():
            raise CommandError(f"{what}: no frame of {a}-{b} has solved cameras")
        pts = project.points
        brim = pts.kind == KIND_BRIM
        obs = pts.obs[sl].astype(np.float64)
        X = pts.positions[sl].astype(np.float64)
        seen = (np.isfinite(obs).all(-1).sum(-1) >= 2).any(0)
        cols = np.flatnonzero(seen | brim)
        if not (seen & ~brim).any():
            raise CommandError(f"{what}: no face point has observations in two cameras")
        brim_cols = brim[cols]
        model = None
        if brim_cols.any():
            first = int(np.argmax(np.isfinite(X[:, cols[brim_cols], 0]).all(1)))
            model = X[first, cols[brim_cols]]
            if not np.isfinite(model).all():
                model = None
        res = bundle_sequence(obs[:, cols], X[:, cols], cal.R[sl], cal.t[sl], cal.intrinsics,
                              brim_points_mask=brim_cols, brim_model=model, progress=progress)
        done = np.zeros(b - a + 1, dtype=bool)
        done[: res.frames_done] = True
        ok = done & solved & np.asarray(res.success, bool) & np.isfinite(res.R).all((1, 2, 3))
        self.frames = np.flatnonzero(ok) + a
        self.R, self.t = res.R[ok], res.t[ok]
        face = ~brim_cols
        self.ids = pts.ids[cols[face]].copy()
        P = res.points[ok][:, face].astype(np.float32)
        old = pts.positions[self.frames][:, cols[face]]
        # only points that had a 3D position move; nothing is created where none was
        self.positions = np.where(np.isfinite(old), P, old)
        self.cancelled = res.frames_done < (b - a + 1)
        rms0 = np.nanmedian(res.rms_before[ok]) if ok.any() else np.nan
        rms1 = np.nanmedian(res.rms_after[ok]) if ok.any() else np.nan
        self.message = (f"{what}: {ok.sum()} frames, median RMS {rms0:.3f} -> {rms1:.3f} px"
                        + (" (cancelled)" if self.cancelled else ""))
        log.info("%s", self.message)

    def apply(self, project: Project, journal: Journal) -> None:
        cal = project.calibration
        frames: NDArray[np.intp] = self.frames
        old = (cal.R[frames].copy(), cal.t[frames].copy(), cal.solved[frames].copy())

        def undo() -> None:
            cal.R[frames], cal.t[frames], cal.solved[frames] = old

        journal.call(undo, "cameras", nbytes=old[0].nbytes + old[1].nbytes)
        cal.R[frames] = self.R
        cal.t[frames] = self.t
        if len(self.ids) and len(frames):
            cols = project.points.index_of(self.ids)
            lo, hi = int(frames.min()), int(frames.max())
            journal.point_block(slice(lo, hi + 1), cols, ("positions",))
            pos = project.points.positions
            pos[np.ix_(frames, cols)] = self.positions

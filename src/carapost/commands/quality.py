"""Remove Spurious Points: delete tracked face points that are not markers.

The points are judged by :func:`carapost.algorithms.spurious.find_spurious_points` when
the command is created (so redo removes exactly the same points); each removed point's
label and reason are kept on the command (``removed``) and logged.
"""

from __future__ import annotations

import logging

import numpy as np

from carapost.algorithms.codes import KIND_BRIM, RECON_NONE
from carapost.algorithms.spurious import (
    SpuriousParameters,
    blob_sizes_mm,
    find_spurious_points,
    ray_misfit,
)
from carapost.commands.stack import Command, CommandError, Journal
from carapost.model.project import Project

log = logging.getLogger("carapost.commands")

__all__ = ["RemoveSpuriousPoints", "spurious_points"]


def spurious_points(project: Project, params: SpuriousParameters | None = None
                    ) -> list[tuple[int, str, str]]:
    """``(point id, label, reason)`` of every face point judged not to be a marker."""
    pts = project.points
    found = find_spurious_points(pts.positions, pts.recon, pts.kind, params,
                                 blob_size_mm=_blob_sizes(project), misfit=_misfit(project),
                                 observed=_observed(project))
    return [(int(pts.ids[s.index]), project.point_label(s.index), s.reason) for s in found]


def _observed(project: Project) -> np.ndarray:
    """Points with a camera observation in some frame (tracked here, not imported)."""
    return np.isfinite(project.points.obs[..., 0]).any(axis=(0, 2))


def _misfit(project: Project) -> np.ndarray | None:
    """Each point's `ray_misfit`; None without a calibration."""
    cal = project.calibration
    if cal.intrinsics is None or not cal.solved.any():
        return None
    pts = project.points
    # the face points' own noise: the brim dots are rounder and sharper
    recon = np.where(pts.kind[None, :] == KIND_BRIM, RECON_NONE, pts.recon)
    return ray_misfit(pts.obs, pts.positions, recon, cal.R, cal.t, cal.intrinsics)


def _blob_sizes(project: Project) -> np.ndarray | None:
    """Each point's median blob size (mm), from its attached detections; None without
    a calibration or detections."""
    cal = project.calibration
    pts = project.points
    if cal.intrinsics is None or project.detections.total == 0:
        return None
    F, P, C = pts.detection.shape
    frames = np.arange(0, F, 4)
    axes = np.full((len(frames), P, C, 2), np.nan)
    for i, f in enumerate(frames):
        for c in range(C):
            k = pts.detection[f, :, c]
            got = k >= 0
            if got.any():
                table = project.detections.get(int(f), c)["axes"]
                axes[i, got, c] = table[k[got]]
    return blob_sizes_mm(pts.positions[frames], axes, cal.R[frames], cal.t[frames],
                         cal.intrinsics.focal, step=1)


class RemoveSpuriousPoints(Command):
    """Delete the face points :func:`spurious_points` finds (one undo entry).

    Raises
    ------
    CommandError
        When there is no such point (nothing to undo).
    """

    description = "Remove Spurious Points"

    def __init__(self, project: Project, params: SpuriousParameters | None = None):
        super().__init__()
        self.found = spurious_points(project, params)
        if not self.found:
            face = project.points.kind != KIND_BRIM
            if not (_observed(project) & face).any():
                raise CommandError("Remove Spurious Points: no tracked point to judge (the "
                                   "points have no camera observations, e.g. imported "
                                   "from a C3D)")
            raise CommandError("Remove Spurious Points: every point moves like a marker")

    @property
    def removed(self) -> list[tuple[str, str]]:
        """``(label, reason)`` of each removed point."""
        return [(label, reason) for _, label, reason in self.found]

    def apply(self, project: Project, journal: Journal) -> None:
        cols = np.sort(project.points.index_of([pid for pid, _, _ in self.found]))
        for _, label, reason in self.found:
            log.info("Remove Spurious Points: %s removed (%s)", label, reason)
        journal.remove_points(cols.astype(np.intp))

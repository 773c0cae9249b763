"""Generic processing results: new detections of some images, computed point arrays.

Both are :class:`~carapost.commands.recipe.Result` s (applied by
:class:`~carapost.commands.recipe.ApplyResult`); :class:`ReplaceDetections` and
:class:`ApplyPointData` are the result commands built from them directly.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from carapost.commands.recipe import ApplyResult, Result
from carapost.commands.stack import CommandError, Journal
from carapost.model.project import Project

#: Per-point arrays of the 2D observations (detaching a detection changes these).
OBS_ARRAYS = ("obs", "source", "detection", "quality", "keyframe")

__all__ = ["OBS_ARRAYS", "ApplyPointData", "DetectionsResult", "PointDataResult",
           "ReplaceDetections", "write_detections"]


def write_detections(journal: Journal, project: Project, images: Sequence[tuple[int, int]],
                     tables: Sequence[Mapping[str, Any]]) -> None:
    """Put new detections into some images (undoably), detaching stale references.

    Points attached to the old detections of these images lose the link (their 2D
    position stays: a detection index into the new table would be wrong).
    """
    if not images:
        return
    pts = project.points
    journal.detections(list(images))
    for f, c in images:
        cols = np.flatnonzero(pts.detection[f, :, c] >= 0)
        if len(cols):
            journal.point_block(slice(f, f + 1), cols, OBS_ARRAYS)
            pts.detection[f, cols, c] = -1
    project.detections.replace_images(list(images), list(tables))


class DetectionsResult(Result):
    """New detection tables for some images (Detect Blobs).

    Parameters
    ----------
    images : sequence of (frame, camera)
    tables : sequence of dict
        One detection table per image (``centre``, ``axes``, ``angle``, ``colour``,
        ``score`` arrays of equal length).
    description : str
    cancelled : bool
    message : str
    """

    def __init__(self, images: Sequence[tuple[int, int]], tables: Sequence[Mapping[str, Any]],
                 description: str = "Detect Blobs", *, cancelled: bool = False,
                 message: str = "") -> None:
        self.images = [(int(f), int(c)) for f, c in images]
        self.tables = [dict(t) for t in tables]
        self.description = description
        self.cancelled = cancelled
        self.message = message

    def write(self, project: Project, journal: Journal) -> None:
        write_detections(journal, project, self.images, self.tables)

    def changes_nothing(self) -> bool:
        """No image was finished."""
        return not self.images


class PointDataResult(Result):
    """Computed per-point arrays over a frame range.

    Parameters
    ----------
    frames : (int, int)
        Inclusive frame range the arrays cover.
    point_ids : sequence of int
        Points (by id) the arrays' point axis refers to.
    arrays : mapping
        Some of the per-point arrays, each shaped like ``points.<name>[frames][:, cols]``.
    description : str
    """

    def __init__(self, frames: tuple[int, int], point_ids: Sequence[int],
                 arrays: Mapping[str, NDArray], description: str) -> None:
        self.frames = (int(frames[0]), int(frames[1]))
        self.point_ids = [int(p) for p in point_ids]
        self.arrays = dict(arrays)
        self.description = description

    def write(self, project: Project, journal: Journal) -> None:
        a, b = self.frames
        if not 0 <= a <= b < project.n_frames:
            raise CommandError(f"frames {a}-{b} are outside the take "
                               f"(0-{project.n_frames - 1})")
        pts = project.points
        cols = pts.index_of(self.point_ids) if self.point_ids else np.zeros(0, np.intp)
        journal.write_points(slice(a, b + 1), cols, self.arrays)


class ReplaceDetections(ApplyResult):
    """Put new detections into some images (Detect Blobs): ``ApplyResult`` of a
    :class:`DetectionsResult`."""

    def __init__(self, images: Sequence[tuple[int, int]], tables: Sequence[Mapping[str, Any]],
                 description: str = "Detect Blobs"):
        super().__init__(DetectionsResult(images, tables, description))

    @property
    def images(self) -> list[tuple[int, int]]:
        """The images whose detections are replaced."""
        return self.result.images  # type: ignore[attr-defined]

    @property
    def tables(self) -> list[dict[str, Any]]:
        """Their new detection tables."""
        return self.result.tables  # type: ignore[attr-defined]


class ApplyPointData(ApplyResult):
    """Write computed per-point arrays over a frame range: ``ApplyResult`` of a
    :class:`PointDataResult` (same parameters)."""

    def __init__(self, frames: tuple[int, int], point_ids: Sequence[int],
                 arrays: Mapping[str, NDArray], description: str):
        super().__init__(PointDataResult(frames, point_ids, arrays, description))

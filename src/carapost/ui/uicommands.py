"""Small undoable commands the window needs that the Edit-menu module does not provide.

They follow the same rules as :mod:`carapost.commands.edit`: validate in ``__init__``
(raise :class:`CommandError`), change the model only through the journal.
"""

from __future__ import annotations

import copy
from typing import Any

import numpy as np

from carapost.commands.stack import Command, CommandError, Journal
from carapost.model.project import KIND_BRIM, Project, Stick


class RenameLabel(Command):
    """Rename a label of the Labelling pane (and the point that carries it)."""

    def __init__(self, project: Project, old: str, new: str) -> None:
        super().__init__()
        new = new.strip()
        if not new or " " in new:
            raise CommandError(f"Rename Label: {new!r} is not a valid label (no spaces)")
        if new in project.labels and new != old:
            raise CommandError(f"Rename Label: a label {new!r} already exists")
        if old not in project.labels:
            raise CommandError(f"Rename Label: no label {old!r}")
        self.old, self.new = old, new
        self.description = f"Rename Label {old} to {new}"

    def apply(self, project: Project, journal: Journal) -> None:
        labels = [self.new if n == self.old else n for n in project.labels]
        journal.setattr(project, "labels", labels, "labels")
        pts = [self.new if n == self.old else n for n in project.points.labels]
        journal.setattr(project.points, "labels", pts, "labels")


class ApplyCalibration(Command):
    """Import XCP: intrinsics and per-frame extrinsics from a calibration file."""

    def __init__(self, project: Project, calib: Any, path: str) -> None:
        super().__init__()
        if calib.n_cameras != project.n_cameras:
            raise CommandError(f"{path}: the XCP has {calib.n_cameras} cameras, the take has "
                               f"{project.n_cameras}")
        self.calib = calib
        self.description = "Import XCP"

    def apply(self, project: Project, journal: Journal) -> None:
        cal = project.calibration
        old = cal.copy()

        def undo() -> None:
            project.calibration = old

        journal.call(undo, "cameras", int(old.R.nbytes + old.t.nbytes))
        new = cal.copy()
        new.intrinsics = self.calib.intrinsics.copy()
        R, t = self.calib.extrinsics_at(np.arange(project.n_frames))
        new.R[:] = R
        new.t[:] = t
        new.solved[:] = True
        new.xcp_extras = copy.deepcopy(self.calib.extras)
        project.calibration = new


class CreateStickMesh(Command):
    """Sticks along the edges of a Delaunay mesh of the face points of the current frame."""

    description = "Create Stick Mesh"

    def __init__(self, project: Project) -> None:
        super().__init__()
        from scipy.spatial import Delaunay

        f = project.current_frame
        pos = project.points.positions[f] if project.n_frames else np.zeros((0, 3))
        ok = ~np.isnan(pos[:, 0]) & (project.points.kind != KIND_BRIM)
        cols = np.flatnonzero(ok)
        if len(cols) < 3:
            raise CommandError("Create Stick Mesh: fewer than three face points have 3D data "
                               "in this frame")
        xyz = pos[cols].astype(np.float64)
        # triangulate the face as seen from the front: drop the least varying axis
        drop = int(np.argmin(xyz.std(axis=0)))
        tri = Delaunay(np.delete(xyz, drop, axis=1))
        edges = set()
        for a, b, c in tri.simplices:
            for u, v in ((a, b), (b, c), (a, c)):
                edges.add((min(u, v), max(u, v)))
        ids = project.points.ids
        have = {frozenset((s.a, s.b)) for s in project.sticks}
        self.pairs = [(int(ids[cols[u]]), int(ids[cols[v]])) for u, v in sorted(edges)
                      if frozenset((int(ids[cols[u]]), int(ids[cols[v]]))) not in have]

    def apply(self, project: Project, journal: Journal) -> None:
        sticks = copy.deepcopy(project.sticks) + [Stick(a, b) for a, b in self.pairs]
        journal.setattr(project, "sticks", sticks, "sticks")


class RelocateVideos(Command):
    """Edit > Relocate Files: point cameras at other video files."""

    description = "Relocate Files"

    def __init__(self, project: Project, paths: dict[int, str]) -> None:
        super().__init__()
        for c in paths:
            if not 0 <= c < project.n_cameras:
                raise CommandError(f"Relocate Files: no camera {c}")
        self.paths = dict(paths)

    def apply(self, project: Project, journal: Journal) -> None:
        cams = copy.deepcopy(project.take.cameras)
        for c, path in self.paths.items():
            cams[c].video_path = path
        journal.setattr(project.take, "cameras", cams, "cameras")

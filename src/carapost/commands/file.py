"""File-menu and project commands: Import XCP, Import Labels, Relocate Files, labels, sticks.

They follow the rules of :mod:`carapost.commands.edit`: the constructor reads and
validates everything (files included) and raises :class:`CommandError` or
:class:`~carapost.io.errors.CaraFileError` naming the file and the problem; ``apply``
changes the model only through the journal, so every command undoes bit-identically.
The window, the scripting session and the API all push these same commands.
"""

from __future__ import annotations

import copy
import logging
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from carapost.commands.edit import AddLabels
from carapost.commands.stack import Command, CommandError, Journal
from carapost.model.project import KIND_BRIM, Project, Stick

log = logging.getLogger("carapost.commands")

__all__ = [
    "ApplyCalibration",
    "CreateStickMesh",
    "ImportLabels",
    "ImportXcp",
    "RelocateFiles",
    "RenameLabel",
    "missing_files",
]


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
    """Import XCP: intrinsics and per-frame extrinsics from a calibration already read.

    Parameters
    ----------
    project : Project
    calib : XcpCalibration
        What :func:`carapost.io.xcp.read_xcp` returned.
    path : str
        The file it came from (for messages).
    """

    def __init__(self, project: Project, calib: Any, path: str | Path) -> None:
        super().__init__()
        if calib.n_cameras != project.n_cameras:
            raise CommandError(f"{path}: the XCP has {calib.n_cameras} cameras, the take has "
                               f"{project.n_cameras}")
        self.calib = calib
        self.path = str(path)
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


class ImportXcp(ApplyCalibration):
    """File > Import XCP: read a Vicon ``.xcp`` file and apply its cameras.

    Raises
    ------
    CaraFileError
        The file is missing or not a readable XCP (the message names it).
    CommandError
        The XCP has another number of cameras than the take.
    """

    def __init__(self, project: Project, path: str | Path) -> None:
        from carapost.io.xcp import read_xcp

        calib = read_xcp(path)
        for note in calib.notes:
            log.warning("%s: %s", Path(path).name, note)
        super().__init__(project, calib, path)


class ImportLabels(AddLabels):
    """Import Labels From Cara File / Text File: names appended to the label list.

    Parameters
    ----------
    project : Project
    path : str or Path
        A ``.cara`` project or a text file of whitespace-separated names.
    kind : {"cara", "text"}, optional
        Which reader; by default ``.cara`` files are read as projects, others as text.
    """

    def __init__(self, project: Project, path: str | Path, kind: str | None = None) -> None:
        from carapost.io.labels import read_label_file, read_labels_from_cara

        path = Path(path)
        if kind is None:
            kind = "cara" if path.suffix.lower() == ".cara" else "text"
        if kind not in ("cara", "text"):
            raise CommandError(f"Import Labels: kind must be 'cara' or 'text', got {kind!r}")
        names = read_labels_from_cara(path) if kind == "cara" else read_label_file(path)
        super().__init__(project, names, description=f"Import Labels From {path.name}")
        self.path = str(path)


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


# ----------------------------------------------------------------------------------------
# Relocate Files
# ----------------------------------------------------------------------------------------
def missing_files(project: Project) -> dict[str, str]:
    """Cameras whose video file or folder does not exist: ``{camera name: path}``."""
    return {
        cam.name: cam.video_path
        for cam in project.take.cameras
        if not cam.video_path or not Path(cam.video_path).exists()
    }


def _camera_index(project: Project, key: str | int) -> int:
    names = [c.name for c in project.take.cameras]
    if isinstance(key, int | np.integer):
        if not 0 <= int(key) < len(names):
            raise CommandError(f"Relocate Files: there is no camera {key} "
                               f"(cameras 0-{len(names) - 1})")
        return int(key)
    if key in names:
        return names.index(key)
    raise CommandError(f"Relocate Files: there is no camera named {key!r} "
                       f"({', '.join(names)})")


class RelocateFiles(Command):
    """Edit > Relocate Files: point cameras at other video files.

    Parameters
    ----------
    project : Project
    mapping : mapping
        Camera name or index -> new video file or image-sequence folder.

    Every new file is opened here: it must be a video (or image sequence) with the
    camera's image size. A different frame count is allowed (logged), since frames
    outside a video show blank.

    Raises
    ------
    CommandError
        Unknown cameras, or a video of another image size than the camera's.
    CaraFileError
        A new file that does not exist or cannot be opened as a video.
    """

    description = "Relocate Files"

    def __init__(self, project: Project, mapping: Mapping[str | int, str | Path]) -> None:
        from carapost.io.video import VideoSource

        super().__init__()
        if not mapping:
            raise CommandError("Relocate Files: no camera was given a new file")
        resolved: dict[int, str] = {}
        for key, new in mapping.items():
            c = _camera_index(project, key)
            path = Path(new).absolute()
            cam = project.take.cameras[c]
            with VideoSource(path) as src:  # CaraFileError names a bad file
                if tuple(src.size) != tuple(cam.image_size):
                    raise CommandError(
                        f"Relocate Files: {path} is {src.size[0]}x{src.size[1]} but camera "
                        f"{cam.name} is {cam.image_size[0]}x{cam.image_size[1]}")
                if src.n_frames < project.n_frames + cam.frame_offset:
                    log.warning("%s has %d frames; the take needs %d (the rest shows blank)",
                                path.name, src.n_frames, project.n_frames + cam.frame_offset)
            resolved[c] = str(path)
        self.paths = resolved

    @classmethod
    def from_folder(cls, project: Project, folder: str | Path) -> RelocateFiles:
        """Look for every missing video in ``folder`` by its file name.

        Raises
        ------
        CaraFileError
            ``folder`` is not a folder.
        CommandError
            None of the missing videos is in it.
        """
        from carapost.io.errors import CaraFileError

        folder = Path(folder)
        if not folder.is_dir():
            raise CaraFileError(folder, "is not a folder")
        found: dict[str | int, str | Path] = {}
        for name, old in missing_files(project).items():
            cand = folder / Path(old).name if old else None
            if cand is not None and cand.exists():
                found[name] = cand
        if not found:
            raise CommandError(f"Relocate Files: none of the missing videos was found in "
                               f"{folder}")
        return cls(project, found)

    @classmethod
    def of(cls, project: Project,
           mapping: Mapping[str | int, str | Path] | str | Path) -> RelocateFiles:
        """From a mapping (see the class) or, for a path, :meth:`from_folder`."""
        if isinstance(mapping, str | Path):
            return cls.from_folder(project, mapping)
        return cls(project, mapping)

    def apply(self, project: Project, journal: Journal) -> None:
        for c, path in self.paths.items():
            journal.setattr(project.take.cameras[c], "video_path", path, "cameras")

"""Edit-menu commands that need no algorithm: usable from Python without Qt.

Every command refuses bad input with :class:`CommandError` before changing anything.
Selections are read when the command is created, so redo repeats exactly the same edit.
"""

from __future__ import annotations

import copy
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

# the result commands live in commands.results; importable from here as before
from carapost.commands.results import (  # noqa: F401
    OBS_ARRAYS,
    ApplyPointData,
    ReplaceDetections,
)
from carapost.commands.stack import Command, CommandError, Journal
from carapost.model.project import (
    RECON_INTERPOLATED,
    RECON_NONE,
    SOURCE_BLOB,
    SOURCE_NONE,
    Project,
    Stick,
)

_POSITION_ARRAYS = ("positions", "recon", "residual")


def _columns(project: Project, point_ids: Iterable[int]) -> NDArray[np.intp]:
    ids = sorted(set(int(p) for p in point_ids))
    if not ids:
        return np.zeros(0, dtype=np.intp)
    try:
        return np.sort(project.points.index_of(ids))
    except KeyError as exc:
        raise CommandError(str(exc.args[0])) from None


def _frames(project: Project, frames: tuple[int, int]) -> slice:
    a, b = int(frames[0]), int(frames[1])
    if not (0 <= a <= b < project.n_frames):
        raise CommandError(f"frames {a}-{b} are outside the take (0-{project.n_frames - 1})")
    return slice(a, b + 1)


def _clear_points(
    journal: Journal, project: Project, frames: slice, cols: NDArray, *, obs: bool
) -> None:
    """Clear 3D data (and the attached 2D observations when ``obs``) of a block."""
    pts = project.points
    names = _POSITION_ARRAYS + (OBS_ARRAYS if obs else ())
    journal.point_block(frames, cols, names)
    from carapost.model.project import POINT_ARRAYS

    for name in names:
        fill = POINT_ARRAYS[name][1]
        sub = pts.arrays[name][frames]
        sub[:, cols] = fill


def _detach(
    journal: Journal, project: Project, frames: slice, cols: NDArray, cams: NDArray
) -> None:
    pts = project.points
    journal.point_block(frames, cols, OBS_ARRAYS)
    from carapost.model.project import POINT_ARRAYS

    fr = np.arange(project.n_frames)[frames]
    ix = np.ix_(fr, cols, cams)
    for name in OBS_ARRAYS:
        pts.arrays[name][ix] = POINT_ARRAYS[name][1]


def _attach(project: Project, frame: int, column: int, cam: int, det_index: int) -> None:
    pts = project.points
    centre = project.detections.centres(frame, cam)
    if not 0 <= det_index < len(centre):
        raise CommandError(f"no detection {det_index} in camera {cam} at frame {frame}")
    pts.obs[frame, column, cam] = centre[det_index]
    pts.source[frame, column, cam] = SOURCE_BLOB
    pts.detection[frame, column, cam] = det_index
    pts.quality[frame, column, cam] = 1.0
    pts.keyframe[frame, column, cam] = False


def _check_detections(project: Project, detections: Iterable[Sequence[int]]) -> list[tuple]:
    out = []
    for d in detections:
        f, c, k = (int(x) for x in d)
        if not (0 <= f < project.n_frames and 0 <= c < project.n_cameras):
            raise CommandError(f"detection ({f}, {c}, {k}) is outside the take")
        if not 0 <= k < len(project.detections.centres(f, c)):
            raise CommandError(f"no detection {k} in camera {c} at frame {f}")
        out.append((f, c, k))
    return sorted(set(out))


def _points_and_detections(
    project: Project,
    point_ids: Iterable[int] | None,
    detections: Iterable[Sequence[int]] | None,
) -> tuple[list[int], list[tuple]]:
    """Sorted unique point ids and checked detections to act on (None: the selection's)."""
    sel = project.selection
    ids = sorted(set(sel.points if point_ids is None else point_ids))
    dets = _check_detections(project, sel.detections if detections is None else detections)
    return ids, dets


# ----------------------------------------------------------------------------------------
# Points
# ----------------------------------------------------------------------------------------
class CreatePointsFromDetections(Command):
    """For each given detection, a new point with that detection attached."""

    description = "Create Points From Detections"

    def __init__(self, project: Project, detections: Iterable[Sequence[int]] | None = None):
        super().__init__()
        dets = project.selection.detections if detections is None else detections
        self.detections = _check_detections(project, dets)
        if not self.detections:
            raise CommandError("Create Points From Detections: no detection is selected")

    def apply(self, project: Project, journal: Journal) -> None:
        cols = journal.append_points(len(self.detections))
        for col, (f, c, k) in zip(cols, self.detections, strict=True):
            _attach(project, f, int(col), c, k)


class DeleteSelected(Command):
    """Delete points (whole take) and/or detections (and detach them from points)."""

    description = "Delete Selected"

    def __init__(
        self,
        project: Project,
        point_ids: Iterable[int] | None = None,
        detections: Iterable[Sequence[int]] | None = None,
    ):
        super().__init__()
        self.point_ids, self.detections = _points_and_detections(project, point_ids, detections)
        if not self.point_ids and not self.detections:
            raise CommandError("Delete Selected: nothing is selected")

    def apply(self, project: Project, journal: Journal) -> None:
        if self.detections:
            by_image: dict[tuple[int, int], list[int]] = {}
            for f, c, k in self.detections:
                by_image.setdefault((f, c), []).append(k)
            _delete_detections(journal, project, by_image)
        if self.point_ids:
            journal.remove_points(_columns(project, self.point_ids))
        journal.setattr(project, "selection", type(project.selection)(
            cameras=project.selection.cameras), "selection")


def _delete_detections(
    journal: Journal, project: Project, by_image: Mapping[tuple[int, int], Sequence[int]]
) -> None:
    """Delete detections image by image, remapping the indices points hold."""
    pts = project.points
    images = sorted(by_image)
    journal.detections(images)
    tables = []
    for (f, c) in images:
        table = project.detections.get(f, c)
        n = len(table["centre"])
        drop = np.zeros(n, dtype=bool)
        drop[np.asarray(by_image[(f, c)], dtype=np.intp)] = True
        remap = np.full(n, -1, dtype=np.int32)
        remap[~drop] = np.arange(int((~drop).sum()), dtype=np.int32)
        tables.append({k: v[~drop].copy() for k, v in table.items()})
        refs = pts.detection[f, :, c]
        cols = np.flatnonzero(refs >= 0)
        if len(cols):
            journal.point_block(slice(f, f + 1), cols, OBS_ARRAYS)
            new = remap[refs[cols]]
            lost = cols[new < 0]
            pts.detection[f, cols, c] = np.where(new >= 0, new, -1)
            if len(lost):
                pts.obs[f, lost, c] = np.nan
                pts.source[f, lost, c] = SOURCE_NONE
                pts.quality[f, lost, c] = 0
                pts.keyframe[f, lost, c] = False
    project.detections.replace_images(images, tables)


class SplitSelectedPoint(Command):
    """From ``frame`` on, move a point's data to a new point (two ids from then on)."""

    description = "Split Selected Point"

    def __init__(self, project: Project, point_id: int | None = None, frame: int | None = None):
        super().__init__()
        if point_id is None:
            if len(project.selection.points) != 1:
                raise CommandError("Split Selected Point: select exactly one point")
            point_id = next(iter(project.selection.points))
        self.point_id = int(point_id)
        _columns(project, [self.point_id])
        self.frame = project.current_frame if frame is None else int(frame)
        if not 0 <= self.frame < project.n_frames:
            raise CommandError(f"Split Selected Point: frame {self.frame} is outside the take")

    def apply(self, project: Project, journal: Journal) -> None:
        pts = project.points
        src = int(pts.index_of([self.point_id])[0])
        kind = int(pts.kind[src])
        new = int(journal.append_points(1, kind=kind)[0])
        src = int(pts.index_of([self.point_id])[0])
        tail = slice(self.frame, project.n_frames)
        journal.point_block(tail, [src])
        for arr in pts.arrays.values():
            sub = arr[tail]
            sub[:, new] = sub[:, src]
        from carapost.model.project import POINT_ARRAYS

        for name, arr in pts.arrays.items():
            sub = arr[tail]
            sub[:, src] = POINT_ARRAYS[name][1]
        journal.setattr(project, "selection", type(project.selection)(
            points=frozenset({int(pts.ids[new])}), cameras=project.selection.cameras),
            "selection")


class Merge(Command):
    """Merge points and/or detections into one point.

    The first (lowest id) point is kept; for every frame and camera where it has no
    observation, the other points' observations fill in (and 3D where it has none).
    Selected detections are attached to the kept point; with no point selected, a new
    point is created from the detections.
    """

    description = "Merge"

    def __init__(
        self,
        project: Project,
        point_ids: Iterable[int] | None = None,
        detections: Iterable[Sequence[int]] | None = None,
    ):
        super().__init__()
        self.point_ids, self.detections = _points_and_detections(project, point_ids, detections)
        _columns(project, self.point_ids)
        if len(self.point_ids) + len(self.detections) < 2:
            raise CommandError("Merge: select at least two points or detections")
        images = [(f, c) for f, c, _ in self.detections]
        if len(set(images)) != len(images):
            raise CommandError("Merge: two selected detections are in the same image")

    def apply(self, project: Project, journal: Journal) -> None:
        pts = project.points
        if self.point_ids:
            keep_id = self.point_ids[0]
        else:
            col = journal.append_points(1)
            keep_id = int(pts.ids[col[0]])
        keep = int(pts.index_of([keep_id])[0])
        others = _columns(project, self.point_ids[1:])
        all_frames = slice(0, project.n_frames)
        if len(others):
            journal.point_block(all_frames, [keep])
            for o in others:
                empty = np.isnan(pts.obs[:, keep, :, 0]) & ~np.isnan(pts.obs[:, o, :, 0])
                for name in OBS_ARRAYS:
                    arr = pts.arrays[name]
                    arr[:, keep][empty] = arr[:, o][empty]
                no3d = np.isnan(pts.positions[:, keep, 0]) & ~np.isnan(pts.positions[:, o, 0])
                for name in _POSITION_ARRAYS:
                    arr = pts.arrays[name]
                    arr[:, keep][no3d] = arr[:, o][no3d]
            if not pts.labels[keep]:
                labelled = [pts.labels[o] for o in others if pts.labels[o]]
                if labelled:
                    old = list(pts.labels)
                    journal.call(lambda old=old: setattr(pts, "labels", old), "labels")
                    pts.labels[keep] = labelled[0]
            journal.remove_points(others)
            keep = int(pts.index_of([keep_id])[0])
        if self.detections:
            for f, c, k in self.detections:
                journal.point_block(slice(f, f + 1), [keep], OBS_ARRAYS)
                _attach(project, f, keep, c, k)
        journal.setattr(project, "selection", type(project.selection)(
            points=frozenset({keep_id}), cameras=project.selection.cameras), "selection")


class ClearSelected(Command):
    """Remove the 3D data and attached 2D observations of points over a frame range.

    The detections themselves stay in the images.
    """

    def __init__(
        self,
        project: Project,
        frames: tuple[int, int],
        point_ids: Iterable[int] | None = None,
        *,
        description: str = "Clear Selected",
    ):
        super().__init__()
        self.description = description
        self.point_ids = sorted(project.selection.points if point_ids is None else point_ids)
        if not self.point_ids:
            raise CommandError(f"{description}: no point is selected")
        self.frames = frames
        _frames(project, frames)

    @classmethod
    def current_frame(cls, project: Project, point_ids: Iterable[int] | None = None):
        """Clear Selected [Current Frame]."""
        f = project.current_frame
        return cls(project, (f, f), point_ids, description="Clear Selected [Current Frame]")

    @classmethod
    def active_range(cls, project: Project, point_ids: Iterable[int] | None = None):
        """Clear Selected [Active Range]."""
        return cls(project, project.active_range, point_ids,
                   description="Clear Selected [Active Range]")

    def apply(self, project: Project, journal: Journal) -> None:
        cols = _columns(project, self.point_ids)
        _clear_points(journal, project, _frames(project, self.frames), cols, obs=True)


class ClearActiveRange(Command):
    """Clear every point over the active range (detections stay)."""

    description = "Clear Active Range"

    def __init__(self, project: Project):
        super().__init__()
        self.frames = project.active_range

    def apply(self, project: Project, journal: Journal) -> None:
        cols = np.arange(project.n_points)
        _clear_points(journal, project, _frames(project, self.frames), cols, obs=True)


class DetachDetections(Command):
    """Detach the 2D data of points in some cameras over a frame range."""

    def __init__(
        self,
        project: Project,
        frames: tuple[int, int],
        cameras: Iterable[int] | None = None,
        point_ids: Iterable[int] | None = None,
        *,
        description: str = "Detach Detections",
    ):
        super().__init__()
        self.description = description
        self.point_ids = sorted(project.selection.points if point_ids is None else point_ids)
        if not self.point_ids:
            raise CommandError(f"{description}: no point is selected")
        if cameras is None:
            cams = project.selection.cameras
            if not cams:
                raise CommandError(
                    f"{description}: no camera view is active or explicitly selected"
                )
        else:
            cams = cameras
        self.cameras = sorted(int(c) for c in cams)
        if any(not 0 <= c < project.n_cameras for c in self.cameras):
            raise CommandError(f"{description}: camera out of range {self.cameras}")
        self.frames = frames
        _frames(project, frames)

    @classmethod
    def current_frame(cls, project: Project, active_camera: int | None = None, **kw: Any):
        """Detach Detections [Current Frame]: explicit camera selection wins over the view."""
        cams = project.selection.cameras or ({active_camera} if active_camera is not None
                                             else None)
        f = project.current_frame
        return cls(project, (f, f), cams, description="Detach Detections [Current Frame]", **kw)

    @classmethod
    def active_range(cls, project: Project, active_camera: int | None = None, **kw: Any):
        """Detach Detections [Active Range]."""
        cams = project.selection.cameras or ({active_camera} if active_camera is not None
                                             else None)
        return cls(project, project.active_range, cams,
                   description="Detach Detections [Active Range]", **kw)

    def apply(self, project: Project, journal: Journal) -> None:
        cols = _columns(project, self.point_ids)
        _detach(journal, project, _frames(project, self.frames), cols,
                np.asarray(self.cameras, dtype=np.intp))


class RemoveUnusedDetections(Command):
    """Delete every detection of the take that no point uses."""

    description = "Remove Unused Detections"

    def apply(self, project: Project, journal: Journal) -> None:
        det = project.detections
        pts = project.points
        counts = det.counts()
        by_image: dict[tuple[int, int], list[int]] = {}
        for f, c in zip(*np.nonzero(counts), strict=True):
            used = pts.detection[f, :, c]
            used = used[used >= 0]
            n = counts[f, c]
            unused = np.setdiff1d(np.arange(n), used)
            if len(unused):
                by_image[(int(f), int(c))] = unused.tolist()
        if by_image:
            _delete_detections(journal, project, by_image)


class RemoveInterpolated3DPoints(Command):
    """Remove interpolated 3D samples of the selected (or all) points in the active range."""

    description = "Remove Interpolated 3D Points"

    def __init__(self, project: Project, point_ids: Iterable[int] | None = None):
        super().__init__()
        ids = project.selection.points if point_ids is None else point_ids
        self.point_ids = sorted(ids) if ids else None
        self.frames = project.active_range

    def apply(self, project: Project, journal: Journal) -> None:
        pts = project.points
        cols = (np.arange(pts.count) if self.point_ids is None
                else _columns(project, self.point_ids))
        fr = _frames(project, self.frames)
        interp = pts.recon[fr][:, cols] == RECON_INTERPOLATED
        # a few samples of a long block change: save only those (masked diff)
        journal.point_mask(fr, cols, interp, _POSITION_ARRAYS + ("sigma",))
        for name, fill in (("positions", np.nan), ("residual", np.nan), ("recon", RECON_NONE),
                           ("sigma", np.nan)):
            sub = pts.arrays[name][fr]
            block = sub[:, cols]
            block[interp] = fill
            sub[:, cols] = block


class RenamePoint(Command):
    """Give a point a label (an empty string unlabels it)."""

    description = "Rename Point"

    def __init__(self, project: Project, point_id: int, label: str):
        super().__init__()
        label = label.strip()
        if " " in label:
            raise CommandError(f"Rename Point: a label cannot contain a space ({label!r})")
        self.point_id = int(point_id)
        _columns(project, [self.point_id])
        self.label = label
        self.description = f"Rename Point {self.point_id} to {label or '(none)'}"

    def apply(self, project: Project, journal: Journal) -> None:
        _set_point_labels(journal, project, {self.point_id: self.label})


def _set_point_labels(journal: Journal, project: Project, mapping: Mapping[int, str]) -> None:
    pts = project.points
    new = list(pts.labels)
    for pid, label in mapping.items():
        col = int(pts.index_of([pid])[0])
        if label:
            # a label names one point: take it from any other point that has it
            for i, lab in enumerate(new):
                if lab == label and i != col:
                    new[i] = ""
        new[col] = label
    journal.setattr(pts, "labels", new, "labels")
    missing = [lab for lab in mapping.values() if lab and lab not in project.labels]
    if missing:
        journal.setattr(project, "labels", list(project.labels) + missing, "labels")


class AssignLabel(RenamePoint):
    """Assign a label of the Labelling pane to a point."""

    def __init__(self, project: Project, point_id: int, label: str):
        super().__init__(project, point_id, label)
        self.description = f"Label point {self.point_id} {label}"


class UnlabelSelectedPoints(Command):
    """Detach labels from the selected points."""

    description = "Unlabel Selected Points"

    def __init__(self, project: Project, point_ids: Iterable[int] | None = None):
        super().__init__()
        self.point_ids = sorted(project.selection.points if point_ids is None else point_ids)
        if not self.point_ids:
            raise CommandError("Unlabel Selected Points: no point is selected")
        _columns(project, self.point_ids)

    def apply(self, project: Project, journal: Journal) -> None:
        _set_point_labels(journal, project, {p: "" for p in self.point_ids})


class AddLabels(Command):
    """Add names to the label list (Import Labels From Text/Cara File)."""

    description = "Import Labels"

    def __init__(self, project: Project, names: Sequence[str], *, description: str | None = None):
        super().__init__()
        from carapost.io.labels import merge_labels

        self.names = merge_labels(project.labels, list(names))
        if description:
            self.description = description

    def apply(self, project: Project, journal: Journal) -> None:
        journal.setattr(project, "labels", list(project.labels) + self.names, "labels")


class ClearAllLabels(Command):
    """Empty the label list of the Labelling pane."""

    description = "Clear All Labels"

    def apply(self, project: Project, journal: Journal) -> None:
        journal.setattr(project, "labels", [], "labels")


class DeleteSelectedLabels(Command):
    """Remove some names from the label list (points keep theirs unless ``unlabel``)."""

    description = "Delete Selected Labels"

    def __init__(self, project: Project, names: Iterable[str]):
        super().__init__()
        self.names = set(names)
        if not self.names:
            raise CommandError("Delete Selected Labels: no label is selected")

    def apply(self, project: Project, journal: Journal) -> None:
        journal.setattr(
            project, "labels", [n for n in project.labels if n not in self.names], "labels"
        )


class CreateStick(Command):
    """A stick between two points."""

    description = "Create Stick"

    def __init__(self, project: Project, point_ids: Iterable[int] | None = None,
                 colour: tuple[int, int, int] = (255, 255, 0)):
        super().__init__()
        ids = sorted(project.selection.points if point_ids is None else point_ids)
        if len(ids) != 2:
            raise CommandError("Create Stick: select exactly two points")
        _columns(project, ids)
        if any({s.a, s.b} == set(ids) for s in project.sticks):
            raise CommandError(f"Create Stick: points {ids[0]} and {ids[1]} already have one")
        self.ids = ids
        self.colour = tuple(int(x) for x in colour)

    def apply(self, project: Project, journal: Journal) -> None:
        sticks = copy.deepcopy(project.sticks) + [Stick(self.ids[0], self.ids[1], self.colour)]
        journal.setattr(project, "sticks", sticks, "sticks")


class EditStickColor(Command):
    """Change the colour of some sticks (by index in ``project.sticks``)."""

    description = "Edit Stick Color"

    def __init__(self, project: Project, sticks: Iterable[int], colour: tuple[int, int, int]):
        super().__init__()
        self.indices = sorted(set(int(i) for i in sticks))
        if not self.indices:
            raise CommandError("Edit Stick Color: no stick is selected")
        if any(not 0 <= i < len(project.sticks) for i in self.indices):
            raise CommandError("Edit Stick Color: no such stick")
        if len(colour) != 3 or any(not 0 <= int(x) <= 255 for x in colour):
            raise CommandError(f"Edit Stick Color: {colour} is not an RGB colour (0-255)")
        self.colour = tuple(int(x) for x in colour)

    def apply(self, project: Project, journal: Journal) -> None:
        sticks = copy.deepcopy(project.sticks)
        for i in self.indices:
            sticks[i].colour = self.colour
        journal.setattr(project, "sticks", sticks, "sticks")


# ----------------------------------------------------------------------------------------
# Properties, cameras, ranges
# ----------------------------------------------------------------------------------------
class SetProperties(Command):
    """Change properties (validated all-or-nothing before anything changes)."""

    def __init__(self, project: Project, values: Mapping[str, Any]):
        super().__init__()
        from carapost.model.properties import PropertyError

        try:
            self.values = {k: project.properties.spec(k).validate(v) for k, v in values.items()}
        except (PropertyError, KeyError) as exc:
            raise CommandError(str(exc)) from None
        self.description = "Set " + ", ".join(
            project.properties.spec(k).label for k in self.values
        )

    def apply(self, project: Project, journal: Journal) -> None:
        journal.properties(self.values)
        project.properties.update(self.values)


class RestorePropertiesToDefaults(Command):
    """Reset every property to its default."""

    description = "Restore Properties To Defaults"

    def apply(self, project: Project, journal: Journal) -> None:
        props = project.properties
        journal.properties(props.keys())
        props.restore_defaults()


class RevertBlobParameters(Command):
    """Read Blob Parameters From Pico Files: back to the values stored at import."""

    description = "Read Blob Parameters From Take"

    def __init__(self, project: Project):
        super().__init__()
        if not project.imported_blob_parameters:
            raise CommandError(
                "Read Blob Parameters: this project has no blob parameters stored at import"
            )
        self.values = dict(project.imported_blob_parameters)

    def apply(self, project: Project, journal: Journal) -> None:
        journal.properties(self.values)
        project.properties.update(self.values)


def _cameras_arg(project: Project, cameras: Iterable[int] | None, what: str) -> list[int]:
    cams = sorted(project.selection.cameras if cameras is None else set(cameras))
    if not cams:
        raise CommandError(f"{what}: select one or more camera views (Shift+click)")
    if any(not 0 <= c < project.n_cameras for c in cams):
        raise CommandError(f"{what}: no camera {cams}")
    return cams


class IncrementImageSequenceOffset(Command):
    """Move the video of the selected cameras one frame forward."""

    description = "Increment Image Sequence Offset"

    def __init__(self, project: Project, cameras: Iterable[int] | None = None, step: int = 1):
        super().__init__()
        self.cameras = _cameras_arg(project, cameras, self.description)
        self.step = int(step)

    def apply(self, project: Project, journal: Journal) -> None:
        cams = copy.deepcopy(project.take.cameras)
        for c in self.cameras:
            cams[c].frame_offset += self.step
        journal.setattr(project.take, "cameras", cams, "cameras")


class RotateSelectedSensors(Command):
    """Rotate the display of the selected cameras by 90 degrees."""

    def __init__(self, project: Project, cameras: Iterable[int] | None = None,
                 clockwise: bool = True):
        super().__init__()
        self.description = (
            f"Rotate Selected Sensors {'Clockwise' if clockwise else 'Anticlockwise'}"
        )
        self.cameras = _cameras_arg(project, cameras, self.description)
        self.delta = 90 if clockwise else -90

    def apply(self, project: Project, journal: Journal) -> None:
        cams = copy.deepcopy(project.take.cameras)
        for c in self.cameras:
            cams[c].rotation = (cams[c].rotation + self.delta) % 360
        journal.setattr(project.take, "cameras", cams, "cameras")


class SetRange(Command):
    """Set the active or view range (Ctrl+1/2/3, Set View Range to Active Range, ...)."""

    def __init__(self, project: Project, which: str, frames: tuple[int, int] | None,
                 description: str | None = None):
        super().__init__()
        if which not in ("active_range", "view_range"):
            raise ValueError(which)
        self.which = which
        full = (0, max(project.n_frames - 1, 0))
        rng = full if frames is None else (int(frames[0]), int(frames[1]))
        if rng[0] > rng[1]:
            rng = (rng[1], rng[0])
        if not (0 <= rng[0] and rng[1] < max(project.n_frames, 1)):
            raise CommandError(f"range {rng} is outside the take (0-{full[1]})")
        self.range = rng
        self.description = description or f"Set {which.replace('_', ' ')} {rng[0]}-{rng[1]}"

    @classmethod
    def active_start(cls, project: Project) -> SetRange:
        """Set Active Range Start (Ctrl+1): start at the current frame."""
        end = max(project.active_range[1], project.current_frame)
        return cls(project, "active_range", (project.current_frame, end),
                   "Set Active Range Start")

    @classmethod
    def active_end(cls, project: Project) -> SetRange:
        """Set Active Range End (Ctrl+2): end at the current frame."""
        start = min(project.active_range[0], project.current_frame)
        return cls(project, "active_range", (start, project.current_frame),
                   "Set Active Range End")

    @classmethod
    def reset_active(cls, project: Project) -> SetRange:
        """Reset Active Range (Ctrl+3)."""
        return cls(project, "active_range", None, "Reset Active Range")

    @classmethod
    def view_to_active(cls, project: Project) -> SetRange:
        """Set View Range to Active Range."""
        return cls(project, "view_range", project.active_range, "Set View Range to Active Range")

    @classmethod
    def reset_view(cls, project: Project) -> SetRange:
        """Reset View Range."""
        return cls(project, "view_range", None, "Reset View Range")

    def apply(self, project: Project, journal: Journal) -> None:
        journal.setattr(project, self.which, self.range, "ranges")

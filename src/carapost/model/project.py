"""The project model: one take, its calibration, detections and points, as columnar arrays.

Sizes designed for: 36,000 frames, 2-16 cameras, 300 points, ~400 detections per image.
Nothing here is a Python object per point-frame; per-point metadata (id, label, kind) are
short lists, everything per frame is a numpy array.

Array layout (F frames, P points, C cameras)
------------------------------------------
``points.positions``   [F, P, 3] float32  3D position (mm, brim frame); NaN where none
``points.recon``       [F, P]    int8     reconstruction kind (``RECON_*``)
``points.residual``    [F, P]    float32  RMS distance of the point to its rays (mm); NaN if none
``points.obs``         [F, P, C, 2] float32 2D observation (px, raw); NaN where none
``points.source``      [F, P, C] int8     where the observation came from (``SOURCE_*``)
``points.detection``   [F, P, C] int32    index of the attached detection in its image, -1
``points.quality``     [F, P, C] float16  match quality 0-1 (patch NCC, target-track score)
``points.keyframe``    [F, P, C] bool     target-track keyframe
"""

from __future__ import annotations

import copy as _copy
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from carapost.algorithms.camera import CameraIntrinsics
from carapost.algorithms.codes import (  # defined once there, re-exported here
    CAMERA_ARRAYS,  # noqa: F401
    KIND_BRIM,  # noqa: F401
    KIND_FACE,
    OPTIONAL_POINT_ARRAYS,  # noqa: F401
    POINT_ARRAYS,
    RAW_POINT_ARRAYS,  # noqa: F401
    RECON_FILTERED,  # noqa: F401
    RECON_INTERPOLATED,  # noqa: F401
    RECON_NAMES,  # noqa: F401
    RECON_NONE,  # noqa: F401
    RECON_SINGLE_SENSOR,  # noqa: F401
    RECON_TRIANGULATED,  # noqa: F401
    SOURCE_BLOB,  # noqa: F401
    SOURCE_KEYFRAME,  # noqa: F401
    SOURCE_MANUAL,  # noqa: F401
    SOURCE_NAMES,  # noqa: F401
    SOURCE_NONE,  # noqa: F401
    SOURCE_PATCH,  # noqa: F401
    SOURCE_TARGET,  # noqa: F401
    blank_point_array,
)
from carapost.model.events import EventHub

# Blob colours.
COLOUR_BLACK = 0
COLOUR_WHITE = 1


@dataclass
class CameraChannel:
    """One camera of the take.

    Attributes
    ----------
    name : str
        Channel name (the ``<channel>`` of ``<take>_<channel>.mkv``).
    video_path : str
        Absolute path of the video file or image-sequence folder ("" if none).
    image_size : tuple of int
        (width, height) in pixels.
    rotation : int
        Display rotation in degrees (0, 90, 180, 270).
    frame_offset : int
        Image sequence offset: video frame = take frame + offset.
    """

    name: str
    video_path: str = ""
    image_size: tuple[int, int] = (1280, 720)
    rotation: int = 0
    frame_offset: int = 0


@dataclass
class Take:
    """Take metadata."""

    name: str = "take"
    cameras: list[CameraChannel] = field(default_factory=list)
    n_frames: int = 0
    fps: float = 60.0
    timecode_start: str = "00:00:00:00"
    metadata: dict[str, Any] = field(default_factory=dict)

    @property
    def n_cameras(self) -> int:
        """Number of cameras."""
        return len(self.cameras)


class Calibration:
    """Per-camera intrinsics and per-frame extrinsics.

    Attributes
    ----------
    intrinsics : CameraIntrinsics or None
    R : ndarray, shape (F, C, 3, 3) float64
        World->camera rotation per frame (identity where unsolved).
    t : ndarray, shape (F, C, 3) float64
        World->camera translation (mm).
    solved : ndarray, shape (F,) bool
        Frames whose cameras were solved (from an XCP or the brim).
    """

    def __init__(self, n_frames: int, n_cameras: int) -> None:
        self.intrinsics: CameraIntrinsics | None = None
        self.R = np.broadcast_to(np.eye(3), (n_frames, n_cameras, 3, 3)).copy()
        self.t = np.zeros((n_frames, n_cameras, 3))
        self.solved = np.zeros(n_frames, dtype=bool)
        self.xcp_extras: Any = None

    def set_static(self, R: NDArray, t: NDArray, frames: slice | None = None) -> None:
        """Give every frame (or ``frames``) the same cameras, R [C,3,3], t [C,3]."""
        sl = frames if frames is not None else slice(None)
        self.R[sl] = R
        self.t[sl] = t
        self.solved[sl] = True

    def copy(self) -> Calibration:
        """A deep copy."""
        out = Calibration(0, 0)
        out.intrinsics = None if self.intrinsics is None else self.intrinsics.copy()
        out.R, out.t, out.solved = self.R.copy(), self.t.copy(), self.solved.copy()
        out.xcp_extras = _copy.deepcopy(self.xcp_extras)
        return out


class Detections:
    """Blob detections of every image: a ragged table, one run per (frame, camera).

    Detection ``k`` of image (f, c) lives at flat row ``offsets[f * C + c] + k``; points
    refer to detections by ``(f, c, k)`` so rebuilding the flat arrays never invalidates
    their references. Axes, angle and score are float16 to keep 43 M detections of a
    long take within memory; centres stay float32 (sub-pixel accuracy matters).

    ``offsets`` and the flat ``arrays`` are never changed in place: every edit
    (:meth:`replace_images`) builds new arrays, and the views :meth:`get` returns are for
    reading. So a reference to them is a snapshot (the trackers' jobs keep references
    instead of copying every detection of a long take on the GUI thread).
    """

    FIELDS: dict[str, tuple[str, tuple[int, ...]]] = {
        "centre": ("float32", (2,)),
        "axes": ("float16", (2,)),
        "angle": ("float16", ()),
        "colour": ("int8", ()),
        "score": ("float16", ()),
    }

    def __init__(self, n_frames: int, n_cameras: int) -> None:
        self.n_frames = n_frames
        self.n_cameras = n_cameras
        self.offsets = np.zeros(n_frames * n_cameras + 1, dtype=np.int64)
        self.arrays: dict[str, NDArray] = {
            k: np.zeros((0,) + shape, dtype=dt) for k, (dt, shape) in self.FIELDS.items()
        }

    # -- queries -------------------------------------------------------------------------
    @property
    def total(self) -> int:
        """Number of detections in the whole take."""
        return int(self.offsets[-1])

    def counts(self) -> NDArray[np.int64]:
        """Detections per image, shape (F, C)."""
        return np.diff(self.offsets).reshape(self.n_frames, self.n_cameras)

    def image_slice(self, frame: int, camera: int) -> slice:
        """Flat rows of image (frame, camera)."""
        i = frame * self.n_cameras + camera
        return slice(int(self.offsets[i]), int(self.offsets[i + 1]))

    def get(self, frame: int, camera: int) -> dict[str, NDArray]:
        """Views of the detections of one image (``centre`` [N,2], ``axes``, ...)."""
        sl = self.image_slice(frame, camera)
        return {k: v[sl] for k, v in self.arrays.items()}

    def centres(self, frame: int, camera: int) -> NDArray[np.float32]:
        """Centres (px) of one image, shape (N, 2)."""
        return self.arrays["centre"][self.image_slice(frame, camera)]

    # -- edits (used by commands) ----------------------------------------------------------
    def take_images(self, images: list[tuple[int, int]]) -> list[dict[str, NDArray]]:
        """Copies of the detections of the given images."""
        return [{k: v.copy() for k, v in self.get(f, c).items()} for f, c in images]

    def replace_images(
        self, images: list[tuple[int, int]], tables: list[dict[str, NDArray]]
    ) -> None:
        """Replace the detections of the given images (one table per image).

        Rebuilds the flat arrays with one gather, O(total detections).
        """
        if not images:
            return
        C = self.n_cameras
        counts = np.diff(self.offsets).copy()
        img_index = np.array([f * C + c for f, c in images], dtype=np.int64)
        if len(np.unique(img_index)) != len(img_index):
            raise ValueError("an image appears twice in one replacement")
        new_counts = counts.copy()
        for idx, table in zip(img_index, tables, strict=True):
            new_counts[idx] = len(table["centre"])
        replaced = np.zeros(len(counts), dtype=bool)
        replaced[img_index] = True
        # Old rows kept: every row whose image is not replaced.
        row_image = np.repeat(np.arange(len(counts)), counts)
        keep_rows = np.flatnonzero(~replaced[row_image])
        new_offsets = np.zeros_like(self.offsets)
        np.cumsum(new_counts, out=new_offsets[1:])
        new_row_image = np.repeat(np.arange(len(counts)), new_counts)
        dest_keep = np.flatnonzero(~replaced[new_row_image])
        total = int(new_offsets[-1])
        for key, (dt, shape) in self.FIELDS.items():
            old = self.arrays[key]
            arr = np.empty((total,) + shape, dtype=dt)
            arr[dest_keep] = old[keep_rows]
            for idx, table in zip(img_index, tables, strict=True):
                s, e = new_offsets[idx], new_offsets[idx + 1]
                if e > s:
                    arr[s:e] = np.asarray(table[key]).astype(dt, copy=False).reshape(
                        (e - s,) + shape
                    )
            self.arrays[key] = arr
        self.offsets = new_offsets

    def copy(self) -> Detections:
        """A deep copy."""
        out = Detections(self.n_frames, self.n_cameras)
        out.offsets = self.offsets.copy()
        out.arrays = {k: v.copy() for k, v in self.arrays.items()}
        return out

    def nbytes(self) -> int:
        """Memory held (bytes)."""
        return int(self.offsets.nbytes + sum(v.nbytes for v in self.arrays.values()))


def empty_table() -> dict[str, NDArray]:
    """A detection table with no rows."""
    return {k: np.zeros((0,) + shape, dtype=dt) for k, (dt, shape) in Detections.FIELDS.items()}


class Points:
    """Points (markers) of the take: per-point metadata and per-frame arrays."""

    def __init__(self, n_frames: int, n_cameras: int) -> None:
        self.n_frames = n_frames
        self.n_cameras = n_cameras
        self.ids = np.zeros(0, dtype=np.int64)
        self.labels: list[str] = []
        self.kind = np.zeros(0, dtype=np.int8)
        self.arrays: dict[str, NDArray] = {
            name: self._blank(name, 0) for name in POINT_ARRAYS
        }
        self.next_id = 1

    def _blank(self, name: str, n_points: int) -> NDArray:
        return blank_point_array(name, self.n_frames, n_points, self.n_cameras)

    def __getattr__(self, name: str) -> NDArray:
        # positions, recon, residual, obs, source, detection, quality, keyframe
        arrays = self.__dict__.get("arrays")
        if arrays is not None and name in arrays:
            return arrays[name]
        raise AttributeError(name)

    @property
    def count(self) -> int:
        """Number of points P."""
        return int(self.ids.shape[0])

    def index_of(self, point_ids: Any) -> NDArray[np.intp]:
        """Column indices of point ids (KeyError for unknown ids)."""
        ids = np.atleast_1d(np.asarray(point_ids, dtype=np.int64))
        order = np.argsort(self.ids)
        pos = np.searchsorted(self.ids, ids, sorter=order)
        pos = np.clip(pos, 0, max(len(order) - 1, 0))
        if len(order) == 0 or np.any(self.ids[order[pos]] != ids):
            missing = set(ids.tolist()) - set(self.ids.tolist())
            raise KeyError(f"no point with id {sorted(missing)}")
        return order[pos].astype(np.intp)

    def allocate_ids(self, n: int) -> NDArray[np.int64]:
        """Fresh point ids."""
        out = np.arange(self.next_id, self.next_id + n, dtype=np.int64)
        self.next_id += n
        return out

    # -- structural edits ---------------------------------------------------------------
    def extract(self, columns: NDArray[np.intp]) -> dict[str, Any]:
        """Copies of whole columns (everything that describes these points)."""
        columns = np.asarray(columns, dtype=np.intp)
        return {
            "columns": columns.copy(),
            "ids": self.ids[columns].copy(),
            "labels": [self.labels[i] for i in columns],
            "kind": self.kind[columns].copy(),
            "arrays": {k: v[:, columns].copy() for k, v in self.arrays.items()},
        }

    def remove(self, columns: NDArray[np.intp]) -> dict[str, Any]:
        """Remove columns; returns what :meth:`insert` needs to put them back."""
        saved = self.extract(columns)
        keep = np.ones(self.count, dtype=bool)
        keep[np.asarray(columns, dtype=np.intp)] = False
        self.ids = self.ids[keep]
        self.kind = self.kind[keep]
        self.labels = [lab for lab, k in zip(self.labels, keep, strict=True) if k]
        self.arrays = {k: v[:, keep] for k, v in self.arrays.items()}
        return saved

    def insert(self, saved: dict[str, Any]) -> None:
        """Insert columns at their saved positions (inverse of :meth:`remove`)."""
        cols = np.asarray(saved["columns"], dtype=np.intp)
        order = np.argsort(cols)
        cols = cols[order]
        n_new = self.count + len(cols)
        is_new = np.zeros(n_new, dtype=bool)
        is_new[cols] = True
        old_pos = np.flatnonzero(~is_new)
        ids = np.empty(n_new, dtype=np.int64)
        ids[old_pos], ids[cols] = self.ids, saved["ids"][order]
        kind = np.empty(n_new, dtype=np.int8)
        kind[old_pos], kind[cols] = self.kind, saved["kind"][order]
        labels: list[str] = [""] * n_new
        for p, lab in zip(old_pos, self.labels, strict=True):
            labels[p] = lab
        for p, j in zip(cols, order, strict=True):
            labels[p] = saved["labels"][j]
        arrays = {}
        for k, v in self.arrays.items():
            arr = np.empty((v.shape[0], n_new) + v.shape[2:], dtype=v.dtype)
            arr[:, old_pos] = v
            arr[:, cols] = saved["arrays"][k][:, order]
            arrays[k] = arr
        self.ids, self.kind, self.labels, self.arrays = ids, kind, labels, arrays
        if len(ids):
            self.next_id = max(self.next_id, int(ids.max()) + 1)

    def append(
        self, n: int, *, labels: list[str] | None = None, kind: int | NDArray = KIND_FACE
    ) -> NDArray[np.intp]:
        """Append ``n`` empty points; returns their column indices."""
        ids = self.allocate_ids(n)
        cols = np.arange(self.count, self.count + n, dtype=np.intp)
        saved = {
            "columns": cols,
            "ids": ids,
            "labels": list(labels) if labels is not None else [""] * n,
            "kind": np.broadcast_to(np.asarray(kind, dtype=np.int8), (n,)).copy(),
            "arrays": {k: self._blank(k, n) for k in POINT_ARRAYS},
        }
        self.insert(saved)
        return cols

    def copy(self) -> Points:
        """A deep copy."""
        out = Points(self.n_frames, self.n_cameras)
        out.ids, out.kind, out.labels = self.ids.copy(), self.kind.copy(), list(self.labels)
        out.arrays = {k: v.copy() for k, v in self.arrays.items()}
        out.next_id = self.next_id
        return out

    def nbytes(self) -> int:
        """Memory held (bytes)."""
        return int(sum(v.nbytes for v in self.arrays.values()))


@dataclass
class Stick:
    """A line drawn between two points."""

    a: int  # point id
    b: int  # point id
    colour: tuple[int, int, int] = (255, 255, 0)


@dataclass
class Selection:
    """What the user has selected.

    ``points`` are point ids; ``detections`` are (frame, camera, index) triples;
    ``cameras`` is the explicit camera selection used by processing and detach commands
    (empty = all cameras). ``order`` holds the selected point ids in the order they were
    selected (Align Data takes origin, direction and plane in click order).
    """

    points: frozenset[int] = frozenset()
    detections: frozenset[tuple[int, int, int]] = frozenset()
    cameras: frozenset[int] = frozenset()
    order: tuple[int, ...] = ()

    def ordered_points(self) -> list[int]:
        """The selected point ids, oldest selection first (ids without a recorded order,
        e.g. from an older file, follow in id order)."""
        known = [p for p in self.order if p in self.points]
        return known + sorted(self.points.difference(known))


@dataclass
class RomReference:
    """A loaded ROM project used by Initialize From ROM (kept by path and content)."""

    path: str
    project: Any = None


class Project:
    """All state of one carapost project.

    Parameters
    ----------
    take : Take
        The take: cameras, frame count, rate, start timecode.
    """

    def __init__(self, take: Take | None = None) -> None:
        from carapost.model.properties import Properties

        self.events = EventHub()
        self.take = take if take is not None else Take()
        F, C = self.take.n_frames, self.take.n_cameras
        self.calibration = Calibration(F, C)
        self.detections = Detections(F, C)
        self.points = Points(F, C)
        self.labels: list[str] = []
        self.sticks: list[Stick] = []
        self.properties = Properties(
            on_change=lambda keys: self.events.emit("properties")
        )
        self.current_frame = 0
        self.active_range: tuple[int, int] = (0, max(F - 1, 0))
        self.view_range: tuple[int, int] = (0, max(F - 1, 0))
        self.selection = Selection()
        self.rom: RomReference | None = None
        self.path: str | None = None
        self.imported_blob_parameters: dict[str, Any] | None = None
        # the Session calls that made this project, oldest first (plain JSON values;
        # carapost.session.script writes and replays them; None: not recorded)
        self.script: list[dict[str, Any]] | None = None
        # Stabilize Data / Align Data (carapost.model.stabilization): never raw positions
        self.stabilization: Any = None
        self.alignment: Any = None
        # Target Tracker pattern (blue box) and search (green cross) sizes the artist set
        # for one point in one camera: (point id, camera) -> (pattern px, search px);
        # a track without an entry uses the Target Tracker's defaults
        self.target_sizes: dict[tuple[int, int], tuple[int, int]] = {}
        self.show_stabilized = False
        self.modified = False
        # file bookkeeping kept by carapost.io.cara and the recovery code: the newer
        # autosave found beside the file when it was opened, the autosave of an untitled
        # project, the autosave this session wrote beside a saved one, and (path, size,
        # mtime_ns, inode) of a file whose arrays are still memory-mapped
        self.newer_autosave: Path | None = None
        self.untitled_autosave: Path | None = None
        self.session_autosave: Path | None = None
        self.mapped_source: tuple[str, int, int, int] | None = None

    # -- sizes ---------------------------------------------------------------------------
    @property
    def n_frames(self) -> int:
        """Number of frames F."""
        return self.take.n_frames

    @property
    def n_cameras(self) -> int:
        """Number of cameras C."""
        return self.take.n_cameras

    @property
    def n_points(self) -> int:
        """Number of points P."""
        return self.points.count

    # -- ranges and selection (validated setters that emit only on real change) -----------
    def _check_range(self, rng: tuple[int, int], what: str) -> tuple[int, int]:
        a, b = int(rng[0]), int(rng[1])
        if not (0 <= a <= b < max(self.n_frames, 1)):
            raise ValueError(
                f"{what} {a}-{b} is outside the take (frames 0-{max(self.n_frames - 1, 0)})"
            )
        return a, b

    def set_current_frame(self, frame: int) -> None:
        """Move to ``frame`` (clamped to the take)."""
        frame = int(min(max(frame, 0), max(self.n_frames - 1, 0)))
        if frame != self.current_frame:
            self.current_frame = frame
            self.events.emit("current_frame", frames=(frame, frame))

    def set_active_range(self, rng: tuple[int, int]) -> None:
        """Set the active range (inclusive frame indices)."""
        rng = self._check_range(rng, "active range")
        if rng != self.active_range:
            self.active_range = rng
            self.events.emit("ranges")

    def set_view_range(self, rng: tuple[int, int]) -> None:
        """Set the view range (inclusive frame indices)."""
        rng = self._check_range(rng, "view range")
        if rng != self.view_range:
            self.view_range = rng
            self.events.emit("ranges")

    def set_selection(
        self,
        points: Any = None,
        detections: Any = None,
        cameras: Any = None,
    ) -> None:
        """Replace parts of the selection (None keeps that part)."""
        sel = self.selection
        order = sel.order
        if points is not None:
            given = list(dict.fromkeys(int(p) for p in points))
            kept = [p for p in sel.ordered_points() if p in set(given)]
            order = tuple(kept + [p for p in given if p not in set(kept)])
        new = Selection(
            frozenset(order) if points is not None else sel.points,
            frozenset(tuple(int(x) for x in d) for d in detections)
            if detections is not None
            else sel.detections,
            frozenset(int(c) for c in cameras) if cameras is not None else sel.cameras,
            order,
        )
        if new != sel:
            self.selection = new
            self.events.emit("selection")

    def selected_columns(self) -> NDArray[np.intp]:
        """Column indices of the selected points (sorted)."""
        ids = sorted(p for p in self.selection.points if p in set(self.points.ids.tolist()))
        return np.sort(self.points.index_of(ids)) if ids else np.zeros(0, dtype=np.intp)

    def processing_cameras(self) -> NDArray[np.intp]:
        """Explicitly selected cameras, or all cameras when none is selected."""
        if self.selection.cameras:
            return np.array(sorted(self.selection.cameras), dtype=np.intp)
        return np.arange(self.n_cameras, dtype=np.intp)

    def point_label(self, column: int) -> str:
        """Display name of a point: its label, or ``Point <id>`` when unlabelled."""
        lab = self.points.labels[column]
        return lab if lab else f"Point {int(self.points.ids[column])}"

    def nbytes(self) -> int:
        """Memory held by the big arrays (bytes)."""
        return self.points.nbytes() + self.detections.nbytes() + int(
            self.calibration.R.nbytes + self.calibration.t.nbytes
        )


def new_project(
    n_frames: int,
    n_cameras: int,
    *,
    fps: float = 60.0,
    name: str = "take",
    image_size: tuple[int, int] = (1280, 720),
) -> Project:
    """An empty project with ``n_cameras`` cameras named ``cam0..`` and ``n_frames`` frames."""
    take = Take(
        name=name,
        cameras=[CameraChannel(f"cam{i}", image_size=image_size) for i in range(n_cameras)],
        n_frames=n_frames,
        fps=fps,
    )
    return Project(take)

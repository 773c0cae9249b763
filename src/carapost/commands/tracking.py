"""Process-menu tracking commands: Track Forwards/Backwards and Initialize from ROM.

Each operation is split in two so a GUI can run the slow part on a worker thread:

- ``compute_tracking(project, ...)`` / ``compute_rom_initialisation(project, ...)`` read
  the project (copies only, no mutation) and return a result object;
- ``TrackResultCommand(result)`` / ``RomResultCommand(result)`` apply it on the GUI thread
  as ONE undoable step (point arrays, cameras and any detections found on the fly).

``TrackCommand(project, ...)`` and ``InitializeFromRom(project, ...)`` do both at once for
scripts. Bad input raises :class:`~carapost.commands.stack.CommandError` with a message
that is also logged on the ``carapost.process`` logger.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from carapost.algorithms.camera import CameraIntrinsics
from carapost.algorithms.params import from_mapping
from carapost.algorithms.rom import RomParameters, initialize_from_rom
from carapost.algorithms.tracking import (
    InitialState,
    RaggedDetections,
    TrackingParameters,
    TrackResult,
    make_spawner,
    track,
    track_take,
)
from carapost.commands.process import check_frame, refuse, require_intrinsics, set_cameras
from carapost.commands.stack import Command, Journal
from carapost.model.project import (
    KIND_BRIM,
    KIND_FACE,
    Project,
    RomReference,
    Stick,
)

log = logging.getLogger("carapost.process")

_ARRAYS = ("positions", "recon", "residual", "obs", "source", "detection", "quality")

__all__ = [
    "InitializeFromRom",
    "LoadRom",
    "RomComputation",
    "RomResultCommand",
    "TrackCommand",
    "TrackComputation",
    "TrackResultCommand",
    "TrackTakeCommand",
    "compute_take_tracking",
    "compute_rom_initialisation",
    "compute_tracking",
]


def _intrinsics(project: Project, what: str) -> CameraIntrinsics:
    return require_intrinsics(project, what, "import an XCP file or initialise from a ROM")


def _tracking_parameters(project: Project, what: str, **overrides: Any) -> TrackingParameters:
    try:
        return TrackingParameters.from_mapping(
            project.properties.section("Tracking Parameters"), **overrides)
    except (TypeError, ValueError) as exc:
        raise refuse(f"{what}: {exc}") from None


def _write_point_block(journal: Journal, project: Project, frames: slice, cols: NDArray,
                       value: Callable[[str], NDArray]) -> None:
    """Write the tracked arrays of points ``cols`` over ``frames`` as one undoable block.

    ``value(name)`` gives each array of `_ARRAYS` for the block (broadcast to
    ``[frames, cols, ...]``); the keyframe flags there are cleared.
    """
    pts = project.points
    journal.point_block(frames, cols, _ARRAYS + ("keyframe",))
    for name in _ARRAYS:
        sub = pts.arrays[name][frames]
        sub[:, cols] = value(name)
    sub = pts.keyframe[frames]
    sub[:, cols] = False


# ------------------------------------------------------------------------------------------
# Tracking
# ------------------------------------------------------------------------------------------
@dataclass
class TrackComputation:
    """What :func:`compute_tracking` found (nothing of the project is changed).

    Attributes
    ----------
    result : TrackResult
    point_ids : list of int
        Ids of the tracked points (the point axis of the result arrays).
    detected_images : list of (frame, camera)
    detected_tables : list of dict
        Detections found on the fly for frames that had none.
    description : str
    """

    result: TrackResult
    point_ids: list[int]
    detected_images: list[tuple[int, int]] = field(default_factory=list)
    detected_tables: list[dict[str, NDArray]] = field(default_factory=list)
    description: str = "Track"

    @property
    def cancelled(self) -> bool:
        """True when the user cancelled (the frames tracked so far are kept)."""
        return bool(self.result.cancelled)


def _detection_source(project: Project, get_image: Callable[[int, int], NDArray] | None,
                      found: dict[tuple[int, int], dict[str, NDArray]]
                      ) -> Callable[[int], list[tuple[NDArray, NDArray | None]]]:
    """Per-frame detections; frames with none are detected on the fly when images exist."""
    det = project.detections
    ragged = RaggedDetections(det.offsets.copy(), det.arrays["centre"].copy(),
                              det.arrays["axes"].copy(), project.n_cameras)
    counts = det.counts().copy()
    blob_params = None

    def source(frame: int) -> list[tuple[NDArray, NDArray | None]]:
        nonlocal blob_params
        if counts[frame].sum() > 0 or get_image is None:
            return ragged(frame)
        from carapost.algorithms.blobs import BlobParameters, detect_blobs

        if blob_params is None:
            blob_params = from_mapping(BlobParameters, project.properties)
        out = []
        for c in range(project.n_cameras):
            d = detect_blobs(get_image(frame, c), blob_params)
            found[(frame, c)] = d._asdict()
            out.append((d.centre.astype(np.float64), d.axes.astype(np.float64)))
        return out

    return source


def compute_tracking(
    project: Project,
    direction: int = 1,
    *,
    single_frame: bool = False,
    point_ids: Iterable[int] | None = None,
    frame: int | None = None,
    progress: Callable[[int, int], bool] | None = None,
    get_image: Callable[[int, int], NDArray] | None = None,
) -> TrackComputation:
    """Track points from the current frame (thread-safe: reads copies, changes nothing).

    Parameters
    ----------
    project : Project
    direction : int
        +1 forwards, -1 backwards.
    single_frame : bool
        Track into the next (previous) frame only; else to the end (start) of the active
        range.
    point_ids : iterable of int, optional
        Points to track; default the selected points, or all when none is selected. Brim
        points are always tracked (they fix the cameras of each frame).
    frame : int, optional
        Start frame (default: the current frame).
    progress : callable, optional
        ``progress(done, total)``; False cancels and keeps the frames tracked.
    get_image : callable, optional
        ``get_image(frame, camera)`` -> grey image: patch tracking and blob detection of
        frames that have none.

    Returns
    -------
    TrackComputation

    Raises
    ------
    CommandError
        No calibration, no point with 3D data at the start frame, nothing to track in
        that direction, unknown point ids or bad parameters.
    """
    if direction not in (1, -1):
        raise ValueError(f"direction must be +1 or -1, got {direction!r}")
    what = ("Track Forwards" if direction > 0 else "Track Backwards") + \
        (" [Single Frame]" if single_frame else " [Sequence]")
    intr = _intrinsics(project, what)
    params = _tracking_parameters(project, what)
    pts = project.points
    start = check_frame(project, frame, what)
    a, b = project.active_range
    if single_frame:
        stop = start + direction
    else:
        stop = b if direction > 0 else a
    stop = min(max(stop, 0), project.n_frames - 1)
    if (stop - start) * direction <= 0:
        raise refuse(f"{what}: nothing to track from frame {start} "
                      f"({'end' if direction > 0 else 'start'} of the active range)")
    if point_ids is None:
        cols = project.selected_columns()
        if cols.size == 0:
            cols = np.arange(pts.count, dtype=np.intp)
    else:
        try:
            cols = np.sort(pts.index_of(sorted(set(int(p) for p in point_ids))))
        except KeyError as exc:
            raise refuse(f"{what}: {exc.args[0]}") from None
    brim = np.flatnonzero(pts.kind == KIND_BRIM)
    cols = np.union1d(cols, brim).astype(np.intp)
    X0 = pts.positions[start, cols].astype(np.float64)
    face_ok = np.isfinite(X0).all(-1) & (pts.kind[cols] != KIND_BRIM)
    if not face_ok.any():
        raise refuse(f"{what}: no point has a 3D position at frame {start} (initialise "
                      "the frame first)")
    cal = project.calibration
    has_brim = bool(np.isfinite(X0[pts.kind[cols] == KIND_BRIM]).all(-1).any()) \
        if brim.size else False
    if not cal.solved[start]:
        raise refuse(f"{what}: the cameras of frame {start} are not solved (Solve "
                      "Calibration Brim first)")
    if not has_brim:
        lo, hi = min(start, stop), max(start, stop)
        if not cal.solved[lo:hi + 1].all():
            raise refuse(f"{what}: without a calibration brim every frame's cameras must "
                          "be solved (import an XCP calibration)")
    # start-frame observations and blob sizes (for patch templates and the size test)
    obs0 = pts.obs[start, cols].astype(np.float64)
    det0 = pts.detection[start, cols]
    axes0 = np.full(det0.shape + (2,), np.nan)
    for c in range(project.n_cameras):
        ax = project.detections.get(start, c)["axes"].astype(np.float64)
        m = (det0[:, c] >= 0) & (det0[:, c] < len(ax))
        axes0[m, c] = ax[det0[m, c]]
    initial = InitialState(X0, pts.kind[cols].copy(), obs0, axes0)
    found: dict[tuple[int, int], dict[str, NDArray]] = {}
    source = _detection_source(project, get_image, found)
    result = track(source, initial, cal.R.copy(), cal.t.copy(), intr, params, start=start,
                   stop=stop, get_image=get_image, resolve_cameras=has_brim,
                   progress=progress)
    images = sorted(found)
    desc = f"{what} [frames {min(start, stop)}-{max(start, stop)}]"
    if result.cancelled:
        log.info("%s cancelled after %d frames (kept)", what, result.frames_done)
    return TrackComputation(result, [int(i) for i in pts.ids[cols]], images,
                            [found[k] for k in images], desc)


def _store_found(journal: Journal, project: Project, images: list[tuple[int, int]],
                 tables: list[dict[str, NDArray]]) -> None:
    """Store (undoably) the detections the tracker found on the fly, which its
    observations refer to."""
    if images:
        journal.detections(images)
        project.detections.replace_images(images, tables)


class TrackResultCommand(Command):
    """Apply a :class:`TrackComputation` as one undoable step."""

    def __init__(self, computation: TrackComputation, project: Project | None = None):
        super().__init__()
        self.computation = computation
        self.description = computation.description

    def apply(self, project: Project, journal: Journal) -> None:
        comp = self.computation
        res = comp.result
        _store_found(journal, project, comp.detected_images, comp.detected_tables)
        if res.last < res.first:
            return
        fr = slice(res.first, res.last + 1)
        cols = project.points.index_of(comp.point_ids)
        _write_point_block(journal, project, fr, cols, lambda name: getattr(res, name))
        set_cameras(journal, project, fr, res.R, res.t)

    def memory(self) -> int:
        """Bytes held (saved slices plus the result kept for redo)."""
        res = self.computation.result
        return super().memory() + sum(int(np.asarray(getattr(res, n)).nbytes)
                                      for n in _ARRAYS)


class TrackCommand(TrackResultCommand):
    """Track Forwards/Backwards [Sequence] or [Single Frame] (Ctrl+W) in one call.

    Parameters are those of :func:`compute_tracking`.
    """

    def __init__(self, project: Project, direction: int = 1, single_frame: bool = False,
                 point_ids: Iterable[int] | None = None,
                 progress: Callable[[int, int], bool] | None = None,
                 get_image: Callable[[int, int], NDArray] | None = None,
                 frame: int | None = None):
        comp = compute_tracking(project, direction, single_frame=single_frame,
                                point_ids=point_ids, frame=frame, progress=progress,
                                get_image=get_image)
        super().__init__(comp)


@dataclass
class TakeTrackComputation:
    """What :func:`compute_take_tracking` found (nothing of the project is changed).

    Attributes
    ----------
    result : TrackResult
        Every frame of the take; the point axis is ``point_ids`` then ``n_new`` new face
        points.
    point_ids : list of int
    start : int
        The initialised frame (its rows of the existing points are not overwritten).
    description : str
    detected_images : list of (frame, camera)
    detected_tables : list of dict
        Detections found on the fly for frames that had none.
    """

    result: TrackResult
    point_ids: list[int]
    start: int
    description: str = "Track Take"
    detected_images: list[tuple[int, int]] = field(default_factory=list)
    detected_tables: list[dict[str, NDArray]] = field(default_factory=list)

    @property
    def cancelled(self) -> bool:
        """True when the user cancelled."""
        return bool(self.result.cancelled)


def compute_take_tracking(
    project: Project,
    frame: int | None = None,
    *,
    find_markers: bool = True,
    spawn_interval: int = 1,
    progress: Callable[[int, int], bool] | None = None,
    get_image: Callable[[int, int], NDArray] | None = None,
) -> TakeTrackComputation:
    """Track every point over the whole take from one frame, finding missed markers.

    Runs :func:`carapost.algorithms.tracking.track_take`: forwards to the end (backwards
    when ``frame`` is the last frame) with Initialize 3D run on the unused detections
    (``find_markers``; the tracked points are its seeds, so nothing is created twice),
    then over the whole take the other way guided by the first pass, so each marker is
    tracked from its first appearance; points are then split where they hop to another
    marker and pieces of one marker joined. Thread-safe: reads copies, changes nothing.
    With ``get_image(frame, camera)``, point-cameras without a blob are patch tracked and
    frames without detections are detected on the fly (as in :class:`TrackCommand`).

    Raises
    ------
    CommandError
        No calibration, unsolved start frame, no point with 3D data there, bad parameters.
    """
    from carapost.algorithms.init3d import Init3DParameters

    what = "Track Take"
    intr = _intrinsics(project, what)
    params = _tracking_parameters(project, what)
    pts = project.points
    start = check_frame(project, frame, what)
    cal = project.calibration
    if not cal.solved[start]:
        raise refuse(f"{what}: the cameras of frame {start} are not solved (Solve "
                      "Calibration Brim first)")
    X0 = pts.positions[start].astype(np.float64)
    kind = pts.kind.copy()
    if not (np.isfinite(X0).all(-1) & (kind != KIND_BRIM)).any():
        raise refuse(f"{what}: no point has a 3D position at frame {start} (initialise "
                      "the frame first)")
    brim = kind == KIND_BRIM
    has_brim = bool(np.isfinite(X0[brim]).all(-1).any()) if brim.any() else False
    if not has_brim and not cal.solved.all():
        raise refuse(f"{what}: without a calibration brim every frame's cameras must be "
                      "solved (import an XCP calibration)")
    obs0 = pts.obs[start].astype(np.float64)
    det0 = pts.detection[start]
    axes0 = np.full(det0.shape + (2,), np.nan)
    for c in range(project.n_cameras):
        ax = project.detections.get(start, c)["axes"].astype(np.float64)
        m = (det0[:, c] >= 0) & (det0[:, c] < len(ax))
        axes0[m, c] = ax[det0[m, c]]
    spawn = None
    if find_markers:
        try:
            ip = from_mapping(Init3DParameters, project.properties)
        except (TypeError, ValueError) as exc:
            raise refuse(f"{what}: {exc}") from None
        bm = X0[brim][np.isfinite(X0[brim]).all(-1)] if has_brim else None
        caddies = tuple((i, i + 1) for i in range(0, intr.n_cameras - 1, 2))
        spawn = make_spawner(intr, caddies, ip, brim_model=bm)
    found: dict[tuple[int, int], dict[str, NDArray]] = {}
    source = _detection_source(project, get_image, found)
    R = cal.R[start].copy() if has_brim else cal.R.copy()
    t = cal.t[start].copy() if has_brim else cal.t.copy()
    result = track_take(source, InitialState(X0, kind, obs0, axes0), R, t, intr, params,
                        start=start, n_frames=project.n_frames, spawn=spawn,
                        spawn_interval=spawn_interval, resolve_cameras=has_brim,
                        progress=progress, get_image=get_image)
    images = sorted(found)
    return TakeTrackComputation(result, [int(i) for i in pts.ids], start,
                                f"{what} [from frame {start}]", images,
                                [found[k] for k in images])


class TrackTakeCommand(Command):
    """Track Take: every point over the whole take, missed markers found on the way.

    Parameters
    ----------
    project : Project
    frame : int, optional
        Initialised frame to start from (default: the current frame).
    computation : TakeTrackComputation, optional
        A result computed on a worker thread (then nothing is computed here).
    progress : callable, optional
    find_markers : bool
        Find markers Initialize 3D missed (default True).
    get_image : callable, optional
        ``get_image(frame, camera)`` -> grey image: patch tracking, and blob detection of
        frames that have none.
    """

    def __init__(self, project: Project, frame: int | None = None, *,
                 computation: TakeTrackComputation | None = None,
                 progress: Callable[[int, int], bool] | None = None,
                 find_markers: bool = True,
                 get_image: Callable[[int, int], NDArray] | None = None):
        super().__init__()
        self.computation = computation or compute_take_tracking(
            project, frame, progress=progress, find_markers=find_markers,
            get_image=get_image)
        self.description = self.computation.description

    def apply(self, project: Project, journal: Journal) -> None:
        comp = self.computation
        res = comp.result
        _store_found(journal, project, comp.detected_images, comp.detected_tables)
        if res.last < res.first:
            return
        pts = project.points
        old = pts.index_of(comp.point_ids)
        new = (journal.append_points(res.n_new, kind=KIND_FACE) if res.n_new
               else np.zeros(0, np.intp))
        cols = np.concatenate([old, new]).astype(np.intp)
        frames = np.arange(res.first, res.last + 1)
        fr = slice(res.first, res.last + 1)
        keep_start = frames == comp.start

        def value(name: str) -> NDArray:
            cur = pts.arrays[name][fr][:, cols]
            val = np.asarray(getattr(res, name)).astype(cur.dtype)
            # the initialised frame of the existing points stays as initialised
            val[keep_start, : old.size] = cur[keep_start, : old.size]
            return val

        _write_point_block(journal, project, fr, cols, value)
        cal = project.calibration
        Rn, tn = res.R.copy(), res.t.copy()
        Rn[keep_start], tn[keep_start] = cal.R[comp.start], cal.t[comp.start]
        set_cameras(journal, project, fr, Rn, tn)

    def memory(self) -> int:
        """Bytes held (saved slices plus the result kept for redo)."""
        res = self.computation.result
        return super().memory() + sum(int(np.asarray(getattr(res, n)).nbytes)
                                      for n in _ARRAYS)


# ------------------------------------------------------------------------------------------
# ROM
# ------------------------------------------------------------------------------------------
class LoadRom(Command):
    """Load ROM: keep a ``.cara`` project to initialise this take from."""

    def __init__(self, project: Project, path: str | Path):
        from carapost.io.cara import load_project
        from carapost.io.errors import CaraFileError

        super().__init__()
        p = Path(path)
        try:
            rom = load_project(p)
        except CaraFileError as exc:
            raise refuse(f"Load ROM: {exc}") from None
        if rom.points.count == 0:
            raise refuse(f"Load ROM: {p} has no points to initialise from")
        if rom.calibration.intrinsics is None:
            raise refuse(f"Load ROM: {p} has no camera calibration")
        self.reference = RomReference(path=str(p.absolute()), project=rom)
        self.description = f"Load ROM {p.name}"
        log.info("Loaded ROM %s: %d points, %d frames", p, rom.points.count, rom.n_frames)

    def apply(self, project: Project, journal: Journal) -> None:
        old = project.rom

        def undo() -> None:
            project.rom = old

        journal.call(undo, "rom")
        project.rom = self.reference


@dataclass
class RomComputation:
    """What :func:`compute_rom_initialisation` found (nothing is changed)."""

    frame: int
    rom_frame: int
    labels: list[str]
    kind: NDArray[np.int8]
    rom_ids: NDArray[np.int64]
    existing_ids: NDArray[np.int64]  # id of the existing point reused per row, -1 = new
    result: Any
    intrinsics: Any
    sticks: list[tuple[int, int, tuple[int, int, int]]]  # rows into the result, colour
    rom_label_list: list[str]
    brim_only: bool
    description: str


def compute_rom_initialisation(project: Project, *, brim_only: bool = False,
                               frame: int | None = None) -> RomComputation:
    """Match the loaded ROM's frame to a frame of this take (changes nothing).

    Raises
    ------
    CommandError
        No ROM loaded, camera counts differ, bad parameters, or nothing matched.
    """
    what = "Initialize from ROM" + (" [Brim Only]" if brim_only else "")
    if project.rom is None or project.rom.project is None:
        raise refuse(f"{what}: no ROM is loaded (File > Load ROM first)")
    rom: Project = project.rom.project
    f = check_frame(project, frame, what)
    if rom.n_cameras != project.n_cameras:
        raise refuse(f"{what}: the ROM has {rom.n_cameras} cameras, this take "
                      f"{project.n_cameras}")
    try:
        rp = from_mapping(RomParameters, project.properties)
    except (TypeError, ValueError) as exc:
        raise refuse(f"{what}: {exc}") from None
    rf = rp.rom_frame_index
    if not 0 <= rf < rom.n_frames:
        raise refuse(f"{what}: ROM Frame Index {rf} is outside the ROM take (0-"
                      f"{rom.n_frames - 1})")
    if not rom.calibration.solved[rf]:
        raise refuse(f"{what}: the ROM's cameras are not solved at frame {rf}")
    tparams = _tracking_parameters(project, what)
    rpts = rom.points
    X = rpts.positions[rf].astype(np.float64)
    keep = np.isfinite(X).all(-1)
    if brim_only:
        keep &= rpts.kind == KIND_BRIM
    rows = np.flatnonzero(keep)
    if rows.size == 0:
        raise refuse(f"{what}: the ROM has no {'brim ' if brim_only else ''}points with a "
                      f"3D position at frame {rf}")
    intr = project.calibration.intrinsics
    if intr is None or intr.n_cameras != project.n_cameras:
        intr = rom.calibration.intrinsics
    dets = RaggedDetections(project.detections.offsets, project.detections.arrays["centre"],
                            project.detections.arrays["axes"], project.n_cameras)(f)
    if not any(len(d[0]) for d in dets):
        raise refuse(f"{what}: frame {f} has no detections (run Detect Blobs)")
    res = initialize_from_rom(dets, X[rows], rpts.kind[rows], rom.calibration.R[rf],
                              rom.calibration.t[rf], intr, rp, tparams)
    n_found = int(np.isfinite(res.positions).all(-1).sum())
    if n_found == 0:
        raise refuse(f"{what}: no ROM point could be matched at frame {f} (try a ROM Frame "
                      "Index closer to this frame's pose, or larger ROM tracking distances)")
    labels = [rpts.labels[i] for i in rows]
    kind = rpts.kind[rows].copy()
    # reuse this take's points of the same label and kind instead of duplicating them
    existing = np.full(rows.size, -1, dtype=np.int64)
    by_label = {(lab, int(k)): int(i) for lab, k, i in zip(
        project.points.labels, project.points.kind, project.points.ids, strict=True) if lab}
    for j, (lab, k) in enumerate(zip(labels, kind, strict=True)):
        if lab:
            existing[j] = by_label.get((lab, int(k)), -1)
    if (existing >= 0).any():
        log.warning("%s: this take already has %d of the ROM's points; updating them at "
                    "frame %d instead of adding duplicates", what, int((existing >= 0).sum()),
                    f)
    elif (project.points.kind == KIND_FACE).any() and not brim_only:
        log.warning("%s: this take already has face points; the ROM's points are added "
                    "beside them", what)
    row_of = {int(rpts.ids[r]): j for j, r in enumerate(rows)}
    sticks = [(row_of[s.a], row_of[s.b], s.colour) for s in rom.sticks
              if s.a in row_of and s.b in row_of]
    desc = f"{what} [frame {f}, ROM frame {rf}]"
    log.info("%s: matched %d of %d points", desc, n_found, rows.size)
    return RomComputation(f, rf, labels, kind, rpts.ids[rows].copy(), existing, res,
                          intr, sticks, list(rom.labels), brim_only, desc)


class RomResultCommand(Command):
    """Apply a :class:`RomComputation` as one undoable step."""

    def __init__(self, computation: RomComputation, project: Project | None = None):
        super().__init__()
        self.computation = computation
        self.description = computation.description

    def apply(self, project: Project, journal: Journal) -> None:
        comp = self.computation
        res = comp.result
        f = comp.frame
        pts = project.points
        cal = project.calibration
        if cal.intrinsics is None:
            journal.setattr(cal, "intrinsics", comp.intrinsics.copy(), "cameras")
        # brim points of the ROM replace the take's brim (the structure comes with them)
        new_rows = np.flatnonzero(comp.existing_ids < 0)
        if (comp.kind[new_rows] == KIND_BRIM).any():
            old_brim = np.flatnonzero(pts.kind == KIND_BRIM)
            reused = set(int(i) for i in comp.existing_ids[comp.existing_ids >= 0])
            drop = [c for c in old_brim if int(pts.ids[c]) not in reused]
            if drop:
                journal.remove_points(np.asarray(drop, dtype=np.intp))
        cols = np.empty(len(comp.labels), dtype=np.intp)
        old = comp.existing_ids >= 0
        if old.any():
            cols[old] = pts.index_of(comp.existing_ids[old])
        if new_rows.size:
            cols[new_rows] = journal.append_points(
                new_rows.size, labels=[comp.labels[j] for j in new_rows],
                kind=comp.kind[new_rows])
        brim_rows = np.flatnonzero(comp.kind == KIND_BRIM)
        if brim_rows.size:
            # the brim structure holds in every frame
            bcols = cols[brim_rows]
            journal.point_block(slice(None), bcols, ("positions",))
            pts.positions[:, bcols] = res.structure[brim_rows].astype(np.float32)[None]
        _write_point_block(journal, project, slice(f, f + 1), cols,
                           lambda name: getattr(res, name))
        set_cameras(journal, project, f, res.R, res.t)
        if not comp.brim_only:
            ids = pts.ids[cols]
            new_sticks = [Stick(int(ids[a]), int(ids[b]), tuple(col))
                          for a, b, col in comp.sticks]
            have = {(s.a, s.b) for s in project.sticks}
            new_sticks = [s for s in new_sticks if (s.a, s.b) not in have]
            if new_sticks:
                journal.setattr(project, "sticks", project.sticks + new_sticks, "sticks")
            missing = [lab for lab in comp.rom_label_list if lab not in project.labels]
            if missing:
                journal.setattr(project, "labels", project.labels + missing, "labels")


class InitializeFromRom(RomResultCommand):
    """Initialize from ROM / Initialize from ROM [Brim Only] at the current frame."""

    def __init__(self, project: Project, brim_only: bool = False, frame: int | None = None):
        super().__init__(compute_rom_initialisation(project, brim_only=brim_only,
                                                    frame=frame))

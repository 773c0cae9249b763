"""Process-menu tracking steps: Track Forwards/Backwards, Track Take, Initialize from ROM.

Each follows the recipe of :mod:`carapost.commands.recipe`:

- ``prepare_tracking`` / ``prepare_take_tracking`` / ``prepare_rom_initialisation``
  ``(project, ...) -> Job`` validate and snapshot (calling thread);
- ``job.compute(progress)`` runs the tracker on the snapshot (worker thread, no project)
  and returns a :class:`TrackComputation` / :class:`TakeTrackComputation` /
  :class:`RomComputation` (each a :class:`~carapost.commands.recipe.Result`);
- ``ApplyResult(result)`` applies it as ONE undoable step (point arrays, cameras and any
  detections found on the fly).

``compute_*(project, ...)`` (prepare + compute) and the one-call commands
``TrackCommand(project, ...)``, ``TrackTakeCommand(project, ...)`` and
``InitializeFromRom(project, ...)`` remain for scripts. Bad input raises
:class:`~carapost.commands.stack.CommandError` with a message that is also logged on the
``carapost.process`` logger.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from carapost.algorithms.camera import CameraIntrinsics
from carapost.algorithms.params import from_mapping
from carapost.algorithms.tracking import (
    InitialState,
    RaggedDetections,
    TrackingParameters,
    TrackResult,
    make_spawner,
    track,
    track_take,
)
from carapost.commands.process import (
    check_frame,
    refuse,
    require_intrinsics,
    set_cameras,
)
from carapost.commands.recipe import Job, Progress, Result, ResultCommand
from carapost.commands.results import write_detections
from carapost.commands.stack import Journal
from carapost.model.project import (
    KIND_BRIM,
    KIND_FACE,
    Project,
)
from carapost.model.rig import caddies

log = logging.getLogger("carapost.process")

_ARRAYS = ("positions", "recon", "residual", "obs", "source", "detection", "quality")

__all__ = [
    "TrackCommand",
    "TrackComputation",
    "TrackResultCommand",
    "TrackTakeCommand",
    "prepare_take_tracking",
    "prepare_tracking",
    "tracked_arrays",
    "tracking_intrinsics",
    "tracking_parameters",
]


def tracking_intrinsics(project: Project, what: str) -> CameraIntrinsics:
    """The intrinsics, refused with the tracking remedy (XCP file or ROM) when missing."""
    return require_intrinsics(project, what, "import an XCP file or initialise from a ROM")


def tracking_parameters(project: Project, what: str) -> TrackingParameters:
    """The Tracking Parameters section as parameters, refused as ``what`` when bad."""
    try:
        return from_mapping(TrackingParameters,
                            project.properties.section("Tracking Parameters"))
    except (TypeError, ValueError) as exc:
        raise refuse(f"{what}: {exc}") from None


def tracked_arrays(value: Callable[[str], NDArray], *, sigma: bool = False) -> dict[str, Any]:
    """The arrays a tracker writes (``value(name)`` for positions, recon, residual, obs,
    source, detection, quality, and sigma when ``sigma``), with the keyframe flags
    cleared: for :meth:`Journal.write_points` (which clears sigma without one)."""
    names = _ARRAYS + (("sigma",) if sigma else ())
    arrays: dict[str, Any] = {name: value(name) for name in names}
    arrays["keyframe"] = False
    return arrays


# ------------------------------------------------------------------------------------------
# Tracking
# ------------------------------------------------------------------------------------------
def _read_only(a: NDArray) -> NDArray:
    """A view of ``a`` the worker cannot write through."""
    v = a.view()
    v.flags.writeable = False
    return v


class _Detections:
    """A snapshot of the take's detections, read by the tracker frame by frame.

    It keeps read-only references to the take's flat detection arrays instead of copies
    (copying the centres and axes of a 36,000-frame, 4-camera take with 100 detections
    per image took ~35 ms of the GUI thread and ~175 MB per job; keeping references,
    ~1.5 ms): :class:`carapost.model.project.Detections` never changes those arrays in
    place (every edit rebuilds them), so the snapshot stays what it was when taken.

    Frames with none are detected on the fly when an image source is given; what is
    found goes into ``found`` so the result can store it.
    """

    def __init__(self, project: Project) -> None:
        det = project.detections
        self.ragged = RaggedDetections(_read_only(det.offsets),
                                       _read_only(det.arrays["centre"]),
                                       _read_only(det.arrays["axes"]), project.n_cameras,
                                       _read_only(det.arrays["score"]))
        self.counts = det.counts()  # a new array (np.diff)
        self.n_cameras = project.n_cameras
        self.blob_section = dict(project.properties.section("Blob Parameters"))

    def run(self, get_image: Callable[[int, int], NDArray] | None,
            tracker: Callable[[Callable[[int], list[tuple[NDArray, NDArray | None]]]],
                              TrackResult],
            ) -> tuple[TrackResult, list[tuple[int, int]], list[dict[str, NDArray]]]:
        """``tracker(source)`` on this snapshot; returns its result and the detections
        found on the fly (images in order, one table each)."""
        found: dict[tuple[int, int], dict[str, NDArray]] = {}
        result = tracker(self.source(get_image, found))
        images = sorted(found)
        return result, images, [found[k] for k in images]

    def source(self, get_image: Callable[[int, int], NDArray] | None,
               found: dict[tuple[int, int], dict[str, NDArray]]
               ) -> Callable[[int], list[tuple[NDArray, NDArray | None]]]:
        """Per-frame detections for the tracker (frames with none detected if possible)."""
        ragged, counts, C = self.ragged, self.counts, self.n_cameras
        blob_params = None

        def source(frame: int) -> list[tuple[NDArray, NDArray | None]]:
            nonlocal blob_params
            if counts[frame].sum() > 0 or get_image is None:
                return ragged(frame)
            from carapost.algorithms.blobs import BlobParameters, detect_blobs

            if blob_params is None:
                blob_params = from_mapping(BlobParameters, self.blob_section)
            out = []
            for c in range(C):
                d = detect_blobs(get_image(frame, c), blob_params)
                found[(frame, c)] = d._asdict()
                out.append((d.centre.astype(np.float64), d.axes.astype(np.float64)))
            return out

        def scores(frame: int) -> list[NDArray | None]:
            """Per camera the blobs' scores of one frame (as ``source`` serves it)."""
            if (frame, 0) in found:
                return [found[(frame, c)]["score"] for c in range(C)]
            return ragged.scores(frame)

        source.scores = scores  # type: ignore[attr-defined]
        return source


def _initial_state(project: Project, start: int, cols: NDArray | slice) -> InitialState:
    """Start-frame positions, observations and blob sizes (patch templates, size test)."""
    pts = project.points
    X0 = pts.positions[start, cols].astype(np.float64)
    obs0 = pts.obs[start, cols].astype(np.float64)
    det0 = pts.detection[start, cols]
    axes0 = np.full(det0.shape + (2,), np.nan)
    for c in range(project.n_cameras):
        ax = project.detections.get(start, c)["axes"].astype(np.float64)
        m = (det0[:, c] >= 0) & (det0[:, c] < len(ax))
        axes0[m, c] = ax[det0[m, c]]
    return InitialState(X0, pts.kind[cols].copy(), obs0, axes0)


@dataclass
class _TrackedPoints(Result):
    """What both trackers return: a point-array record over frames, and the detections
    they found on the fly (stored with it, since its observations refer to them)."""

    result: TrackResult
    point_ids: list[int]
    detected_images: list[tuple[int, int]] = field(default_factory=list, kw_only=True)
    detected_tables: list[dict[str, NDArray]] = field(default_factory=list, kw_only=True)

    @property
    def cancelled(self) -> bool:  # type: ignore[override]
        """True when the user cancelled (the frames tracked so far are kept)."""
        return bool(self.result.cancelled)

    def changes_nothing(self) -> bool:
        """No frame was tracked and no detection found (cancelled at once)."""
        return self.result.last < self.result.first and not self.detected_images

    def store_found(self, project: Project, journal: Journal) -> None:
        """Store (undoably) the detections found on the fly."""
        write_detections(journal, project, self.detected_images, self.detected_tables)

    def nbytes(self) -> int:
        """Bytes of the tracked arrays kept for redo."""
        return sum(int(np.asarray(getattr(self.result, n)).nbytes) for n in _ARRAYS)


@dataclass
class _TrackingJob(Job):
    """The snapshot both trackers start from (see :func:`prepare_tracking` and
    :func:`prepare_take_tracking`)."""

    detections: _Detections
    initial: InitialState
    R: NDArray
    t: NDArray
    intrinsics: CameraIntrinsics
    params: TrackingParameters
    start: int
    resolve_cameras: bool
    point_ids: list[int]


# ------------------------------------------------------------------------------------------
# Tracking
# ------------------------------------------------------------------------------------------
@dataclass
class TrackComputation(_TrackedPoints):
    """What a :class:`TrackJob` found: the result of Track Forwards/Backwards.

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

    description: str = "Track"

    def write(self, project: Project, journal: Journal) -> None:
        res = self.result
        self.store_found(project, journal)
        if res.last < res.first:
            return
        fr = slice(res.first, res.last + 1)
        cols = project.points.index_of(self.point_ids)
        journal.write_points(fr, cols, tracked_arrays(lambda name: getattr(res, name)))
        set_cameras(journal, project, fr, res.R, res.t)


@dataclass
class TrackJob(_TrackingJob):
    """Snapshot for :func:`carapost.algorithms.tracking.track` (see
    :func:`prepare_tracking`)."""

    stop: int
    what: str
    description: str
    get_image: Callable[[int, int], NDArray] | None = None

    def compute(self, progress: Progress = None) -> TrackComputation:
        result, images, tables = self.detections.run(self.get_image, lambda source: track(
            source, self.initial, self.R, self.t, self.intrinsics, self.params,
            start=self.start, stop=self.stop, get_image=self.get_image,
            resolve_cameras=self.resolve_cameras, progress=progress))
        if result.cancelled:
            log.info("%s cancelled after %d frames (kept)", self.what, result.frames_done)
        return TrackComputation(result, list(self.point_ids), detected_images=images,
                                detected_tables=tables, description=self.description)


def prepare_tracking(
    project: Project,
    direction: int = 1,
    *,
    single_frame: bool = False,
    point_ids: Iterable[int] | None = None,
    frame: int | None = None,
    get_image: Callable[[int, int], NDArray] | None = None,
) -> TrackJob:
    """Track points from the current frame: validate and snapshot.

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
    get_image : callable, optional
        ``get_image(frame, camera)`` -> grey image (called on the worker thread): patch
        tracking and blob detection of frames that have none.

    Returns
    -------
    TrackJob
        ``job.compute(progress)`` tracks (``progress(done, total)``; False cancels and
        keeps the frames tracked).

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
    intr = tracking_intrinsics(project, what)
    params = tracking_parameters(project, what)
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
    return TrackJob(_Detections(project), _initial_state(project, start, cols),
                    cal.R.copy(), cal.t.copy(), intr.copy(), params, start, has_brim,
                    [int(i) for i in pts.ids[cols]], stop=stop, what=what,
                    description=f"{what} [frames {min(start, stop)}-{max(start, stop)}]",
                    get_image=get_image)


class TrackResultCommand(ResultCommand):
    """Apply a :class:`TrackComputation` as one undoable step (``ResultCommand``)."""


class TrackCommand(TrackResultCommand):
    """Track Forwards/Backwards [Sequence] or [Single Frame] (Ctrl+W) in one call.

    Parameters are those of :func:`prepare_tracking`, plus ``progress``.
    """

    def __init__(self, project: Project, direction: int = 1, single_frame: bool = False,
                 point_ids: Iterable[int] | None = None,
                 progress: Callable[[int, int], bool] | None = None,
                 get_image: Callable[[int, int], NDArray] | None = None,
                 frame: int | None = None):
        super().__init__(prepare_tracking(project, direction, single_frame=single_frame,
                                          point_ids=point_ids, frame=frame,
                                          get_image=get_image).compute(progress))


@dataclass
class TakeTrackComputation(_TrackedPoints):
    """What a :class:`TakeTrackJob` found (the result of Track Take).

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

    start: int
    description: str = "Track Take"

    def write(self, project: Project, journal: Journal) -> None:
        res = self.result
        self.store_found(project, journal)
        if res.last < res.first:
            return
        pts = project.points
        old = pts.index_of(self.point_ids)
        new = (journal.append_points(res.n_new, kind=KIND_FACE) if res.n_new
               else np.zeros(0, np.intp))
        cols = np.concatenate([old, new]).astype(np.intp)
        frames = np.arange(res.first, res.last + 1)
        fr = slice(res.first, res.last + 1)
        keep_start = frames == self.start

        def value(name: str) -> NDArray:
            cur = pts.arrays[name][fr][:, cols]
            val = np.asarray(getattr(res, name)).astype(cur.dtype)
            # the initialised frame of the existing points stays as initialised; its
            # sigma is the tracker's (the initialisation measures none, and the
            # tracker's describes those very samples: it leaves the frame as it is),
            # else that frame would export the reprojection residual in px among mm
            held = cur[keep_start, : old.size]
            if name == "sigma":
                held = np.where(np.isfinite(val[keep_start, : old.size]),
                                val[keep_start, : old.size], held)
            val[keep_start, : old.size] = held
            return val

        journal.write_points(fr, cols, tracked_arrays(value, sigma=res.sigma is not None))
        cal = project.calibration
        Rn, tn = res.R.copy(), res.t.copy()
        Rn[keep_start], tn[keep_start] = cal.R[self.start], cal.t[self.start]
        set_cameras(journal, project, fr, Rn, tn)


@dataclass
class TakeTrackJob(_TrackingJob):
    """Snapshot for :func:`carapost.algorithms.tracking.track_take` (see
    :func:`prepare_take_tracking`)."""

    n_frames: int
    caddies: tuple[tuple[int, int], ...]  # Initialize 3D's camera pairs (model.rig)
    description: str
    spawn_parameters: Any = None  # Init3DParameters when finding markers
    brim_model: NDArray | None = None
    spawn_interval: int = 1
    get_image: Callable[[int, int], NDArray] | None = None

    def compute(self, progress: Progress = None) -> TakeTrackComputation:
        spawn = None
        if self.spawn_parameters is not None:
            spawn = make_spawner(self.intrinsics, self.caddies,
                                 self.spawn_parameters, brim_model=self.brim_model)
        result, images, tables = self.detections.run(self.get_image, lambda source: track_take(
            source, self.initial, self.R, self.t, self.intrinsics, self.params,
            start=self.start, n_frames=self.n_frames, spawn=spawn,
            spawn_interval=self.spawn_interval, resolve_cameras=self.resolve_cameras,
            progress=progress, get_image=self.get_image))
        return TakeTrackComputation(result, list(self.point_ids), self.start,
                                    self.description, detected_images=images,
                                    detected_tables=tables)


def prepare_take_tracking(
    project: Project,
    frame: int | None = None,
    *,
    find_markers: bool = True,
    spawn_interval: int = 1,
    get_image: Callable[[int, int], NDArray] | None = None,
) -> TakeTrackJob:
    """Track every point over the whole take from one frame, finding missed markers.

    ``compute(progress)`` runs :func:`carapost.algorithms.tracking.track_take`: forwards
    to the end (backwards when ``frame`` is the last frame) with Initialize 3D run on the
    unused detections (``find_markers``; the tracked points are its seeds, so nothing is
    created twice), then over the whole take the other way guided by the first pass, so
    each marker is tracked from its first appearance; points are then split where they
    hop to another marker and pieces of one marker joined. With ``get_image(frame,
    camera)``, point-cameras without a blob are patch tracked and frames without
    detections are detected on the fly (as in :class:`TrackCommand`).

    Raises
    ------
    CommandError
        No calibration, unsolved start frame, no point with 3D data there, bad parameters.
    """
    from carapost.algorithms.init3d import Init3DParameters

    what = "Track Take"
    intr = tracking_intrinsics(project, what)
    params = tracking_parameters(project, what)
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
    ip = bm = None
    if find_markers:
        try:
            ip = from_mapping(Init3DParameters, project.properties)
        except (TypeError, ValueError) as exc:
            raise refuse(f"{what}: {exc}") from None
        bm = X0[brim][np.isfinite(X0[brim]).all(-1)] if has_brim else None
    R = cal.R[start].copy() if has_brim else cal.R.copy()
    t = cal.t[start].copy() if has_brim else cal.t.copy()
    return TakeTrackJob(_Detections(project), _initial_state(project, start, slice(None)),
                        R, t, intr.copy(), params, start, has_brim, [int(i) for i in pts.ids],
                        n_frames=project.n_frames,
                        caddies=caddies(project.n_cameras, project.take.metadata),
                        description=f"{what} [from frame {start}]", spawn_parameters=ip,
                        brim_model=bm, spawn_interval=spawn_interval, get_image=get_image)


class TrackTakeCommand(ResultCommand):
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
        super().__init__(computation or prepare_take_tracking(
            project, frame, find_markers=find_markers, get_image=get_image).compute(progress))

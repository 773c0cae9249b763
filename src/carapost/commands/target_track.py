"""The Target Tracker's commands: target-track keyframes, tracking runs, clearing.

Edit > Add Target Track / Edit Target Track, the Tracker pane's Add Keyframe To Current
Frame, Edit > Gaps To Keys and Clear Tracked Points are plain commands; a tracking run
(Track forward / back, one frame or to the end) follows the processing recipe
(:mod:`carapost.commands.recipe`): :func:`prepare_target_track` snapshots the selected
points' keyframes and 2D data, :class:`TargetTrackJob` runs
:func:`carapost.algorithms.target_track.track_target` per point and camera on a worker,
every camera in lockstep (:class:`carapost.algorithms.target_lockstep.LockstepTracker`:
one frame step advances every track still going),
and its :class:`TargetTrackResult` writes the tracked 2D observations (source
``SOURCE_TARGET``, the score in ``quality``) and the re-solved 3D of every tracked frame
as one History entry. A paused (cancelled) run keeps what it tracked.

3D after each tracked frame: triangulated from two cameras or more (Gauss-Newton on the
reprojection error, :func:`carapost.algorithms.triangulation.triangulate`); from one
camera, with Allow Single Sensor Tracking, on its ray nearest the neighbours'
prediction (``RECON_SINGLE_SENSOR``). Cameras that lost the marker are first tracked
again from the others' 3D (:mod:`carapost.commands.target_reacquire`).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from carapost.algorithms.camera import CameraIntrinsics, pixel_rays
from carapost.algorithms.codes import (
    RECON_NONE,
    RECON_SINGLE_SENSOR,
    RECON_TRIANGULATED,
    SOURCE_KEYFRAME,
    SOURCE_NONE,
    SOURCE_TARGET,
)
from carapost.algorithms.params import from_mapping
from carapost.algorithms.target_lockstep import LockstepTracker, TrackRun
from carapost.algorithms.target_track import (
    STOP_CANCELLED,
    STOP_END,
    STOP_THRESHOLD,
    TargetTrackerParameters,
    check_keyframe,
)
from carapost.commands import target_depth
from carapost.commands.recipe import Job, Progress, Result
from carapost.commands.stack import Command, CommandError, Journal
from carapost.commands.target_reacquire import reacquire
from carapost.commands.target_sizes import track_parameters
from carapost.model.project import Project

log = logging.getLogger("carapost.commands")

__all__ = [
    "AddKeyframe",
    "AddTargetTrack",
    "ClearTrackedPoints",
    "EditTargetTrack",
    "GapsToKeys",
    "TargetTrackJob",
    "TargetTrackResult",
    "key_frames",
    "prepare_target_track",
    "resolve_3d",
    "tracker_parameters",
]

#: The per-point arrays a tracking run or a keyframe edit writes.
_NAMES = ("positions", "recon", "residual", "obs", "source", "detection", "quality",
          "keyframe", "sigma")

ImageFn = Callable[[int, int], NDArray[np.uint8]]


def tracker_parameters(project: Project, **overrides: Any) -> TargetTrackerParameters:
    """The Target Tracker settings of the project's properties (plus overrides)."""
    try:
        return from_mapping(TargetTrackerParameters, project.properties, **overrides)
    except (TypeError, ValueError) as exc:
        raise CommandError(f"Target Tracker: {exc}") from None


def _column(project: Project, point: int, what: str) -> int:
    try:
        return int(project.points.index_of([int(point)])[0])
    except KeyError:
        raise CommandError(f"{what}: there is no point {point}") from None


def _check_image_point(project: Project, camera: int, frame: int, xy: Any, what: str,
                       pattern_size: int) -> tuple[int, int, NDArray[np.float64]]:
    c, f = int(camera), int(frame)
    if not 0 <= c < project.n_cameras:
        raise CommandError(f"{what}: there is no camera {c} (cameras 0-"
                           f"{project.n_cameras - 1})")
    if not 0 <= f < project.n_frames:
        raise CommandError(f"{what}: frame {f} is outside the take (0-"
                           f"{project.n_frames - 1})")
    p = np.asarray(xy, dtype=np.float64).reshape(-1)
    if p.shape != (2,) or not np.isfinite(p).all():
        raise CommandError(f"{what}: the position must be two finite pixel coordinates")
    w, h = project.take.cameras[c].image_size
    try:
        check_keyframe(p, (h, w), pattern_size)
    except ValueError as exc:
        raise CommandError(f"{what}: {exc} of camera {c}") from None
    return c, f, p


def _intrinsics(project: Project) -> CameraIntrinsics | None:
    return project.calibration.intrinsics


def resolve_3d(obs: NDArray, R: NDArray, t: NDArray, intr: CameraIntrinsics | None,
               reference: NDArray, single_sensor: bool
               ) -> tuple[NDArray[np.float32], NDArray[np.int8], NDArray[np.float32]]:
    """3D of one point over some frames from its observations.

    Parameters
    ----------
    obs : ndarray, shape (n, C, 2)
        Raw pixel observations, NaN where none.
    R, t : ndarray, shape (n, C, 3, 3), (n, C, 3)
        Cameras of those frames.
    intr : CameraIntrinsics or None
        None (no calibration): no 3D.
    reference : ndarray, shape (n, 3)
        A nearby 3D position per frame (mm) for single-camera frames (NaN: none).
    single_sensor : bool
        Allow Single Sensor Tracking.

    Returns
    -------
    positions (n, 3) float32, recon (n,) int8, residual (n,) float32
    """
    n = len(obs)
    pos = np.full((n, 3), np.nan, np.float32)
    recon = np.full(n, RECON_NONE, np.int8)
    res = np.full(n, np.nan, np.float32)
    if intr is None or n == 0:
        return pos, recon, res
    have = np.isfinite(obs).all(-1)                  # (n, C)
    count = have.sum(1)
    multi = count >= 2
    if multi.any():
        from carapost.algorithms.triangulation import TriangulationParameters, triangulate

        tri = triangulate(obs[multi][:, None], R[multi], t[multi], intr,
                          TriangulationParameters(minimum_cameras=2))
        ok = np.isfinite(tri.points[:, 0]).all(-1)
        idx = np.flatnonzero(multi)[ok]
        pos[idx] = tri.points[ok, 0]
        recon[idx] = RECON_TRIANGULATED
        res[idx] = tri.residual[ok, 0]
    single = (count == 1) & np.isfinite(reference).all(-1)
    if single_sensor and single.any():
        for i in np.flatnonzero(single):
            c = int(np.flatnonzero(have[i])[0])
            o, d = pixel_rays(obs[i], R[i], t[i], intr)    # (C, 3): NaN but camera c
            o, d = o[c], d[c]
            depth = float((reference[i] - o) @ d)
            if depth > 0:
                pos[i] = o + depth * d
                recon[i] = RECON_SINGLE_SENSOR
                res[i] = 0.0
    return pos, recon, res


def _nearest_reference(positions: NDArray, frames: NDArray) -> NDArray[np.float64]:
    """Per frame of ``frames``: the 3D position of the nearest frame that has one."""
    have = np.flatnonzero(np.isfinite(positions[:, 0]))
    out = np.full((len(frames), 3), np.nan)
    if not len(have):
        return out
    pos = np.searchsorted(have, frames)
    lo = have[np.clip(pos - 1, 0, len(have) - 1)]
    hi = have[np.clip(pos, 0, len(have) - 1)]
    near = np.where(np.abs(frames - lo) <= np.abs(hi - frames), lo, hi)
    return positions[near].astype(np.float64)


def _resolve_frames(project: Project, col: int, frames: NDArray, single: bool,
                    obs: NDArray | None = None) -> dict[str, NDArray]:
    """New 3D of point column ``col`` at ``frames`` (its current or the given obs)."""
    pts, cal = project.points, project.calibration
    o = pts.obs[frames, col].astype(np.float64) if obs is None else obs
    ref = _nearest_reference(np.where(np.isin(np.arange(project.n_frames), frames)[:, None],
                                      np.nan, pts.positions[:, col]), frames)
    ref = np.where(np.isfinite(ref), ref, pts.positions[frames, col])
    p, r, e = resolve_3d(o, cal.R[frames], cal.t[frames], _intrinsics(project), ref, single)
    unsolved = ~cal.solved[frames]
    p[unsolved], r[unsolved], e[unsolved] = np.nan, RECON_NONE, np.nan
    # the old uncertainty belonged to the old 3D: unknown until estimated again
    return {"positions": p, "recon": r, "residual": e,
            "sigma": np.full(len(frames), np.nan, np.float32)}


def _write_cells(project: Project, journal: Journal, col: int, frames: NDArray,
                 cams: NDArray, values: dict[str, Any], resolve: bool,
                 single: bool) -> None:
    """Set observation cells (frames[i], col, cams[i]) and re-solve those frames' 3D."""
    if not len(frames):
        return
    pts = project.points
    a, b = int(frames.min()), int(frames.max())
    block = {k: pts.arrays[k][a:b + 1, [col]].copy() for k in _NAMES}
    rel = frames - a
    for k, v in values.items():
        block[k][rel, 0, cams] = v
    if resolve:
        fr = np.unique(frames)
        new = _resolve_frames(project, col, fr, single,
                              obs=block["obs"][fr - a, 0].astype(np.float64))
        for k, v in new.items():
            block[k][fr - a, 0] = v
    journal.write_points(slice(a, b + 1), [col], block)


def key_frames(project: Project, col: int, cam: int) -> dict[int, NDArray[np.float64]]:
    """The target-track keyframes of one point in one camera: frame -> (x, y)."""
    pts = project.points
    fr = np.flatnonzero(pts.keyframe[:, col, cam] & np.isfinite(pts.obs[:, col, cam, 0]))
    return {int(f): pts.obs[f, col, cam].astype(np.float64) for f in fr}


def _selected_ids(project: Project, points: Iterable[int] | None, what: str) -> list[int]:
    ids = sorted(project.selection.points) if points is None else [int(p) for p in points]
    if not ids:
        raise CommandError(f"{what}: no point is selected")
    for p in ids:
        _column(project, p, what)
    return ids


# ---- keyframe commands ----------------------------------------------------------------
class AddTargetTrack(Command):
    """Edit > Add Target Track: a new point with a target-track keyframe at a click."""

    def __init__(self, project: Project, camera: int, frame: int, xy: Any) -> None:
        super().__init__()
        params = tracker_parameters(project)
        self.camera, self.frame, self.xy = _check_image_point(
            project, camera, frame, xy, "Add Target Track", params.pattern_size)
        self.description = f"Add Target Track [camera {self.camera}, frame {self.frame}]"

    def apply(self, project: Project, journal: Journal) -> None:
        col = int(journal.append_points(1)[0])
        _write_cells(project, journal, col, np.array([self.frame]), np.array([self.camera]),
                     {"obs": self.xy.astype(np.float32), "source": SOURCE_KEYFRAME,
                      "detection": -1, "quality": 1.0, "keyframe": True},
                     resolve=False, single=False)
        journal.setattr(project, "selection", type(project.selection)(
            points=frozenset({int(project.points.ids[col])}),
            cameras=project.selection.cameras), "selection")


class EditTargetTrack(Command):
    """Edit > Edit Target Track: a keyframe of a point at a click (replacing that
    camera's connected detection, if any)."""

    def __init__(self, project: Project, point: int, camera: int, frame: int,
                 xy: Any) -> None:
        super().__init__()
        what = "Edit Target Track"
        params = tracker_parameters(project)
        self.point = int(point)
        _column(project, self.point, what)
        pattern = params.pattern_size
        if 0 <= int(camera) < project.n_cameras:   # the track's own box, if it has one
            pattern = track_parameters(project, self.point, int(camera), params).pattern_size
        self.camera, self.frame, self.xy = _check_image_point(
            project, camera, frame, xy, what, pattern)
        self.single = params.allow_single_sensor_tracking
        self.description = (f"Edit Target Track [point {self.point}, camera {self.camera}, "
                            f"frame {self.frame}]")

    def apply(self, project: Project, journal: Journal) -> None:
        col = _column(project, self.point, "Edit Target Track")
        _write_cells(project, journal, col, np.array([self.frame]), np.array([self.camera]),
                     {"obs": self.xy.astype(np.float32), "source": SOURCE_KEYFRAME,
                      "detection": -1, "quality": 1.0, "keyframe": True},
                     resolve=True, single=self.single)


class AddKeyframe(Command):
    """Tracker pane > Add Keyframe To Current Frame: every selected point becomes a
    keyframe in every camera where it has a 2D position on the frame."""

    def __init__(self, project: Project, points: Iterable[int] | None = None,
                 frame: int | None = None) -> None:
        super().__init__()
        what = "Add Keyframe To Current Frame"
        self.ids = _selected_ids(project, points, what)
        self.frame = int(project.current_frame if frame is None else frame)
        if not 0 <= self.frame < project.n_frames:
            raise CommandError(f"{what}: frame {self.frame} is outside the take")
        cols = project.points.index_of(self.ids)
        have = np.isfinite(project.points.obs[self.frame, cols, :, 0])
        if not have.any():
            raise CommandError(f"{what}: the selected points have no 2D position on "
                               f"frame {self.frame}")
        self.description = f"Add Keyframe [frame {self.frame}]"

    def apply(self, project: Project, journal: Journal) -> None:
        pts = project.points
        for pid in self.ids:
            col = _column(project, pid, "Add Keyframe")
            cams = np.flatnonzero(np.isfinite(pts.obs[self.frame, col, :, 0]))
            if len(cams):
                _write_cells(project, journal, col, np.full(len(cams), self.frame), cams,
                             {"source": SOURCE_KEYFRAME, "detection": -1, "quality": 1.0,
                              "keyframe": True}, resolve=False, single=False)


class GapsToKeys(Command):
    """Edit > Gaps To Keys: keyframes either side of every gap of the selected points
    (in every camera with a 2D position there)."""

    def __init__(self, project: Project, points: Iterable[int] | None = None) -> None:
        super().__init__()
        from carapost.model.queries import gaps

        what = "Gaps To Keys"
        self.ids = _selected_ids(project, points, what)
        self.cells: list[tuple[int, int]] = []   # (point id, frame)
        for pid in self.ids:
            col = _column(project, pid, what)
            for a, b in gaps(project, col):
                self.cells += [(pid, int(a) - 1), (pid, int(b) + 1)]
        if not self.cells:
            raise CommandError(f"{what}: the selected points have no gap")
        n = len(self.cells) // 2
        self.description = f"Gaps To Keys [{n} gap{'s' if n != 1 else ''}]"

    def apply(self, project: Project, journal: Journal) -> None:
        pts = project.points
        for pid in self.ids:
            col = _column(project, pid, "Gaps To Keys")
            frames = np.array(sorted({f for p, f in self.cells if p == pid}), dtype=np.intp)
            have = np.isfinite(pts.obs[frames, col, :, 0])
            fi, ci = np.nonzero(have)
            _write_cells(project, journal, col, frames[fi], ci,
                         {"source": SOURCE_KEYFRAME, "detection": -1, "quality": 1.0,
                          "keyframe": True}, resolve=False, single=False)


class ClearTrackedPoints(Command):
    """Tracker pane > Clear Tracked Points: remove the target-track 2D data (keyframes
    and tracked observations) of the selected points over the whole take; their 3D is
    re-solved from what remains."""

    def __init__(self, project: Project, points: Iterable[int] | None = None) -> None:
        super().__init__()
        what = "Clear Tracked Points"
        self.ids = _selected_ids(project, points, what)
        cols = project.points.index_of(self.ids)
        src = project.points.source[:, cols]
        if not np.isin(src, (SOURCE_KEYFRAME, SOURCE_TARGET)).any():
            raise CommandError(f"{what}: the selected points have no target-tracked data")
        self.single = tracker_parameters(project).allow_single_sensor_tracking
        self.description = "Clear Tracked Points"

    def apply(self, project: Project, journal: Journal) -> None:
        pts = project.points
        for pid in self.ids:
            col = _column(project, pid, "Clear Tracked Points")
            fi, ci = np.nonzero(np.isin(pts.source[:, col], (SOURCE_KEYFRAME, SOURCE_TARGET)))
            _write_cells(project, journal, col, fi, ci,
                         {"obs": np.nan, "source": SOURCE_NONE, "detection": -1,
                          "quality": 0.0, "keyframe": False}, resolve=True,
                         single=self.single)


# ---- tracking runs --------------------------------------------------------------------
@dataclass
class _Track:
    """One (point, camera) to track, as snapshotted."""

    point: int
    camera: int
    keys: dict[int, NDArray[np.float64]]
    start_xy: NDArray[np.float64]
    velocity: NDArray[np.float64] | None
    stop: int
    #: the run's settings with this track's own pattern and search sizes (None: the run's)
    params: TargetTrackerParameters | None = None
    #: why ``stop`` is short of the run's end: a keyframe ahead (Stop On Next Keyframe)
    #: or 2D data ahead (Overwrite Existing Tracks off); "" when it is the run's end
    limit: str = ""


@dataclass
class TargetTrackResult(Result):
    """Tracked observations of some points and their re-solved 3D (one History entry)."""

    first: int
    ids: list[int]
    arrays: dict[str, NDArray]          # each (n, P) / (n, P, C[, 2]) over first..
    description: str
    message: str = ""
    cancelled: bool = False
    frames_tracked: int = 0
    reasons: dict[tuple[int, int], str] = field(default_factory=dict)
    last_frame: int | None = None

    def write(self, project: Project, journal: Journal) -> None:
        n = len(self.arrays["positions"])
        cols = project.points.index_of(self.ids)
        journal.write_points(slice(self.first, self.first + n), cols, self.arrays)

    def changes_nothing(self) -> bool:
        return self.frames_tracked == 0


@dataclass
class TargetTrackJob(Job):
    """A tracking run of the selected points (see :func:`prepare_target_track`)."""

    tracks: list[_Track]
    get_image: ImageFn
    direction: int
    start: int
    params: TargetTrackerParameters
    ids: list[int]
    first: int
    block: dict[str, NDArray]              # the points' arrays over first..last
    R: NDArray
    t: NDArray
    solved: NDArray
    intr: CameraIntrinsics | None
    auto_keys: list[tuple[int, int]]       # (point index, camera) keyed at start
    description: str
    #: per point: its nearest points' triangulated 3D over first.. (n, k, 3) mm, NaN
    #: where not triangulated; their motion carries a one-camera frame's depth
    neighbour_xyz: list[NDArray] | None = None
    #: track the cameras that lost the marker again (`target_reacquire`)
    reacquire: bool = True
    #: What the run has tracked so far, appended on the worker as it goes: (point id,
    #: camera, frame, score) per tracked frame (the window draws the span growing, and
    #: shows the frame being tracked). Read it from another thread by slicing.
    live: list[tuple[int, int, int, float]] = field(default_factory=list, repr=False)
    #: ``request(frame, cameras, direction)``: the images of ``frame`` for these cameras
    #: are wanted next (the window's frame service starts decoding them all, and reads
    #: ahead in the direction of travel); called from the worker before each frame.
    request: Callable[[int, list[int], int], None] | None = field(default=None,
                                                                   repr=False)
    #: The latest tracked position of each (point id, camera): (frame, x, y), replaced
    #: as the run goes (the views draw it while they follow the run). Read a copy.
    live_xy: dict[tuple[int, int], tuple[int, float, float]] = field(default_factory=dict,
                                                                     repr=False)

    @property
    def stop(self) -> int:
        """The farthest frame any track may reach (the views follow up to it)."""
        stops = [tr.stop for tr in self.tracks] or [self.start]
        return max(stops) if self.direction > 0 else min(stops)

    def compute(self, progress: Progress = None) -> TargetTrackResult:
        d, P = self.direction, self.params
        block = {k: v.copy() for k, v in self.block.items()}
        cancelled = False
        reasons: dict[tuple[int, int], str] = {}
        tracked = 0
        touched = np.zeros(len(block["positions"]), dtype=bool)
        index = {pid: i for i, pid in enumerate(self.ids)}
        for i, c in self.auto_keys:
            r = self.start - self.first
            block["keyframe"][r, i, c] = True
            block["source"][r, i, c] = SOURCE_KEYFRAME
            block["detection"][r, i, c] = -1
            block["quality"][r, i, c] = 1.0
        last = self.start

        def seen_by(tr: _Track) -> Callable[[int, NDArray, float], None]:
            def seen(f: int, xy: NDArray, score: float) -> None:
                if f not in tr.keys:
                    self.live.append((tr.point, tr.camera, int(f), float(score)))
                    if np.isfinite(xy).all():
                        self.live_xy[(tr.point, tr.camera)] = (int(f), float(xy[0]),
                                                               float(xy[1]))
            return seen

        # every (point, camera) one frame per step: the views, the timeline and the
        # progress bar go once through the range, and a frame's images are wanted at once
        lock = LockstepTracker([
            TrackRun(lambda f, c=tr.camera: self.get_image(f, c), tr.keys, self.start,
                     tr.stop, d, tr.params if tr.params is not None else P, tr.start_xy,
                     tr.velocity, seen_by(tr)) for tr in self.tracks])

        def step(done: int, total: int) -> bool:
            return progress is None or progress(done, total) is not False

        def wanted(frame: int, runs: list[int]) -> None:
            if self.request is not None:
                self.request(frame, sorted({self.tracks[i].camera for i in runs}), d)

        results = lock.run(step, wanted)
        for tr, res in zip(self.tracks, results, strict=True):
            if res is None:
                continue
            reasons[(tr.point, tr.camera)] = self.stop_reason(tr, res)
            cancelled = cancelled or res.reason == STOP_CANCELLED
            i = index[tr.point]
            # the start frame carries the 2D point the run began from (a keyframe, a
            # detection or an earlier track): the run did not track it, so it is not
            # rewritten, and a run lost on its first step changes nothing
            ok = res.tracked & (res.frames != res.frames[0])
            fr = res.frames[ok] - self.first
            if len(fr):
                self.write_tracked(block, touched, fr, i, tr.camera, res.xy[ok],
                                   res.score[ok])
                tracked += len(fr)
        added = 0
        if (P.allow_single_sensor_tracking and self.reacquire and not cancelled
                and self.intr is not None):
            added, paused = reacquire(self, block, touched, results, reasons, progress,
                                      lock.total)
            tracked, cancelled = tracked + added, paused
        # 3D of every frame a camera was tracked in
        rows = np.flatnonzero(touched)
        for i in range(len(self.ids)):
            if not len(rows):
                break
            (block["positions"][rows, i], block["recon"][rows, i],
             block["residual"][rows, i]) = self.solve(block, touched, i)
            block["sigma"][rows, i] = np.nan     # the old 3D's uncertainty, not this one's
        if len(rows):   # the farthest frame tracked (cameras tracked again included)
            last = int(rows[-1] if d > 0 else rows[0]) + self.first
        message = _run_message(self.tracks, results, tracked, last, P.break_threshold)
        if added:
            message += (f"; {added} observation{'s' if added != 1 else ''} tracked again "
                        "in cameras that had lost the marker, from the others' 3D")
        log.info("%s", message)
        return TargetTrackResult(self.first, list(self.ids), block, self.description,
                                 message, cancelled, tracked + len(self.auto_keys), reasons,
                                 last)

    @staticmethod
    def stop_reason(tr: _Track, res: Any) -> str:
        """Why the run ``res`` of ``tr`` stopped: reaching a stop set by a keyframe or
        data ahead is that (``tr.limit``), not the take's end."""
        return tr.limit if res.reason == STOP_END and tr.limit else res.reason

    @staticmethod
    def write_tracked(block: dict[str, NDArray], touched: NDArray, fr: NDArray, i: int,
                      c: int, xy: NDArray, score: NDArray) -> None:
        """Write tracked frames ``fr`` (block rows) of point ``i`` in camera ``c`` into
        ``block``: the positions ``xy`` (len(fr), 2) raw px as target-tracked
        observations scored ``score``, no detection, no keyframe; ``touched`` marks
        the frames to re-solve."""
        block["obs"][fr, i, c] = xy.astype(np.float32)
        block["source"][fr, i, c] = SOURCE_TARGET
        block["detection"][fr, i, c] = -1
        block["quality"][fr, i, c] = score.astype(np.float16)
        block["keyframe"][fr, i, c] = False
        touched[fr] = True

    def solve(self, block: dict[str, NDArray], touched: NDArray, i: int
              ) -> tuple[NDArray[np.float32], NDArray[np.int8], NDArray[np.float32]]:
        """3D of point ``i`` over the re-solved frames ``np.flatnonzero(touched)`` from
        the block's observations (:func:`resolve_3d`, depth from
        :func:`~carapost.commands.target_depth.depth_reference`): positions (m, 3) mm,
        recon (m,), residual (m,)."""
        P = self.params
        rows = np.flatnonzero(touched)
        obs = block["obs"][rows, i].astype(np.float64)
        positions = self.block["positions"][:, i].astype(np.float64)   # before the run
        ref = _nearest_reference(np.where(touched[:, None], np.nan, positions), rows)
        if P.allow_single_sensor_tracking and self.neighbour_xyz is not None:
            ref = target_depth.depth_reference(self, i, rows, obs, positions, touched, ref)
        p, r, e = resolve_3d(obs, self.R[rows], self.t[rows], self.intr, ref,
                             P.allow_single_sensor_tracking)
        bad = ~self.solved[rows]
        p[bad], r[bad], e[bad] = np.nan, RECON_NONE, np.nan
        return p, r, e


def _match_text(score: float) -> str:
    """How a lost track's last frame matched, for the run's message."""
    if not score > 0.0:
        # the first step's assignment found no disc, or two that fit alike
        # (`target_identity.first_step` gives no score then): nothing was measured
        return "no unambiguous match"
    # the match truncated, never rounded up to the threshold it fell below
    return f"match {np.floor(score * 1000) / 1000:.3f}"


def _run_message(tracks: list[_Track], results: list[Any], tracked: int, last: int,
                 threshold: float) -> str:
    """What a run did, for the status bar and the log: how far it got and, for every
    track that lost its marker, where and with what match (the artist keys there)."""
    why = sorted({tr.limit if r.reason == STOP_END and tr.limit else r.reason
                  for tr, r in zip(tracks, results, strict=True) if r is not None})
    text = (f"Target Tracker: {tracked} observation{'s' if tracked != 1 else ''} tracked "
            f"in {len(tracks)} point-camera{'s' if len(tracks) != 1 else ''}, up to frame "
            f"{last}")
    lost = [(tr, r) for tr, r in zip(tracks, results, strict=True)
            if r is not None and r.reason == STOP_THRESHOLD]
    if lost:
        where = ", ".join(f"point {tr.point} camera {tr.camera} at frame "
                          f"{int(r.frames[-1])} ({_match_text(float(r.score[-1]))})"
                          for tr, r in lost[:4])
        more = f" and {len(lost) - 4} more" if len(lost) > 4 else ""
        text += f"; lost the marker: {where}{more}, below the Break Threshold {threshold:g}"
    return f"{text} (stopped: {', '.join(why) or '-'})"


def prepare_target_track(project: Project, get_image: ImageFn, direction: int, *,
                         single_frame: bool = False, to: int | None = None,
                         points: Iterable[int] | None = None,
                         frame: int | None = None, **overrides: Any) -> TargetTrackJob:
    """A tracking run of the selected points from the current frame.

    Parameters
    ----------
    project : Project
    get_image : callable
        ``get_image(frame, camera)``, safe for the worker thread.
    direction : int
        +1 forwards, -1 backwards.
    single_frame : bool
        Track forward / back one frame.
    to : int, optional
        Last frame to reach (default: the end / start of the take).
    points : iterable of int, optional
        Point ids (default: the selected points).
    frame : int, optional
        Start frame (default: the current frame).
    **overrides
        Target Tracker parameter fields (e.g. ``pattern_size``).

    Raises
    ------
    CommandError
        No point selected, no 2D position on the start frame, no keyframe to track from,
        bad settings or a keyframe whose pattern box leaves the image.
    """
    what = "Target Track"
    if direction not in (1, -1):
        raise CommandError(f"{what}: direction must be +1 or -1")
    params = tracker_parameters(project, **overrides)
    ids = _selected_ids(project, points, what)
    F = project.n_frames
    s = int(project.current_frame if frame is None else frame)
    if not 0 <= s < F:
        raise CommandError(f"{what}: frame {s} is outside the take (0-{F - 1})")
    end = (F - 1 if direction > 0 else 0) if to is None else int(to)
    if not 0 <= end < F:
        raise CommandError(f"{what}: frame {end} is outside the take (0-{F - 1})")
    if (end - s) * direction < 0:
        end = s
    if single_frame:
        end = s + direction if 0 <= s + direction < F else s
    if params.stop_after_n_frames:
        lim = s + direction * params.n_frames
        end = min(end, lim) if direction > 0 else max(end, lim)
    if end == s:
        raise CommandError(f"{what}: frame {s} is the "
                           f"{'last' if direction > 0 else 'first'} frame to track")
    pts = project.points
    cols = pts.index_of(ids)
    tracks: list[_Track] = []
    auto: list[tuple[int, int]] = []
    if not np.isfinite(pts.obs[s, cols, :, 0]).any():
        raise CommandError(f"{what}: the selected points have no 2D position on frame {s}")
    keyed_any = pts.keyframe[:, cols].any(axis=(1, 2))          # (F,)
    for i, (pid, col) in enumerate(zip(ids, cols, strict=True)):
        for c in np.flatnonzero(np.isfinite(pts.obs[s, col, :, 0])):
            keys = key_frames(project, int(col), int(c))
            xy = pts.obs[s, col, c].astype(np.float64)
            if not keys:
                # no keyframe in this camera yet: tracking needs one to start from (with
                # Automatically Add Keyframes it is kept; otherwise it only seeds the run)
                keys[s] = xy
                if params.auto_add_keyframes:
                    auto.append((i, int(c)))
            w, h = project.take.cameras[c].image_size
            tp = track_parameters(project, int(pid), int(c), params,
                                  keep=frozenset(overrides))
            if tp.pattern_size + 4 > min(w, h):
                raise CommandError(f"{what}: the Pattern Size ({tp.pattern_size} px) "
                                   f"is larger than the {w} x {h} image of camera {c}")
            for kf, kxy in keys.items():
                try:
                    check_keyframe(kxy, (h, w), tp.pattern_size)
                except ValueError as exc:
                    raise CommandError(f"{what}: point {pid}, camera {c}, keyframe "
                                       f"{kf}: {exc}") from None
            stop, limit = end, ""
            if params.stop_on_next_keyframe:   # any selected point's keyframe, any camera
                ahead = np.flatnonzero(keyed_any)
                ahead = ahead[ahead > s] if direction > 0 else ahead[ahead < s][::-1]
                if len(ahead):
                    k = int(ahead[0])
                    cut = min(stop, k - 1) if direction > 0 else max(stop, k + 1)
                    stop, limit = cut, (f"keyframe {k}" if cut != end else limit)
            if not params.overwrite_existing_tracks:   # keep existing 2D data
                rng = (np.arange(s + 1, stop + 1) if direction > 0
                       else np.arange(s - 1, stop - 1, -1))
                busy = rng[np.isfinite(pts.obs[rng, col, c, 0])] if len(rng) else rng
                if len(busy):
                    stop, limit = int(busy[0]) - direction, f"2D data at {int(busy[0])}"
            prev = s - direction
            vel = None
            if 0 <= prev < F and np.isfinite(pts.obs[prev, col, c]).all():
                vel = xy - pts.obs[prev, col, c].astype(np.float64)
            if (stop - s) * direction > 0:
                tracks.append(_Track(int(pid), int(c), keys, xy, vel, int(stop),
                                     None if tp is params else tp, limit))
    if not tracks:
        raise CommandError(f"{what}: nothing to track from frame {s} (the next frame is "
                           "a keyframe or already has 2D data; see Overwrite Existing "
                           "Tracks and Stop On Next Keyframe)")
    lo = min([s] + [tr.stop for tr in tracks])
    hi = max([s] + [tr.stop for tr in tracks])
    block = {k: pts.arrays[k][lo:hi + 1][:, cols].copy() for k in _NAMES}
    cal = project.calibration
    intr = cal.intrinsics.copy() if cal.intrinsics is not None else None
    name = {(1, True): "Track Forward One Frame", (-1, True): "Track Back One Frame",
            (1, False): "Track Forward", (-1, False): "Track Back"}[(direction, single_frame)]
    return TargetTrackJob(tracks, get_image, direction, s, params, ids, lo, block,
                          cal.R[lo:hi + 1].copy(), cal.t[lo:hi + 1].copy(),
                          cal.solved[lo:hi + 1].copy(), intr, auto,
                          f"{name} [frame {s}, {len(ids)} point{'s' if len(ids) > 1 else ''}]",
                          neighbour_xyz=(target_depth.neighbour_xyz(project, cols, lo, hi)
                                         if params.allow_single_sensor_tracking else None))

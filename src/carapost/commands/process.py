"""Process-menu commands: blob detection, calibration brim, Initialize 3D, bundle.

Each command computes its result when it is created (the slow part, which a UI runs on a
worker thread) and applies it as one undoable step. Bad input raises
:class:`~carapost.commands.stack.CommandError` with a message that is also logged on the
``carapost.process`` logger; the project is then unchanged.

Brim points are ``KIND_BRIM`` points whose ``positions`` hold the brim model in every
frame (the brim is rigid in its own frame, which is the world frame); a brim solve
attaches them to detections and marks them ``RECON_TRIANGULATED`` at the solved frame.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Hashable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from carapost.algorithms.camera import CameraIntrinsics
from carapost.algorithms.params import from_mapping
from carapost.commands.edit import ReplaceDetections
from carapost.commands.stack import Command, CommandError, Journal
from carapost.model.project import (
    KIND_BRIM,
    KIND_FACE,
    RECON_NONE,
    RECON_TRIANGULATED,
    SOURCE_BLOB,
    Project,
)

log = logging.getLogger("carapost.process")

_OBS = ("obs", "source", "detection", "quality", "keyframe")
_POS = ("positions", "recon", "residual")

__all__ = [
    "BundleCurrentFrame",
    "DetectBlobs",
    "ImportBrimSvg",
    "Initialize3D",
    "InitializeDefaultBrim",
    "SetBrimModel",
    "SolveBrimAuto",
    "SolveBrimManual",
]


def refuse(message: str) -> CommandError:
    """A :class:`CommandError` for ``message``, logged as an error on ``carapost.process``.

    Processing commands ``raise refuse(...)`` so the reason reaches the Log pane even when
    the caller (a batch script) only catches the exception.
    """
    log.error("%s", message)
    return CommandError(message)


def check_frame(project: Project, frame: int | None, what: str) -> int:
    """The frame index ``frame`` (the current frame when None), refused with a logged
    message when it is outside the take."""
    f = project.current_frame if frame is None else int(frame)
    if not 0 <= f < project.n_frames:
        raise refuse(f"{what}: frame {f} is outside the take (0-{project.n_frames - 1})")
    return f


def require_intrinsics(project: Project, what: str,
                       remedy: str = "import an XCP file for the intrinsics",
                       ) -> CameraIntrinsics:
    """The project's camera intrinsics; refuses ``what`` when there are none for this take.

    ``remedy`` completes the message "the project has no camera calibration (...)".
    """
    intr = project.calibration.intrinsics
    if intr is None:
        raise refuse(f"{what}: the project has no camera calibration ({remedy})")
    if intr.n_cameras != project.n_cameras:
        raise refuse(f"{what}: the calibration has {intr.n_cameras} cameras, the take "
                      f"{project.n_cameras}")
    return intr


def _frame_detections(project: Project, frame: int) -> list[NDArray[np.float64]]:
    return [project.detections.centres(frame, c).astype(np.float64)
            for c in range(project.n_cameras)]


def _brim(project: Project, frame: int, what: str) -> tuple[NDArray[np.intp], NDArray]:
    """Columns of the brim points and the brim model (B, 3)."""
    cols = np.flatnonzero(project.points.kind == KIND_BRIM)
    if cols.size == 0:
        raise refuse(f"{what}: the project has no calibration brim (Initialize Default "
                      "Calibration Brim or Import Calibration Brim [SVG] first)")
    model = project.points.positions[frame, cols].astype(np.float64)
    if not np.all(np.isfinite(model)):
        raise refuse(f"{what}: the brim model has points without a position")
    return cols, model


def set_cameras(journal: Journal, project: Project, frames: int | slice, R: NDArray,
                t: NDArray) -> None:
    """Set (undoably) the solved cameras of one frame or of a block of frames.

    ``R`` and ``t`` are ``(C, 3, 3)`` and ``(C, 3)`` for one frame, ``(n, C, 3, 3)`` and
    ``(n, C, 3)`` for a slice of ``n`` frames; those frames become solved.
    """
    cal = project.calibration
    old = (cal.R[frames].copy(), cal.t[frames].copy(), np.copy(cal.solved[frames]))

    def undo() -> None:
        cal.R[frames], cal.t[frames], cal.solved[frames] = old

    journal.call(undo, "cameras", nbytes=old[0].nbytes + old[1].nbytes)
    cal.R[frames] = R
    cal.t[frames] = t
    cal.solved[frames] = True


def _ray_residual(X: NDArray, obs: NDArray, R: NDArray, t: NDArray, intr) -> NDArray:
    """RMS distance (mm) of points X [P, 3] to the rays of their observations [P, C, 2]."""
    from carapost.algorithms.camera import pixel_rays

    P, C = obs.shape[:2]
    o, d = pixel_rays(obs, R[None], t[None], intr)  # (P, C, 3)
    v = X[:, None, :] - o
    perp = v - (v * d).sum(-1, keepdims=True) * d
    d2 = (perp**2).sum(-1)
    ok = np.isfinite(d2)
    n = ok.sum(1)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.sqrt(np.where(ok, d2, 0.0).sum(1) / n)
    out[n < 1] = np.nan
    return out


def _write_frame(project: Project, frame: int, cols: NDArray, X: NDArray, det: NDArray,
                 residual: NDArray, dets: list[NDArray]) -> None:
    """Write 3D positions and blob observations of points at one frame (journal first)."""
    pts = project.points
    C = project.n_cameras
    f = frame
    pts.positions[f, cols] = X
    pts.recon[f, cols] = np.where(np.isfinite(X).all(1), RECON_TRIANGULATED, RECON_NONE)
    pts.residual[f, cols] = residual
    obs = np.full((len(cols), C, 2), np.nan, dtype=np.float32)
    for c in range(C):
        m = det[:, c] >= 0
        obs[m, c] = dets[c][det[m, c]]
    pts.obs[f, cols] = obs
    pts.source[f, cols] = np.where(det >= 0, SOURCE_BLOB, 0)
    pts.detection[f, cols] = det
    pts.quality[f, cols] = np.where(det >= 0, 1.0, 0.0)
    pts.keyframe[f, cols] = False


# ------------------------------------------------------------------------------------------
# Detect Blobs
# ------------------------------------------------------------------------------------------
class DetectBlobs(ReplaceDetections):
    """Detect Blobs [Active Range] / [Current Frame] with the project's Blob Parameters.

    Parameters
    ----------
    project : Project
    frames : (int, int)
        Inclusive frame range.
    cameras : sequence of int, optional
        Cameras to process; default: the explicitly selected cameras, or all.
    get_image : callable (frame, camera) -> ndarray [H, W]
        Supplies the grey image of one camera at one frame.
    progress : callable (done, total) -> bool, optional
        Returning False cancels; the images finished so far are kept.
    workers : int
        Detector threads.
    """

    def __init__(self, project: Project, frames: tuple[int, int] | None = None,
                 cameras: Sequence[int] | None = None,
                 get_image: Callable[[int, int], NDArray] | None = None,
                 progress: Callable[[int, int], bool] | None = None, workers: int = 2):
        from carapost.algorithms.blobs import BlobParameters, detect_blobs_batch

        what = "Detect Blobs"
        if get_image is None:
            raise refuse(f"{what}: no image source (the take has no camera videos)")
        a, b = frames if frames is not None else (project.current_frame,) * 2
        a, b = check_frame(project, a, what), check_frame(project, b, what)
        if a > b:
            a, b = b, a
        cams = (project.processing_cameras() if cameras is None
                else np.array(sorted(set(int(c) for c in cameras)), dtype=np.intp))
        if cams.size == 0 or cams.min() < 0 or cams.max() >= project.n_cameras:
            raise refuse(f"{what}: no such camera in {list(cams)}")
        try:
            params = from_mapping(BlobParameters, project.properties)
        except ValueError as exc:
            raise refuse(f"{what}: {exc}") from None
        keys: list[Hashable] = [(f, int(c)) for f in range(a, b + 1) for c in cams]
        result = detect_blobs_batch(lambda k: get_image(*k), keys, params, workers=workers,
                                    progress=progress)
        if not result:
            raise refuse(f"{what}: cancelled before any image was finished")
        images = [k for k in keys if k in result]
        tables = [result[k]._asdict() for k in images]
        self.cancelled = len(images) < len(keys)
        desc = f"{what} [frames {a}-{b}]" if b > a else f"{what} [frame {a}]"
        super().__init__(images, tables, description=desc)
        log.info("%s: %d images, %d detections%s", desc, len(images),
                 sum(len(t["centre"]) for t in tables),
                 " (cancelled: finished images kept)" if self.cancelled else "")


# ------------------------------------------------------------------------------------------
# Brim models
# ------------------------------------------------------------------------------------------
class SetBrimModel(Command):
    """Replace the brim points by a brim model: labels and positions (B, 3) in mm."""

    def __init__(self, labels: Sequence[str], xyz: NDArray,
                 description: str = "Set Calibration Brim"):
        super().__init__()
        self.labels = list(labels)
        self.xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
        if len(self.labels) != len(self.xyz) or len(self.xyz) < 4:
            raise refuse(f"{description}: a brim needs at least 4 dots with one label each "
                          f"(got {len(self.xyz)} dots, {len(self.labels)} labels)")
        if not np.all(np.isfinite(self.xyz)):
            raise refuse(f"{description}: a brim dot position is not finite")
        self.description = description

    def apply(self, project: Project, journal: Journal) -> None:
        old = np.flatnonzero(project.points.kind == KIND_BRIM)
        if old.size:
            journal.remove_points(old)
        cols = journal.append_points(len(self.xyz), labels=self.labels, kind=KIND_BRIM)
        project.points.positions[:, cols] = self.xyz.astype(np.float32)[None]


class InitializeDefaultBrim(SetBrimModel):
    """Initialize Default Calibration Brim [v1.0 / v1.1 / v2.0] (replaces any brim)."""

    def __init__(self, project: Project, version: str = "v2.0"):
        from carapost.io.brim_svg import default_brim

        try:
            labels, xyz = default_brim(version)
        except ValueError as exc:
            raise refuse(f"Initialize Default Calibration Brim: {exc}") from None
        super().__init__(labels, xyz,
                         f"Initialize Default Calibration Brim [{version.strip().lower()}]")
        log.info("%s: %d brim dots", self.description, len(xyz))


class ImportBrimSvg(SetBrimModel):
    """Import Calibration Brim [SVG]: a planar custom brim (replaces any brim)."""

    def __init__(self, project: Project, path: str | Path):
        from carapost.io.brim_svg import read_brim_svg
        from carapost.io.errors import CaraFileError

        try:
            labels, xyz = read_brim_svg(path)
        except CaraFileError as exc:
            raise refuse(f"Import Calibration Brim [SVG]: {exc}") from None
        super().__init__(labels, xyz, f"Import Calibration Brim [SVG] {Path(path).name}")
        self.path = str(path)
        log.info("%s: %d brim dots", self.description, len(xyz))


# ------------------------------------------------------------------------------------------
# Brim solves
# ------------------------------------------------------------------------------------------
class _ApplyBrimSolve(Command):
    """Write a brim solve: cameras of the frame, brim points attached to detections."""

    def __init__(self, project: Project, frame: int, result: Any, cols: NDArray,
                 model: NDArray, description: str):
        super().__init__()
        self.frame = frame
        self.R, self.t = result.R.copy(), result.t.copy()
        self.matches = result.matches.copy()
        self.ids = project.points.ids[cols].copy()
        intr = project.calibration.intrinsics
        dets = _frame_detections(project, frame)
        obs = np.full(self.matches.shape + (2,), np.nan)
        for c in range(project.n_cameras):
            m = self.matches[:, c] >= 0
            obs[m, c] = dets[c][self.matches[m, c]]
        self.model = model
        self.residual = _ray_residual(model, obs, self.R, self.t, intr)
        self.description = description

    def apply(self, project: Project, journal: Journal) -> None:
        f = self.frame
        cols = project.points.index_of(self.ids)
        journal.point_block(slice(f, f + 1), cols, _POS + _OBS)
        set_cameras(journal, project, f, self.R, self.t)
        det = self.matches
        _write_frame(project, f, cols, self.model, det, self.residual,
                     _frame_detections(project, f))
        seen = (det >= 0).any(1)
        project.points.recon[f, cols[~seen]] = RECON_NONE
        project.points.residual[f, cols[~seen]] = np.nan


class SolveBrimManual(_ApplyBrimSolve):
    """Solve Calibration Brim [Manual].

    Parameters
    ----------
    project : Project
    frame : int
    correspondences : mapping camera -> sequence of (brim_index, detection_index), optional
        ``brim_index`` counts the brim points in project order. Default: the detections
        attached to brim points at ``frame`` (at least 4 in every camera).
    """

    def __init__(self, project: Project, frame: int | None = None,
                 correspondences: Mapping[int, Sequence[tuple[int, int]]] | None = None):
        from carapost.algorithms.brim import solve_brim_manual

        what = "Solve Calibration Brim [Manual]"
        f = check_frame(project, frame, what)
        intr = require_intrinsics(project, what)
        cols, model = _brim(project, f, what)
        if correspondences is None:
            det = project.points.detection[f, cols]  # (B, C)
            correspondences = {c: [(int(b), int(det[b, c])) for b in np.flatnonzero(
                det[:, c] >= 0)] for c in range(project.n_cameras)}
        dets = _frame_detections(project, f)
        res = solve_brim_manual(dets, correspondences, model, intr)
        if not res.success:
            raise refuse(res.message)
        super().__init__(project, f, res, cols, model, f"{what} [frame {f}]")
        self.message = res.message


class SolveBrimAuto(_ApplyBrimSolve):
    """Solve the brim with no hand matches, using the rig geometry of the XCP calibration.

    The cameras of ``frame`` (or of the first solved frame) give the rig's relative
    geometry; only their relation to each other is used.
    """

    def __init__(self, project: Project, frame: int | None = None):
        from carapost.algorithms.brim import solve_brim_auto

        what = "Solve Calibration Brim [Automatic]"
        f = check_frame(project, frame, what)
        intr = require_intrinsics(project, what)
        cols, model = _brim(project, f, what)
        cal = project.calibration
        if not cal.solved.any():
            raise refuse(f"{what}: needs the rig geometry of an XCP calibration (import one) "
                          "or a solved frame")
        ref = f if cal.solved[f] else int(np.flatnonzero(cal.solved)[0])
        res = solve_brim_auto(_frame_detections(project, f), model, intr, cal.R[ref],
                              cal.t[ref])
        if not res.success:
            raise refuse(res.message)
        super().__init__(project, f, res, cols, model, f"{what} [frame {f}]")
        self.message = res.message


# ------------------------------------------------------------------------------------------
# Initialize 3D and bundle
# ------------------------------------------------------------------------------------------
def _caddies(n_cameras: int) -> tuple[tuple[int, int], ...]:
    """Caddy pairs: (0, 1), (2, 3), ... (first half left, as the rig's channels)."""
    return tuple((i, i + 1) for i in range(0, n_cameras - 1, 2))


class Initialize3D(Command):
    """Initialize 3D: face points from the detections of one frame.

    Seeds are the face points of the frame attached to detections in two or more cameras
    (matched by hand) unless ``seeds`` gives per-camera detection index tuples; with none
    at all, seeds are found automatically. Seed points keep their ids and are updated;
    new points are appended. Uses the Initialize 3D Parameters of the project.
    """

    def __init__(self, project: Project, frame: int | None = None,
                 seeds: Sequence[Sequence[int]] | None = None):
        from carapost.algorithms.brim import brim_exclusion_mask
        from carapost.algorithms.init3d import Init3DParameters, initialize_3d

        what = "Initialize 3D"
        f = check_frame(project, frame, what)
        intr = require_intrinsics(project, what)
        cal = project.calibration
        if not cal.solved[f]:
            raise refuse(f"{what}: the cameras of frame {f} are not solved (Solve "
                          "Calibration Brim first)")
        pts = project.points
        C = project.n_cameras
        dets = _frame_detections(project, f)
        if not any(len(d) for d in dets):
            raise refuse(f"{what}: frame {f} has no detections (run Detect Blobs)")
        R, t = cal.R[f].copy(), cal.t[f].copy()
        # detections already taken by points stay out; brim ones and the brim region too
        exclude = [np.zeros(len(d), dtype=bool) for d in dets]
        attached = pts.detection[f]  # (P, C)
        for c in range(C):
            k = attached[:, c]
            exclude[c][k[(k >= 0) & (k < len(dets[c]))]] = True
        brim_cols = np.flatnonzero(pts.kind == KIND_BRIM)
        brim_model = brim_det = None
        if brim_cols.size:
            brim_model = pts.positions[f, brim_cols].astype(np.float64)
            if np.all(np.isfinite(brim_model)):
                region = brim_exclusion_mask(dets, brim_model, R, t, intr)
                brim_det = pts.detection[f, brim_cols].astype(np.intp)
                for c in range(C):
                    exclude[c] |= region[c]
            else:
                brim_model = None
        seed_cols = np.zeros(0, dtype=np.intp)
        if seeds is None:
            face = np.flatnonzero(pts.kind == KIND_FACE)
            nviews = (attached[face] >= 0).sum(1)
            seed_cols = face[nviews >= 2]
            seed_rows = [list(attached[c]) for c in seed_cols]
            for c in range(C):  # seed detections are theirs to use
                exclude[c][attached[seed_cols, c][attached[seed_cols, c] >= 0]] = False
        else:
            seed_rows = [list(s) for s in seeds]
        try:
            params = from_mapping(Init3DParameters, project.properties)
        except (TypeError, ValueError) as exc:
            raise refuse(f"{what}: {exc}") from None
        try:
            res = initialize_3d(dets, R, t, intr, caddies=_caddies(C),
                                seeds=seed_rows or None, exclude_mask=exclude, params=params,
                                brim_model=brim_model, brim_detections=brim_det)
        except ValueError as exc:
            raise refuse(f"{what}: {exc}") from None
        if not res.success:
            raise refuse(res.message)
        super().__init__()
        self.frame = f
        self.seed_ids = pts.ids[seed_cols].copy()
        self.result = res
        self.cameras_changed = not (np.array_equal(res.R, R) and np.array_equal(res.t, t))
        self.description = f"{what} [frame {f}]"
        self.message = res.message
        # residual in mm with the final cameras
        obs = np.full(res.detections.shape + (2,), np.nan)
        for c in range(C):
            m = res.detections[:, c] >= 0
            obs[m, c] = dets[c][res.detections[m, c]]
        self.residual = _ray_residual(res.points, obs, res.R, res.t, intr)

    def apply(self, project: Project, journal: Journal) -> None:
        f = self.frame
        res = self.result
        n_old = len(self.seed_ids)
        old_cols = project.points.index_of(self.seed_ids) if n_old else np.zeros(0, np.intp)
        if n_old:
            journal.point_block(slice(f, f + 1), old_cols, _POS + _OBS)
        new_cols = journal.append_points(len(res.points) - n_old, kind=KIND_FACE)
        cols = np.concatenate([old_cols, new_cols]).astype(np.intp)
        if self.cameras_changed:
            set_cameras(journal, project, f, res.R, res.t)
        _write_frame(project, f, cols, res.points, res.detections, self.residual,
                     _frame_detections(project, f))


class BundleCurrentFrame(Command):
    """Bundle Current Frame [Unconstrained]: refine the frame's cameras and face points.

    Brim points with a model position are kept fixed (they define the frame); every point
    with two or more observations takes part.
    """

    def __init__(self, project: Project, frame: int | None = None):
        from carapost.algorithms.bundle import bundle_frame

        what = "Bundle Current Frame [Unconstrained]"
        f = check_frame(project, frame, what)
        intr = require_intrinsics(project, what)
        cal = project.calibration
        if not cal.solved[f]:
            raise refuse(f"{what}: the cameras of frame {f} are not solved")
        pts = project.points
        obs = pts.obs[f].astype(np.float64)  # (P, C, 2)
        nview = np.isfinite(obs).all(-1).sum(1)
        brim = pts.kind == KIND_BRIM
        X = pts.positions[f].astype(np.float64)
        use = (nview >= 2) & (brim | np.isfinite(X).all(1))
        use |= brim & (nview >= 1) & np.isfinite(X).all(1)
        face = use & ~brim
        if not face.any() and not (use & brim).any():
            raise refuse(f"{what}: no point of frame {f} has observations in two cameras")
        cols = np.flatnonzero(use)
        X0 = X[cols]
        # face points without a 3D position get one from their rays first
        need = ~np.isfinite(X0).all(1)
        if need.any():
            from carapost.algorithms.triangulation import (
                TriangulationParameters,
                triangulate,
            )

            tri = triangulate(obs[cols][need][None], cal.R[f], cal.t[f], intr,
                              TriangulationParameters(minimum_cameras=2))
            X0[need] = tri.points[0]
        res = bundle_frame(obs[cols], X0, cal.R[f], cal.t[f], intr,
                           fixed_points_mask=brim[cols])
        if not (res.success or np.isfinite(res.rms_after)):
            raise refuse(f"{what}: the adjustment failed ({res.message})")
        super().__init__()
        self.frame = f
        self.ids = pts.ids[cols[~brim[cols]]].copy()
        self.points = res.points[~brim[cols]]
        self.R, self.t = res.R, res.t
        self.residual = _ray_residual(self.points, obs[cols][~brim[cols]], res.R, res.t, intr)
        self.description = f"{what} [frame {f}]"
        self.message = (f"{what}: frame {f}, {len(cols)} points, RMS {res.rms_before:.3f} -> "
                        f"{res.rms_after:.3f} px")
        log.info("%s", self.message)

    def apply(self, project: Project, journal: Journal) -> None:
        f = self.frame
        pts = project.points
        set_cameras(journal, project, f, self.R, self.t)
        if len(self.ids):
            cols = pts.index_of(self.ids)
            journal.point_block(slice(f, f + 1), cols, _POS)
            pts.positions[f, cols] = self.points
            pts.recon[f, cols] = RECON_TRIANGULATED
            pts.residual[f, cols] = self.residual


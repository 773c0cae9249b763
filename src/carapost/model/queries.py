"""Derived, vectorised queries on a project (nothing here changes the model)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from carapost.algorithms.camera import camera_centres
from carapost.algorithms.camera import project as project_points
from carapost.model.project import (
    RECON_SINGLE_SENSOR,
    RECON_TRIANGULATED,
    SOURCE_NONE,
    Project,
)
from carapost.model.rig import caddy_groups


def _frames(project: Project, frames: tuple[int, int] | None) -> slice:
    if frames is None:
        return slice(0, project.n_frames)
    return slice(int(frames[0]), int(frames[1]) + 1)


def contribution_mask(
    project: Project, frames: tuple[int, int] | None = None
) -> NDArray[np.bool_]:
    """Cameras that contributed to each measured 3D sample.

    A camera contributes when the point has an observation in it and the sample was
    reconstructed from observations (triangulated or single-sensor); interpolated,
    filtered and missing samples have no contributing camera.

    Returns
    -------
    ndarray, shape (F, P, C) bool
    """
    sl = _frames(project, frames)
    pts = project.points
    measured = np.isin(pts.recon[sl], (RECON_TRIANGULATED, RECON_SINGLE_SENSOR))
    has_obs = (pts.source[sl] != SOURCE_NONE) & ~np.isnan(pts.obs[sl][..., 0])
    return has_obs & measured[..., None]


def contribution_count(
    project: Project, frames: tuple[int, int] | None = None
) -> NDArray[np.int8]:
    """Number of contributing cameras per point-frame, shape (F, P) int8."""
    return contribution_mask(project, frames).sum(axis=-1, dtype=np.int8)


def reprojection_error(
    project: Project, frames: tuple[int, int] | None = None, *, chunk: int = 4096
) -> NDArray[np.float32]:
    """Mean reprojection error (px) of each 3D sample over its observations.

    Returns
    -------
    ndarray, shape (F, P) float32
        NaN where the sample has no 3D position, no observation or no calibration.
    """
    sl = _frames(project, frames)
    pts = project.points
    cal = project.calibration
    n = sl.stop - sl.start
    out = np.full((n, pts.count), np.nan, dtype=np.float32)
    if cal.intrinsics is None or pts.count == 0:
        return out
    for s in range(0, n, chunk):
        f0, f1 = sl.start + s, min(sl.start + s + chunk, sl.stop)
        uv, _ = project_points(
            pts.positions[f0:f1].astype(np.float64), cal.R[f0:f1], cal.t[f0:f1], cal.intrinsics
        )
        d = np.linalg.norm(uv - pts.obs[f0:f1], axis=-1)
        with np.errstate(invalid="ignore"):
            valid = ~np.isnan(d)
            cnt = valid.sum(axis=-1)
            total = np.where(valid, d, 0.0).sum(axis=-1)
            out[s : s + (f1 - f0)] = np.where(cnt > 0, total / np.maximum(cnt, 1), np.nan)
    return out


def present(project: Project, frames: tuple[int, int] | None = None) -> NDArray[np.bool_]:
    """Whether each point has a 3D position, shape (F, P) bool."""
    sl = _frames(project, frames)
    return ~np.isnan(project.points.positions[sl, :, 0])


def _runs(missing: NDArray[np.bool_]) -> NDArray[np.int64]:
    """Runs of True in a 1D bool array as [N, 2] inclusive (start, end)."""
    m = np.concatenate([[False], missing, [False]])
    d = np.diff(m.astype(np.int8))
    starts = np.flatnonzero(d == 1)
    ends = np.flatnonzero(d == -1) - 1
    return np.stack([starts, ends], axis=-1).astype(np.int64)


def gaps(
    project: Project, column: int, frames: tuple[int, int] | None = None
) -> NDArray[np.int64]:
    """Gaps of one point: runs of frames without a 3D position, as [N, 2] (start, end).

    Only runs bounded by data on both sides inside ``frames`` count as gaps; leading
    and trailing runs (before the point appears, after it is lost) are not gaps.
    """
    sl = _frames(project, frames)
    missing = np.isnan(project.points.positions[sl, column, 0])
    runs = _runs(missing)
    if len(runs):
        inner = (runs[:, 0] > 0) & (runs[:, 1] < len(missing) - 1)
        runs = runs[inner]
    return runs + sl.start


def gap_counts(project: Project, frames: tuple[int, int] | None = None) -> NDArray[np.int64]:
    """Number of gaps per point (interior missing runs), shape (P,)."""
    sl = _frames(project, frames)
    missing = np.isnan(project.points.positions[sl, :, 0])
    if missing.shape[0] == 0:
        return np.zeros(project.n_points, dtype=np.int64)
    has = ~missing
    # any data at or after each frame
    seen_after = np.flip(np.logical_or.accumulate(np.flip(has, axis=0), axis=0), axis=0)
    # a run starting at frame i >= 1 is a gap if frame i-1 has data and data returns later
    interior = missing[1:] & has[:-1] & seen_after[1:]
    return interior.sum(axis=0).astype(np.int64)


def point_with_fewest_gaps(
    project: Project,
    columns: NDArray[np.intp] | None = None,
    frames: tuple[int, int] | None = None,
) -> int | None:
    """Column of the point with the fewest gaps that still has at least one.

    Among ``columns`` (default: all); ties go to the point with fewer missing frames.
    None when no point has a gap.
    """
    counts = gap_counts(project, frames)
    cols = np.arange(project.n_points) if columns is None else np.asarray(columns, np.intp)
    if len(cols) == 0:
        return None
    c = counts[cols]
    with_gaps = c > 0
    if not np.any(with_gaps):
        return None
    sl = _frames(project, frames)
    missing = np.isnan(project.points.positions[sl][:, cols, 0]).sum(axis=0)
    key = np.where(with_gaps, c, np.iinfo(np.int64).max)
    order = np.lexsort((missing, key))
    return int(cols[order[0]])


def next_gap(project: Project, column: int, after_frame: int) -> tuple[int, int] | None:
    """The first gap of a point that starts after ``after_frame`` (or None)."""
    g = gaps(project, column)
    later = g[g[:, 0] > after_frame]
    return (int(later[0, 0]), int(later[0, 1])) if len(later) else None


@dataclass(frozen=True)
class PointInformation:
    """What View > Get Point Information reports about one point at one frame.

    Attributes
    ----------
    label : str
        The point's label (or its generated name).
    point_id : int
    frame : int
    position : ndarray, shape (3,) float64
        3D position in mm, NaN when the point has none at this frame.
    observations : ndarray, shape (C, 2) float64
        2D position in each sensor in px, NaN where unobserved.
    blob_size : ndarray, shape (C, 2) float64
        Full axis lengths (px) of the detection the point uses in each sensor, NaN where
        it uses none.
    centroid_distances : tuple of (str, float)
        Distance (mm) from the 3D position to the centroid of the camera centres of
        each caddy (``"caddy 1"``, ...; `carapost.model.rig.caddy_groups`, the same
        caddies as Initialize 3D) and of ``"all cameras"``; empty when the point
        has no 3D position or the frame is not calibrated.
    """

    label: str
    point_id: int
    frame: int
    position: NDArray[np.float64]
    observations: NDArray[np.float64]
    blob_size: NDArray[np.float64]
    centroid_distances: tuple[tuple[str, float], ...]

    def text(self) -> str:
        """The report as lines of text (the dialog and the log show this)."""
        X = self.position
        lines = [f"{self.label} (id {self.point_id}) at frame {self.frame}",
                 "3D: " + ("none" if np.isnan(X[0]) else
                           f"({X[0]:.2f}, {X[1]:.2f}, {X[2]:.2f}) mm")]
        for c, (o, size) in enumerate(zip(self.observations, self.blob_size, strict=True)):
            blob = "" if np.isnan(size[0]) else f", blob {size[0]:.1f} x {size[1]:.1f} px"
            lines.append(f"Sensor {c}: " + ("-" if np.isnan(o[0]) else
                                            f"({o[0]:.1f}, {o[1]:.1f}) px{blob}"))
        lines += [f"Distance to centroid of {name}: {d:.1f} mm"
                  for name, d in self.centroid_distances]
        return "\n".join(lines)


def point_information(project: Project, column: int, frame: int) -> PointInformation:
    """3D position, 2D position and blob size per sensor, distances to the caddies.

    Parameters
    ----------
    project : Project
    column : int
        Point column.
    frame : int

    Returns
    -------
    PointInformation
    """
    pts = project.points
    C = project.n_cameras
    X = pts.positions[frame, column].astype(np.float64)
    obs = pts.obs[frame, column].astype(np.float64).reshape(C, 2)
    size = np.full((C, 2), np.nan)
    for c in range(C):
        det = int(pts.detection[frame, column, c])
        if det >= 0:
            axes = project.detections.get(frame, c)["axes"]
            if det < len(axes):
                size[c] = 2.0 * axes[det, :2].astype(np.float64)  # semi-axes -> full
    cal = project.calibration
    distances: list[tuple[str, float]] = []
    if not np.isnan(X[0]) and C and cal.solved.any():
        centres = camera_centres(cal.R[frame], cal.t[frame])
        groups = [(f"caddy {k + 1}", list(cams))
                  for k, cams in enumerate(caddy_groups(C, project.take.metadata))]
        groups.append(("all cameras", list(range(C))))
        distances = [(name, float(np.linalg.norm(centres[cams].mean(axis=0) - X)))
                     for name, cams in groups]
    return PointInformation(project.point_label(column), int(pts.ids[column]), int(frame),
                            X, obs, size, tuple(distances))


def distance_between(project: Project, column_a: int, column_b: int, frame: int) -> float:
    """Distance (mm) between two points' 3D positions at ``frame``; NaN if one has none."""
    a = project.points.positions[frame, column_a].astype(np.float64)
    b = project.points.positions[frame, column_b].astype(np.float64)
    return float(np.linalg.norm(a - b))

"""Derived, vectorised queries on a project (nothing here changes the model)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from carapost.algorithms.camera import project as project_points
from carapost.model.project import (
    RECON_SINGLE_SENSOR,
    RECON_TRIANGULATED,
    SOURCE_NONE,
    Project,
)


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

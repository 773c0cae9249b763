"""Re-solve points' 3D from the 2D observations they keep (after Detach Detections).

The clean-up recipes for jitter rely on it: detach a bad camera's detections and the
point is recalculated from the other cameras, in the same undo step. Point-frames whose
3D was measured (triangulated or single sensor) are solved again from the cameras that
still observe them:

- two or more cameras: triangulated (the Triangulation Parameters, as everywhere);
- one camera, with Allow Single Sensor Tracking: the point of that camera's ray closest
  to the old position, kept when it is within the Single Sensor Tracking Threshold (the
  tracker's single-sensor rule); otherwise, or with no camera left, the sample has no 3D.

Interpolated and filtered samples are left alone: they never came from the cameras.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from carapost.algorithms.camera import pixel_rays
from carapost.algorithms.params import from_mapping
from carapost.algorithms.tracking import TrackingParameters
from carapost.algorithms.triangulation import TriangulationParameters, triangulate
from carapost.commands.stack import Journal
from carapost.model.project import (
    RECON_NONE,
    RECON_SINGLE_SENSOR,
    RECON_TRIANGULATED,
    SOURCE_NONE,
    Project,
)

__all__ = ["resolve_points"]


def resolve_points(journal: Journal, project: Project, frames: slice,
                   columns: NDArray[np.intp]) -> int:
    """Solve the measured 3D of some points again from their remaining observations.

    Parameters
    ----------
    journal : Journal
        The command's journal (the old block is saved for undo).
    project : Project
    frames : slice
        Frames of the block.
    columns : ndarray of int
        Point columns.

    Returns
    -------
    int
        Point-frames re-solved (0 when the cameras are not calibrated).
    """
    cal = project.calibration
    intr = cal.intrinsics
    cols = np.asarray(columns, dtype=np.intp)
    if intr is None or cols.size == 0:
        return 0
    pts = project.points
    recon = pts.recon[frames][:, cols]
    measured = (recon == RECON_TRIANGULATED) | (recon == RECON_SINGLE_SENSOR)
    if not measured.any():
        return 0
    obs = pts.obs[frames][:, cols].astype(np.float64)
    has = ~np.isnan(obs[..., 0]) & (pts.source[frames][:, cols] != SOURCE_NONE)
    obs[~has] = np.nan
    R, t = cal.R[frames], cal.t[frames]
    try:
        tri_params = from_mapping(TriangulationParameters, project.properties)
        track_params = from_mapping(TrackingParameters, project.properties)
    except (TypeError, ValueError):
        tri_params, track_params = TriangulationParameters(), TrackingParameters()
    tri = triangulate(obs, R, t, intr, tri_params)
    old = pts.positions[frames][:, cols].astype(np.float64)
    positions = old.copy()
    new_recon = recon.copy()
    residual = pts.residual[frames][:, cols].astype(np.float64)
    n_obs = has.sum(-1)
    two = measured & (n_obs >= 2) & np.isfinite(tri.points).all(-1)
    positions[two] = tri.points[two]
    new_recon[two] = RECON_TRIANGULATED
    residual[two] = tri.residual[two]
    one = measured & (n_obs == 1) & np.isfinite(old).all(-1)
    kept = np.zeros_like(one)
    if one.any() and track_params.allow_single_sensor_tracking:
        f, p = np.nonzero(one)
        cam = np.argmax(has[f, p], axis=1)
        origin, d = pixel_rays(obs[f, p, cam][None], R[f, cam][None], t[f, cam][None],
                               intr.subset(cam))
        origin, d = origin[0], d[0]
        s = np.einsum("ni,ni->n", old[f, p] - origin, d)
        Xs = origin + s[:, None] * d
        dist = np.linalg.norm(Xs - old[f, p], axis=-1)
        ok = (dist <= track_params.single_sensor_tracking_threshold) & (s > 0)
        positions[f[ok], p[ok]] = Xs[ok]
        new_recon[f[ok], p[ok]] = RECON_SINGLE_SENSOR
        residual[f[ok], p[ok]] = dist[ok]
        kept[f[ok], p[ok]] = True
    lost = measured & ~two & ~kept
    positions[lost] = np.nan
    new_recon[lost] = RECON_NONE
    residual[lost] = np.nan
    changed = measured
    sigma = pts.arrays["sigma"][frames][:, cols].copy() if "sigma" in pts.arrays else None
    arrays = {"positions": positions, "recon": new_recon, "residual": residual}
    if sigma is not None:
        sigma[changed] = np.nan  # the geometry changed: the old uncertainty is stale
        arrays["sigma"] = sigma
    journal.write_points(frames, cols, arrays)
    return int(changed.sum())

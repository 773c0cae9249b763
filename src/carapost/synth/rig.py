"""The head rig: cameras on two caddies and the calibration brim, in the helmet frame.

Helmet frame (mm): origin at the centre of the head at rest, **x to the actor's left,
y up, z forward**. Cameras hang below and in front of the face on a left caddy (cameras
0, 1, ...) and a right caddy; the brim is a light band tilted like a visor above the
forehead, with dark dots on it, rigidly fixed to the helmet.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from carapost.algorithms.camera import VICON_RADIAL2, CameraIntrinsics

# Brim: a cone-shaped band rho = R0 + (y - Y0) tan(tilt) about the helmet's y axis, so its
# face looks forward and down towards the cameras.
BRIM_R0 = 122.0
BRIM_Y0 = 74.0
BRIM_TILT_DEG = 40.0
BRIM_WIDTH = 26.0  # along the band's slant (mm)
BRIM_HALF_ANGLE_DEG = 47.0
BRIM_DOT_RADIUS = 2.5


def brim_point(alpha_deg: NDArray[np.float64], v: NDArray[np.float64]) -> NDArray[np.float64]:
    """Point on the brim band at azimuth ``alpha`` (deg, + = actor's left), slant ``v`` (mm)."""
    tau = np.radians(BRIM_TILT_DEG)
    a = np.radians(alpha_deg)
    rho = BRIM_R0 + v * np.sin(tau)
    return np.stack([rho * np.sin(a), BRIM_Y0 + v * np.cos(tau), rho * np.cos(a)], axis=-1)


def brim_normal(p: NDArray[np.float64]) -> NDArray[np.float64]:
    """Unit normal (towards the cameras: outward and down) of the brim at points ``p``."""
    p = np.asarray(p, dtype=np.float64)
    rho = np.hypot(p[..., 0], p[..., 2])
    n = np.stack([p[..., 0] / rho, np.full(rho.shape, -np.tan(np.radians(BRIM_TILT_DEG))),
                  p[..., 2] / rho], axis=-1)
    return n / np.linalg.norm(n, axis=-1, keepdims=True)


def brim_model(rng: np.random.Generator | None = None
               ) -> tuple[NDArray[np.float64], list[str]]:
    """The brim dots: positions (B, 3) in mm (helmet frame) and labels ``Brim01``...

    Two staggered rows; a few gaps make the pattern asymmetric so it can be identified.
    With ``rng`` (a rig variant), the spacing, the rows' heights, the span and the gaps
    are drawn at random: another brim layout on the same band.
    """
    if rng is None:
        step, half, v_rows, gaps = 7.0, 42.0, (7.0, 19.0), [-24.5, 10.5]
    else:
        step = float(rng.uniform(6.0, 8.5))
        half = float(rng.uniform(34.0, BRIM_HALF_ANGLE_DEG - 3.0))
        v_rows = (float(rng.uniform(5.0, 9.0)), float(rng.uniform(16.0, 21.0)))
        n_upper = int(2 * ((half - step / 2) // step) + 1)
        upper_all = (np.arange(n_upper) - (n_upper - 1) / 2) * step
        gaps = list(rng.choice(upper_all, size=int(rng.integers(1, 4)), replace=False))
    lower = np.arange(-half, half + 0.1, step)
    lower -= lower.mean()
    upper = np.arange(-(half - step / 2), half - step / 2 + 0.1, step)
    upper -= upper.mean()
    upper = upper[~np.isin(upper.round(6), np.round(gaps, 6))]
    alpha = np.concatenate([lower, upper])
    v = np.concatenate([np.full(lower.size, v_rows[0]), np.full(upper.size, v_rows[1])])
    pts = brim_point(alpha, v)
    return pts, [f"Brim{i + 1:02d}" for i in range(len(pts))]


def look_at(centre: NDArray[np.float64], target: NDArray[np.float64], roll_deg: float = 0.0
            ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """World->camera ``R, t`` of a camera at ``centre`` looking at ``target``, image y ~ down."""
    z = target - centre
    z = z / np.linalg.norm(z)
    down = np.array([0.0, -1.0, 0.0])
    x = np.cross(down, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    if roll_deg:
        c, s = np.cos(np.radians(roll_deg)), np.sin(np.radians(roll_deg))
        R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ R
    return R, -R @ centre


def rig_cameras(n_cameras: int, size: tuple[int, int],
                rng: np.random.Generator | None = None, *, baseline_mm: float = 45.0,
                separation_mm: float = 128.0
                ) -> tuple[CameraIntrinsics, NDArray[np.float64], NDArray[np.float64]]:
    """Nominal (unflexed) rig: intrinsics and extrinsics of ``n_cameras`` cameras.

    Cameras ``0 .. ceil(C/2)-1`` sit on the left caddy (actor's left, +x), the rest on the
    right one; within a caddy they are stacked ``baseline_mm`` apart, the caddies
    ``separation_mm`` apart (top cameras), all looking at the face. The focal length is
    set from the image's short side, so a portrait size (e.g. 720x1280) gives
    portrait-mounted cameras with the same field of view across.
    With ``rng`` (a rig variant), every camera's position and aim move by a few mm, its
    roll by a few degrees and its focal length by up to 10 %: another rig of the same kind.

    Returns
    -------
    intrinsics : CameraIntrinsics
    R : ndarray, shape (C, 3, 3)
    t : ndarray, shape (C, 3)
    """
    w, h = size
    n_left = (n_cameras + 1) // 2
    Rs, ts = [], []
    focal, pp, dc, radial = [], [], [], []
    diag = 0.5 * np.hypot(w, h)
    for i in range(n_cameras):
        left = i < n_left
        j = i if left else i - n_left
        sx = 1.0 if left else -1.0
        centre = np.array([sx * (separation_mm / 2.0 - 4.0 * j), -42.0 - baseline_mm * j,
                           232.0 - 8.0 * j])
        target = np.array([-sx * 8.0, 14.0 + 4.0 * j, 75.0])
        roll = (1.5 if left else -1.2) + 0.7 * j
        f_scale = 1.0
        if rng is not None:
            centre = centre + rng.normal(0.0, 6.0, 3)
            target = target + rng.normal(0.0, 6.0, 3)
            roll += float(rng.normal(0.0, 3.0))
            f_scale = float(rng.uniform(0.9, 1.1))
        R, t = look_at(centre, target, roll)
        Rs.append(R)
        ts.append(t)
        # slightly different lenses per camera, face filling most of the frame
        focal.append(f_scale * min(w, h) * (0.80 + 0.012 * ((i * 7) % 5 - 2)))
        pp.append([(w - 1) / 2.0 + 3.1 * ((i % 3) - 1) + 1.3,
                   (h - 1) / 2.0 - 2.2 * ((i % 2) - 0.5)])
        dc.append([pp[-1][0] - 1.7 + 0.9 * (i % 2), pp[-1][1] + 1.2 - 0.8 * (i % 3)])
        # about 4 px of barrel distortion at the image corners
        k1 = (3.2 + 0.4 * (i % 3)) / diag**3
        k2 = 0.6 / diag**5
        radial.append([k1, k2, 0.0])
    intr = CameraIntrinsics(
        focal=np.array(focal),
        principal_point=np.array(pp),
        radial=np.array(radial),
        distortion_centre=np.array(dc),
        image_size=np.tile([float(w), float(h)], (n_cameras, 1)),
        radial_model=[VICON_RADIAL2] * n_cameras,
        names=[f"cam{i}" for i in range(n_cameras)],
    )
    return intr, np.array(Rs), np.array(ts)

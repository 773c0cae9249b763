"""Camera model: pinhole + Vicon radial distortion, vectorised over points and cameras.

Conventions
-----------
- World->camera: ``x_cam = R @ X + t``; the camera looks down +z, image x right, y down.
- Pixels: OpenCV convention, the centre of the top-left pixel is (0, 0).
- Vicon radial models map *raw* (distorted, as seen on the sensor) pixels to *corrected*
  (ideal pinhole) pixels in closed form::

      d  = (x_r - c_x, a (y_r - c_y))          r = |d|
      s  = 1 + k1 r^2 + k2 r^4 [+ k3 r^6]
      x_c = c_x + s d_x ,  y_c = c_y + s d_y / a

  ``VICON_RADIAL`` (two terms) uses the principal point as distortion centre;
  ``VICON_RADIAL2`` ("Vicon3Parameter cx cy k1 k2 k3") has its own centre and three terms.
  Undistortion is therefore the closed form above and distortion (projection) is its
  inverse, solved per point by Newton's method on the radius.

The reference guide writes ``y_c = (s d_y + c_y) / a``; that is not the inverse of its own
``d_y = a (y_r - c_y)`` when ``a != 1`` and every real file has ``a == 1``, so we use the
self-consistent form above.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

#: Radial model names as written in XCP files.
VICON_RADIAL = "VICON_RADIAL"
VICON_RADIAL2 = "VICON_RADIAL2"


@dataclass
class CameraIntrinsics:
    """Intrinsics of ``C`` cameras as columnar arrays.

    Attributes
    ----------
    focal : ndarray, shape (C,)
        Focal length in pixels (XCP ``FOCAL_LENGTH``).
    principal_point : ndarray, shape (C, 2)
        Principal point in pixels.
    aspect : ndarray, shape (C,)
        Pixel aspect ratio ``a`` (focal length in y is ``f / a``).
    skew : ndarray, shape (C,)
        Skew coefficient (pixels).
    radial : ndarray, shape (C, 3)
        Radial coefficients k1, k2, k3 (per px^2, px^4, px^6); k3 = 0 for ``VICON_RADIAL``.
    distortion_centre : ndarray, shape (C, 2)
        Centre of the radial model in pixels (the principal point for ``VICON_RADIAL``).
    image_size : ndarray, shape (C, 2)
        Sensor size (width, height) in pixels.
    radial_model : list of str
        ``"VICON_RADIAL"`` or ``"VICON_RADIAL2"`` per camera (kept for export).
    names : list of str
        Camera (channel) names.
    """

    focal: NDArray[np.float64]
    principal_point: NDArray[np.float64]
    aspect: NDArray[np.float64] = field(default=None)  # type: ignore[assignment]
    skew: NDArray[np.float64] = field(default=None)  # type: ignore[assignment]
    radial: NDArray[np.float64] = field(default=None)  # type: ignore[assignment]
    distortion_centre: NDArray[np.float64] = field(default=None)  # type: ignore[assignment]
    image_size: NDArray[np.float64] = field(default=None)  # type: ignore[assignment]
    radial_model: list[str] = field(default=None)  # type: ignore[assignment]
    names: list[str] = field(default=None)  # type: ignore[assignment]

    def __post_init__(self) -> None:
        self.focal = np.asarray(self.focal, dtype=np.float64).reshape(-1)
        n = self.focal.shape[0]
        self.principal_point = np.asarray(self.principal_point, np.float64).reshape(n, 2)
        self.aspect = (
            np.ones(n) if self.aspect is None else np.asarray(self.aspect, np.float64).reshape(n)
        )
        self.skew = (
            np.zeros(n) if self.skew is None else np.asarray(self.skew, np.float64).reshape(n)
        )
        if self.radial is None:
            self.radial = np.zeros((n, 3))
        else:
            rad = np.asarray(self.radial, np.float64).reshape(n, -1)
            self.radial = np.zeros((n, 3))
            self.radial[:, : rad.shape[1]] = rad[:, :3]
        if self.distortion_centre is None:
            self.distortion_centre = self.principal_point.copy()
        else:
            self.distortion_centre = np.asarray(self.distortion_centre, np.float64).reshape(n, 2)
        if self.image_size is None:
            self.image_size = np.round(self.principal_point * 2.0)
        else:
            self.image_size = np.asarray(self.image_size, np.float64).reshape(n, 2)
        if self.radial_model is None:
            self.radial_model = [VICON_RADIAL2] * n
        if self.names is None:
            self.names = [f"cam{i}" for i in range(n)]
        if len(self.radial_model) != n or len(self.names) != n:
            raise ValueError("radial_model and names need one entry per camera")

    @property
    def n_cameras(self) -> int:
        """Number of cameras ``C``."""
        return int(self.focal.shape[0])

    def K(self) -> NDArray[np.float64]:
        """Pinhole matrices, shape (C, 3, 3): ``[[f, skew, px], [0, f/a, py], [0, 0, 1]]``."""
        K = np.zeros((self.n_cameras, 3, 3))
        K[:, 0, 0] = self.focal
        K[:, 0, 1] = self.skew
        K[:, 0, 2] = self.principal_point[:, 0]
        K[:, 1, 1] = self.focal / self.aspect
        K[:, 1, 2] = self.principal_point[:, 1]
        K[:, 2, 2] = 1.0
        return K

    def subset(self, cameras: ArrayLike) -> CameraIntrinsics:
        """The intrinsics of the given camera indices, in that order."""
        idx = np.asarray(cameras, dtype=np.intp).reshape(-1)
        return CameraIntrinsics(
            focal=self.focal[idx],
            principal_point=self.principal_point[idx],
            aspect=self.aspect[idx],
            skew=self.skew[idx],
            radial=self.radial[idx],
            distortion_centre=self.distortion_centre[idx],
            image_size=self.image_size[idx],
            radial_model=[self.radial_model[i] for i in idx],
            names=[self.names[i] for i in idx],
        )

    def copy(self) -> CameraIntrinsics:
        """A deep copy."""
        return self.subset(np.arange(self.n_cameras))

    def equals(self, other: CameraIntrinsics, atol: float = 0.0) -> bool:
        """True when every array agrees within ``atol`` and names/models match."""
        arrays = ("focal", "principal_point", "aspect", "skew", "radial",
                  "distortion_centre", "image_size")
        return (
            self.n_cameras == other.n_cameras
            and all(
                np.allclose(getattr(self, a), getattr(other, a), rtol=0.0, atol=atol)
                for a in arrays
            )
            and self.radial_model == other.radial_model
            and self.names == other.names
        )


def undistort_pixels(uv: ArrayLike, intr: CameraIntrinsics) -> NDArray[np.float64]:
    """Raw (distorted) pixels -> corrected pinhole pixels, closed form.

    Parameters
    ----------
    uv : array_like, shape (..., C, 2)
        Raw pixel coordinates, the camera axis second to last. NaN passes through.
    intr : CameraIntrinsics
        Intrinsics of the ``C`` cameras.

    Returns
    -------
    ndarray, shape (..., C, 2)
        Corrected pixel coordinates (px).
    """
    uv = np.asarray(uv, dtype=np.float64)
    c = intr.distortion_centre
    a = intr.aspect
    dx = uv[..., 0] - c[:, 0]
    dy = a * (uv[..., 1] - c[:, 1])
    r2 = dx * dx + dy * dy
    k1, k2, k3 = intr.radial[:, 0], intr.radial[:, 1], intr.radial[:, 2]
    s = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    out = np.empty_like(uv)
    out[..., 0] = c[:, 0] + s * dx
    out[..., 1] = c[:, 1] + s * dy / a
    return out


def distort_pixels(
    uv: ArrayLike, intr: CameraIntrinsics, *, iterations: int = 30, tol: float = 1e-10
) -> NDArray[np.float64]:
    """Corrected pinhole pixels -> raw (distorted) pixels, the inverse of `undistort_pixels`.

    Solves ``rho = r s(r)`` for the raw radius ``r`` by Newton's method, vectorised.

    Parameters
    ----------
    uv : array_like, shape (..., C, 2)
        Corrected pixel coordinates (camera axis second to last).
    intr : CameraIntrinsics
        Intrinsics of the ``C`` cameras.
    iterations : int
        Maximum Newton iterations.
    tol : float
        Stop when every radius update is below this (px).

    Returns
    -------
    ndarray, shape (..., C, 2)
        Raw pixel coordinates (px). Where the model cannot be inverted (beyond the
        radius at which ``r s(r)`` stops increasing) the result is NaN.
    """
    uv = np.asarray(uv, dtype=np.float64)
    c = intr.distortion_centre
    a = intr.aspect
    ex = uv[..., 0] - c[:, 0]
    ey = a * (uv[..., 1] - c[:, 1])
    rho = np.hypot(ex, ey)
    k1, k2, k3 = intr.radial[:, 0], intr.radial[:, 1], intr.radial[:, 2]
    k1 = np.broadcast_to(k1, rho.shape)
    k2 = np.broadcast_to(k2, rho.shape)
    k3 = np.broadcast_to(k3, rho.shape)
    r = rho.copy()
    with np.errstate(invalid="ignore", over="ignore"):
        for _ in range(iterations):
            r2 = r * r
            f = r * (1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))) - rho
            df = 1.0 + r2 * (3.0 * k1 + r2 * (5.0 * k2 + r2 * 7.0 * k3))
            step = f / df
            r = r - step
            if not np.any(np.abs(step) > tol):
                break
        r2 = r * r
        df = 1.0 + r2 * (3.0 * k1 + r2 * (5.0 * k2 + r2 * 7.0 * k3))
        bad = (df <= 0) | (r < 0) | ~np.isfinite(r)
        scale = np.where(rho > 0, r / np.where(rho > 0, rho, 1.0), 1.0)
    out = np.empty_like(uv)
    out[..., 0] = c[:, 0] + scale * ex
    out[..., 1] = c[:, 1] + scale * ey / a
    out[bad] = np.nan
    return out


def project(
    X: ArrayLike,
    R: ArrayLike,
    t: ArrayLike,
    intr: CameraIntrinsics,
    *,
    distort: bool = True,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Project 3D points into every camera.

    Parameters
    ----------
    X : array_like, shape (..., P, 3)
        World points (mm).
    R : array_like, shape (..., C, 3, 3)
        World->camera rotations; leading axes broadcast with those of ``X``.
    t : array_like, shape (..., C, 3)
        World->camera translations (mm).
    intr : CameraIntrinsics
        Intrinsics of the ``C`` cameras.
    distort : bool
        Apply the radial model (raw pixels) or not (corrected pinhole pixels).

    Returns
    -------
    uv : ndarray, shape (..., P, C, 2)
        Pixel coordinates (px).
    depth : ndarray, shape (..., P, C)
        z in each camera frame (mm); points with depth <= 0 are behind the camera and
        their ``uv`` is NaN.
    """
    X = np.asarray(X, dtype=np.float64)
    R = np.asarray(R, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    xc = np.einsum("...cij,...pj->...pci", R, X) + t[..., None, :, :]
    depth = xc[..., 2]
    K = intr.K()
    with np.errstate(divide="ignore", invalid="ignore"):
        xn = xc[..., 0] / depth
        yn = xc[..., 1] / depth
    uv = np.empty(xc.shape[:-1] + (2,))
    uv[..., 0] = K[:, 0, 0] * xn + K[:, 0, 1] * yn + K[:, 0, 2]
    uv[..., 1] = K[:, 1, 1] * yn + K[:, 1, 2]
    uv[depth <= 0] = np.nan
    if distort:
        uv = distort_pixels(uv, intr)
    return uv, depth


def pixels_to_normalised(uv: ArrayLike, intr: CameraIntrinsics) -> NDArray[np.float64]:
    """Raw pixels -> normalised image coordinates (x/z, y/z) in each camera frame.

    Parameters
    ----------
    uv : array_like, shape (..., C, 2)
        Raw pixel coordinates.
    intr : CameraIntrinsics
        Intrinsics of the ``C`` cameras.

    Returns
    -------
    ndarray, shape (..., C, 2)
        Normalised coordinates (dimensionless).
    """
    corr = undistort_pixels(uv, intr)
    K = intr.K()
    yn = (corr[..., 1] - K[:, 1, 2]) / K[:, 1, 1]
    xn = (corr[..., 0] - K[:, 0, 2] - K[:, 0, 1] * yn) / K[:, 0, 0]
    return np.stack([xn, yn], axis=-1)


def camera_centres(R: ArrayLike, t: ArrayLike) -> NDArray[np.float64]:
    """Camera centres ``C = -R^T t``.

    Parameters
    ----------
    R : array_like, shape (..., 3, 3)
    t : array_like, shape (..., 3)

    Returns
    -------
    ndarray, shape (..., 3)
        Centres in world mm.
    """
    R = np.asarray(R, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    return -np.einsum("...ji,...j->...i", R, t)


def pixel_rays(
    uv: ArrayLike, R: ArrayLike, t: ArrayLike, intr: CameraIntrinsics
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """World rays through raw pixels.

    Parameters
    ----------
    uv : array_like, shape (..., C, 2)
        Raw pixel coordinates.
    R : array_like, shape (..., C, 3, 3)
        World->camera rotations (broadcast against ``uv``'s leading axes).
    t : array_like, shape (..., C, 3)
        World->camera translations (mm).
    intr : CameraIntrinsics

    Returns
    -------
    origins : ndarray, shape (..., C, 3)
        Camera centres (mm).
    directions : ndarray, shape (..., C, 3)
        Unit ray directions in the world frame.
    """
    n = pixels_to_normalised(uv, intr)
    d_cam = np.concatenate([n, np.ones(n.shape[:-1] + (1,))], axis=-1)
    R = np.asarray(R, dtype=np.float64)
    d = np.einsum("...ji,...j->...i", R, d_cam)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    origins = np.broadcast_to(camera_centres(R, t), d.shape)
    return origins, d


def quaternion_to_matrix(q: ArrayLike) -> NDArray[np.float64]:
    """Quaternion ``(qx, qy, qz, qw)`` (real part last, as XCP) -> rotation matrix.

    Parameters
    ----------
    q : array_like, shape (..., 4)

    Returns
    -------
    ndarray, shape (..., 3, 3)
    """
    q = np.asarray(q, dtype=np.float64)
    flat = Rotation.from_quat(q.reshape(-1, 4)).as_matrix()
    return flat.reshape(q.shape[:-1] + (3, 3))


def matrix_to_quaternion(R: ArrayLike) -> NDArray[np.float64]:
    """Rotation matrix -> quaternion ``(qx, qy, qz, qw)`` with ``qw >= 0``.

    Parameters
    ----------
    R : array_like, shape (..., 3, 3)

    Returns
    -------
    ndarray, shape (..., 4)
    """
    R = np.asarray(R, dtype=np.float64)
    q = Rotation.from_matrix(R.reshape(-1, 3, 3)).as_quat()
    q = np.where(q[:, 3:4] < 0, -q, q)
    return q.reshape(R.shape[:-2] + (4,))


def rodrigues_to_matrix(rvec: ArrayLike) -> NDArray[np.float64]:
    """Rotation vectors (axis * angle, rad) -> matrices, shape (..., 3) -> (..., 3, 3)."""
    rvec = np.asarray(rvec, dtype=np.float64)
    return Rotation.from_rotvec(rvec.reshape(-1, 3)).as_matrix().reshape(rvec.shape[:-1] + (3, 3))


def matrix_to_rodrigues(R: ArrayLike) -> NDArray[np.float64]:
    """Rotation matrices -> rotation vectors, shape (..., 3, 3) -> (..., 3)."""
    R = np.asarray(R, dtype=np.float64)
    return Rotation.from_matrix(R.reshape(-1, 3, 3)).as_rotvec().reshape(R.shape[:-2] + (3,))


def cross_matrix(v: ArrayLike) -> NDArray[np.float64]:
    """Cross-product matrices ``[v]x`` (``[v]x u = v x u``), shape (..., 3) -> (..., 3, 3)."""
    v = np.asarray(v, dtype=np.float64)
    z = np.zeros(v.shape[:-1])
    return np.stack([
        np.stack([z, -v[..., 2], v[..., 1]], -1),
        np.stack([v[..., 2], z, -v[..., 0]], -1),
        np.stack([-v[..., 1], v[..., 0], z], -1),
    ], -2)

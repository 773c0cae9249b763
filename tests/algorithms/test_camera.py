"""Camera model: projection, distortion inverse, rays."""

from __future__ import annotations

import numpy as np
import pytest

from carapost.algorithms.camera import (
    CameraIntrinsics,
    camera_centres,
    cross_matrix,
    distort_pixels,
    matrix_to_quaternion,
    pixel_rays,
    project,
    quaternion_to_matrix,
    undistort_pixels,
)


def _intrinsics(model: str) -> CameraIntrinsics:
    # Radial terms of the strength real 1280x720 head-rig lenses show (a few px at the corners).
    if model == "VICON_RADIAL":
        radial = [[2.0e-8, 3.0e-15, 0.0], [-1.5e-8, 2.0e-15, 0.0]]
        centre = None
    else:
        radial = [[5.6e-8, -3.4e-15, -7.9e-21], [-2.0e-8, 1.0e-14, 1.0e-21]]
        centre = [[641.3, 358.2], [637.7, 362.9]]
    return CameraIntrinsics(
        focal=[900.0, 1100.0],
        principal_point=[[640.5, 360.2], [639.0, 359.0]],
        radial=radial,
        distortion_centre=centre,
        image_size=[[1280, 720], [1280, 720]],
        radial_model=[model, model],
    )


@pytest.mark.parametrize("model", ["VICON_RADIAL", "VICON_RADIAL2"])
def test_distortion_inverse_over_whole_sensor(model: str) -> None:
    intr = _intrinsics(model)
    xs, ys = np.meshgrid(np.linspace(-0.5, 1279.5, 161), np.linspace(-0.5, 719.5, 91))
    raw = np.stack([xs.ravel(), ys.ravel()], axis=-1)[:, None, :].repeat(2, axis=1)
    corrected = undistort_pixels(raw, intr)
    back = distort_pixels(corrected, intr)
    assert np.max(np.abs(back - raw)) < 1e-6
    # The model really distorts: corners move by more than a pixel.
    assert np.max(np.abs(corrected - raw)) > 1.0


def test_projection_matches_opencv_pinhole_when_undistorted(rng: np.random.Generator) -> None:
    import cv2

    intr = _intrinsics("VICON_RADIAL2")
    intr.radial[:] = 0
    rvec = np.array([[0.1, -0.2, 0.05], [-0.3, 0.1, 0.2]])
    R = np.stack([cv2.Rodrigues(r)[0] for r in rvec])
    t = np.array([[10.0, -5.0, 300.0], [-20.0, 3.0, 280.0]])
    X = rng.uniform(-50, 50, size=(20, 3))
    uv, depth = project(X, R, t, intr)
    for c in range(2):
        ref, _ = cv2.projectPoints(X, rvec[c], t[c], intr.K()[c], None)
        np.testing.assert_allclose(uv[:, c], ref[:, 0], atol=1e-9)
    assert np.all(depth > 0)


def test_rays_pass_through_projected_points(rng: np.random.Generator) -> None:
    intr = _intrinsics("VICON_RADIAL2")
    q = rng.normal(size=(2, 4))
    R = quaternion_to_matrix(q / np.linalg.norm(q, axis=1, keepdims=True))
    C = np.array([[0.0, 0.0, -300.0], [50.0, 0.0, -280.0]])
    t = -np.einsum("cij,cj->ci", R, C)
    np.testing.assert_allclose(camera_centres(R, t), C, atol=1e-9)
    X = rng.uniform(-30, 30, size=(15, 3))
    uv, depth = project(X, R, t, intr)
    ok = depth > 0
    o, d = pixel_rays(uv, R, t, intr)
    # distance of X to each ray
    v = X[:, None, :] - o
    dist = np.linalg.norm(v - np.sum(v * d, axis=-1, keepdims=True) * d, axis=-1)
    assert np.all(dist[ok] < 1e-6)


def test_behind_camera_is_nan() -> None:
    intr = _intrinsics("VICON_RADIAL")
    R = np.stack([np.eye(3), np.eye(3)])
    t = np.zeros((2, 3))
    uv, depth = project(np.array([[0.0, 0.0, -10.0]]), R, t, intr)
    assert np.all(np.isnan(uv)) and np.all(depth < 0)


def test_quaternion_round_trip(rng: np.random.Generator) -> None:
    q = rng.normal(size=(50, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[q[:, 3] < 0] *= -1
    np.testing.assert_allclose(matrix_to_quaternion(quaternion_to_matrix(q)), q, atol=1e-12)


def test_per_frame_broadcasting(rng: np.random.Generator) -> None:
    intr = _intrinsics("VICON_RADIAL2")
    F = 3
    R = np.broadcast_to(np.eye(3), (F, 2, 3, 3)).copy()
    t = np.zeros((F, 2, 3))
    t[:, :, 2] = 300.0
    t[1, 0, 0] = 5.0
    X = rng.uniform(-20, 20, size=(F, 7, 3))
    uv, _ = project(X, R, t, intr)
    assert uv.shape == (F, 7, 2, 2)
    uv1, _ = project(X[1], R[1], t[1], intr)
    np.testing.assert_allclose(uv[1], uv1)


def test_cross_matrix_is_the_cross_product():
    rng = np.random.default_rng(3)
    v, u = rng.normal(size=(2, 4, 5, 3))
    np.testing.assert_allclose(cross_matrix(v) @ u[..., None], np.cross(v, u)[..., None],
                               atol=1e-12)
    assert cross_matrix(v[0, 0]).shape == (3, 3)

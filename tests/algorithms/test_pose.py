"""Camera pose refinement (both schemes) and PnP candidates."""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import pytest

from carapost.algorithms.camera import pixels_to_normalised, project, rodrigues_to_matrix
from carapost.algorithms.pose import pnp_candidates, refine_poses
from carapost.synth.scene import SynthConfig, build_scene


@lru_cache(maxsize=2)
def _scene():
    return build_scene(SynthConfig(frames=2))


def _perturbed(scene, rng):
    R0 = rodrigues_to_matrix(rng.normal(0, 0.01, (4, 3))) @ scene.cam_R[1]
    t0 = scene.cam_t[1] + rng.normal(0, 1.0, (4, 3))
    return R0, t0


def _brim_obs(scene, frame):
    obs = np.where(scene.brim_visible[frame][..., None], scene.brim_uv[frame], np.nan)
    return np.swapaxes(pixels_to_normalised(obs, scene.intrinsics), 0, 1)  # (C, B, 2)


@pytest.mark.parametrize("linearise", ["rotated", "camera"])
def test_refine_poses_recovers_the_next_frames_cameras(linearise):
    # the per-frame re-solve: cameras of frame 1 from a perturbed start and the brim
    scene = _scene()
    R0, t0 = _perturbed(scene, np.random.default_rng(5))
    xn = _brim_obs(scene, 1)
    out = refine_poses(scene.brim3d, xn, R0, t0, scale=scene.intrinsics.focal,
                       huber_px=None if linearise == "camera" else 2.0, linearise=linearise)
    assert out.solved.all()
    uv, _ = project(scene.brim3d, out.R, out.t, scene.intrinsics)
    err = np.linalg.norm(uv - scene.brim_uv[1], axis=-1)[scene.brim_visible[1]]
    assert err.max() < 0.01
    assert np.all(out.rms_px < 0.01)


@pytest.mark.parametrize("linearise", ["rotated", "camera"])
def test_refine_poses_keeps_cameras_with_too_few_points(linearise):
    scene = _scene()
    R0, t0 = _perturbed(scene, np.random.default_rng(6))
    xn = _brim_obs(scene, 1)
    xn[2, 3:] = np.nan  # camera 2 sees 3 dots at most
    out = refine_poses(scene.brim3d, xn, R0, t0, scale=scene.intrinsics.focal, min_points=6,
                       huber_px=None if linearise == "camera" else 2.0, linearise=linearise)
    assert not out.solved[2] and out.solved[[0, 1, 3]].all()
    assert np.array_equal(out.R[2], R0[2]) and np.array_equal(out.t[2], t0[2])
    assert np.isnan(out.rms_px[2])


def test_tracking_resection_is_the_camera_scheme_bit_for_bit(rng):
    from carapost.algorithms.tracking import resect_cameras

    scene = _scene()
    R0, t0 = _perturbed(scene, rng)
    uv = np.where(scene.brim_visible[1][..., None], scene.brim_uv[1], np.nan)
    R, t, solved = resect_cameras(scene.brim3d, uv, R0, t0, scene.intrinsics)
    out = refine_poses(scene.brim3d, _brim_obs(scene, 1), R0, t0,
                       scale=scene.intrinsics.focal, iterations=4, huber_px=None,
                       min_points=6, linearise="camera")
    assert np.array_equal(R, out.R) and np.array_equal(t, out.t)
    assert np.array_equal(solved, out.solved)


def test_refine_poses_rejects_inconsistent_options():
    X, xn = np.zeros((4, 3)), np.zeros((1, 4, 2))
    R, t = np.eye(3)[None], np.zeros((1, 3))
    with pytest.raises(ValueError, match="huber_px"):
        refine_poses(X, xn, R, t, scale=[1.0], linearise="camera")
    with pytest.raises(ValueError, match="scale"):
        refine_poses(X, xn, R, t, huber_px=None, linearise="camera")
    with pytest.raises(ValueError, match="huber_px"):
        refine_poses(X, xn, R, t, huber_px=None)
    with pytest.raises(ValueError, match="linearise"):
        refine_poses(X, xn, R, t, linearise="other")


def test_pnp_candidates_contain_the_true_pose():
    scene = _scene()
    c = 1
    vis = np.flatnonzero(scene.brim_visible[0, :, c])[:6]
    obj = scene.brim3d[vis]
    img = pixels_to_normalised(scene.brim_uv[0, vis, c][:, None], scene.intrinsics.subset([c]))
    cands = pnp_candidates(obj, img[:, 0])
    assert cands
    assert any(np.allclose(R, scene.cam_R[0, c], atol=1e-6)
               and np.allclose(t, scene.cam_t[0, c], atol=1e-3) for R, t in cands)

"""Multi-view geometry: rays, epipolar distance, ray triangulation, point-to-ray RMS."""

from __future__ import annotations

import numpy as np

from carapost.algorithms.camera import pixels_to_normalised, project
from carapost.algorithms.multiview import (
    camera_rays,
    essential_matrix,
    multiview_tracks,
    normalised_coordinates,
    ray_midpoints,
    ray_residual,
    symmetric_epipolar_distance,
    triangulate_tracks,
)
from carapost.synth.scene import SynthConfig, build_scene


def test_multiview_geometry_on_a_synthetic_frame():
    s = build_scene(SynthConfig(frames=1))
    R, t, intr = s.cam_R[0], s.cam_t[0], s.intrinsics
    seen = s.visible[0].all(1)
    X = s.points3d[0][seen]
    uv = s.uv[0][seen]  # (P, C, 2)
    dets_n = [normalised_coordinates(uv[:, c], intr, c) for c in range(4)]
    assert np.allclose(dets_n[1], pixels_to_normalised(uv[:, 1:2], intr.subset([1]))[:, 0])
    # the true pairs satisfy the epipolar constraint, others mostly do not
    E = essential_matrix(R[0], t[0], R[1], t[1])
    d = symmetric_epipolar_distance(dets_n[0], dets_n[1], E, intr.focal[0], intr.focal[1])
    assert np.diag(d).max() < 1e-6
    # ray midpoints and the least-squares intersection agree on exact data
    ca, da = camera_rays(dets_n[0], R[0], t[0])
    cb, db = camera_rays(dets_n[1], R[1], t[1])
    mid = ray_midpoints(ca, da, cb, db)
    tracks = np.tile(np.arange(len(uv))[:, None], (1, 4))
    Xt, res, rep = triangulate_tracks(tracks, dets_n, R, t, intr.focal)
    assert np.allclose(mid, Xt, atol=1e-6)
    assert res.max() < 1e-6 and rep.max() < 1e-6
    assert np.allclose(Xt, X, atol=1e-6)
    # the raw-pixel point-to-ray RMS is 0 on the points and grows off them
    uvp, _ = project(Xt, R, t, intr)
    assert ray_residual(Xt, uvp, R, t, intr).max() < 1e-6
    assert ray_residual(Xt + [0.0, 0.0, 1.0], uvp, R, t, intr).min() > 0.1
    obs = uvp.copy()
    obs[0] = np.nan
    assert np.isnan(ray_residual(Xt, obs, R, t, intr)[0])
    # every marker seen by all four cameras is found as one track
    found, Xf = multiview_tracks(dets_n, R, t, intr.focal, 1.0, min_views=4)
    assert len(found) == len(uv)

"""Takes unlike the standard ones: marker layouts, sizes, inks, head shapes, rigs."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from carapost.algorithms.camera import camera_centres
from carapost.synth import SynthConfig, build_scene
from carapost.synth.face import poisson_marker_set, surface_points
from carapost.synth.variety import HELD_OUT_VARIANTS, TUNING_VARIANTS, other_rig_config


def test_tuning_and_held_out_sets_are_disjoint_and_reproducible():
    assert not set(TUNING_VARIANTS) & set(HELD_OUT_VARIANTS)
    assert other_rig_config(101, frames=10) == other_rig_config(101, frames=10)
    assert other_rig_config(101, frames=10) != other_rig_config(102, frames=10)
    with pytest.raises(ValueError, match="index"):
        other_rig_config(0)


def test_poisson_markers_keep_their_distance_and_sizes():
    specs = poisson_marker_set(60, np.random.default_rng(3), (1.2, 2.0))
    assert len(specs) == 60 and len({m.label for m in specs}) == 60
    phi = np.array([m.phi for m in specs])
    psi = np.array([m.psi for m in specs])
    rad = np.array([m.radius for m in specs])
    assert np.all((rad >= 1.2) & (rad <= 2.0))
    p = surface_points(phi, psi)
    d = np.linalg.norm(p[:, None] - p[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    # blue noise: no two markers closer than a few mm (two discs never touch)
    assert d.min() > 2 * 2.0 + 1.0
    # and off the eyes (the lids fold over them in a blink)
    eye = ((np.abs(phi) - 21) / 8.5) ** 2 + ((psi - 15) / 4.0) ** 2 < 1.0
    assert not eye.any()


def test_other_rig_scene_geometry():
    # variant 0: the nominal rig of these dimensions (a variant moves every camera)
    cfg = dataclasses.replace(other_rig_config(2, frames=4), size=(360, 640), variant=0)
    sc = build_scene(cfg)
    assert len(sc.labels) == cfg.poisson_markers
    assert sc.labels[0] == "P001"
    assert np.all((sc.marker_ink >= 0.12) & (sc.marker_ink <= 0.30))
    cen = camera_centres(sc.nominal_R, sc.nominal_t)
    # the first cameras of the caddies are caddy_separation_mm apart across, the two
    # cameras of a caddy caddy_baseline_mm apart vertically
    assert abs(cen[0, 0] - cen[2, 0]) == pytest.approx(cfg.caddy_separation_mm, abs=1e-6)
    assert abs(cen[0, 1] - cen[1, 1]) == pytest.approx(cfg.caddy_baseline_mm, abs=1e-6)
    # portrait image: the focal follows the short side
    assert sc.intrinsics.focal.max() < 0.9 * 360
    # every marker is seen by two cameras of one caddy somewhere (lower face, jaw)
    vis = sc.visible
    one = (vis.sum(-1) >= 2) & (vis[..., :2].any(-1) != vis[..., 2:].any(-1))
    assert one.any() and (vis.sum(-1) >= 2).mean() > 0.8


def test_head_scale_stretches_the_face():
    base = SynthConfig(frames=2, seed=1, size=(320, 180))
    a = build_scene(base)
    b = build_scene(dataclasses.replace(base, head_scale=(1.1, 0.95, 1.05)))
    # at rest (same slip) the markers scale about the head centre, up to the slip
    ra = np.linalg.norm(a.points3d[0] - a.head_t[0], axis=-1)
    rb = np.linalg.norm(b.points3d[0] - b.head_t[0], axis=-1)
    assert 1.0 < np.median(rb / ra) < 1.1
    # normals stay unit and still face outwards
    n = b.marker_normals[0]
    assert np.allclose(np.linalg.norm(n, axis=-1), 1.0)
    assert np.all(np.einsum("mi,mi->m", n, b.points3d[0] - b.head_t[0]) > 0)


def test_options_leave_the_standard_take_unchanged():
    """New options at their defaults draw nothing: old takes are reproduced exactly."""
    a = build_scene(SynthConfig(frames=3, seed=4, size=(320, 180)))
    b = build_scene(SynthConfig(frames=3, seed=4, size=(320, 180), flex_scale=1.0,
                                slip_scale=1.0, caddy_baseline_mm=45.0))
    assert np.array_equal(a.points3d, b.points3d) and np.array_equal(a.cam_R, b.cam_R)
    assert a.marker_ink is None


def test_marker_ink_sets_the_grey_of_the_disc():
    from carapost.synth.render import render_frame

    base = SynthConfig(frames=1, seed=1, size=(640, 360), noise=0.0, blur=0.0)
    dark = build_scene(dataclasses.replace(base, marker_ink=(0.05, 0.05)))
    pale = build_scene(dataclasses.replace(base, marker_ink=(0.45, 0.45)))
    i_dark, i_pale = render_frame(dark, 0, 0), render_frame(pale, 0, 0)
    vis = dark.visible[0, :, 0]
    u = np.round(dark.uv[0, vis, 0]).astype(int)
    g_dark = i_dark[u[:, 1], u[:, 0]].astype(float)
    g_pale = i_pale[u[:, 1], u[:, 0]].astype(float)
    assert np.median(g_pale) > 3 * np.median(g_dark)


def test_bad_options_are_refused():
    for kw in ({"marker_radius_mm": (2.0, 1.0)}, {"marker_ink": (0.1, 1.5)},
               {"head_scale": (1.0, 2.0, 1.0)}, {"caddy_baseline_mm": 5.0},
               {"poisson_markers": -1}, {"flex_scale": -1.0}):
        with pytest.raises(ValueError):
            SynthConfig(**kw).validate()

"""The skin following the markers (SynthConfig.skin_motion), against the truth."""

from __future__ import annotations

import numpy as np
import pytest

from carapost.algorithms.target_track import sample_patch
from carapost.synth import SynthConfig, build_scene, render_frame
from carapost.synth.render import prepare
from carapost.synth.skin_motion import marker_offsets

SMALL = {"preset": "speech", "frames": 40, "seed": 3, "size": (640, 360)}


@pytest.fixture(scope="module")
def scenes():
    return build_scene(SynthConfig(**SMALL)), build_scene(SynthConfig(**SMALL, skin_motion=True))


def _moving_marker(scene):
    """The face marker visible throughout in camera 0 that slides farthest over the
    head-following skin from frame 0 (a ``skin_motion`` scene), and that frame."""
    prepare(scene)
    A = scene.cache["warps"][0]
    vis = scene.visible[:, :, 0].all(0)
    off = np.stack([marker_offsets(scene, f, 0, A[f, 0])[1][:vis.sum()]
                    for f in range(scene.n_frames)])   # (F, K, 2)
    off = np.linalg.norm(off - off[0], axis=-1)   # the slide since frame 0
    f, k = np.unravel_index(np.argmax(off), off.shape)
    return int(np.flatnonzero(vis)[k]), int(f), float(off[f, k])


def test_the_skin_around_a_marker_moves_with_it(scenes):
    plain, skin = scenes
    m, f, slide = _moving_marker(skin)
    assert slide > 3.0   # a lip marker slides several px over the static skin
    yy, xx = np.mgrid[-12:13, -12:13]
    # the skin around the disc (its ring), not the disc itself
    r_px = plain.marker_radius_mm[m] * SMALL["size"][1] / 260
    ring = (np.hypot(xx, yy) > 2.2 * r_px + 2) & (np.hypot(xx, yy) < 12)

    def ring_ncc(scene):
        a = sample_patch(render_frame(scene, 0, 0, sensor=False), scene.uv[0, m, 0], 25)[ring]
        b = sample_patch(render_frame(scene, f, 0, sensor=False), scene.uv[f, m, 0], 25)[ring]
        a, b = a - a.mean(), b - b.mean()
        return float(a @ b / np.sqrt((a @ a) * (b @ b)))

    assert ring_ncc(skin) > 0.9 > ring_ncc(plain)


def test_off_by_default_and_the_truth_is_unchanged(scenes):
    plain, skin = scenes
    assert plain.rest_points3d is None and skin.rest_points3d is not None
    np.testing.assert_array_equal(plain.uv, skin.uv)
    np.testing.assert_array_equal(plain.visible, skin.visible)

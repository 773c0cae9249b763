"""Label From Template on synthetic faces with known truth (the scene's marker labels)."""

from __future__ import annotations

import numpy as np
import pytest

from carapost.algorithms.camera import rodrigues_to_matrix
from carapost.algorithms.labelling import (
    LabellingParameters,
    label_from_template,
    reference_cloud,
)
from carapost.synth.scene import SynthConfig, build_scene


def _scenes(markers: str, variant: int = 0):
    tpl = build_scene(SynthConfig(preset="rom", markers=markers, frames=60, seed=11,
                                  variant=variant))
    tgt = build_scene(SynthConfig(preset="fast", markers=markers, frames=60, seed=3,
                                  variant=variant))
    return tpl, tgt


@pytest.mark.parametrize(("markers", "variant"), [("standard", 0), ("dense156", 0),
                                                  ("sparse35", 4)])
def test_labels_a_moved_shuffled_take_with_missing_and_spurious_points(markers, variant):
    tpl, tgt = _scenes(markers, variant)
    rng = np.random.default_rng(5)
    # another session: the helmet sits 5 degrees and ~7 mm differently on the head
    R = rodrigues_to_matrix(np.deg2rad(5.0) * np.array([0.6, 0.8, 0.0]))
    X = tgt.points3d @ R.T + [6.0, -3.0, 2.0] + rng.normal(0, 0.15, tgt.points3d.shape)
    M = X.shape[1]
    order = rng.permutation(M)[: M - 3]           # three markers were never tracked
    X = X[:, order]
    ghost = X[:, :2] + [[9.0, 9.0, 9.0]]             # two spurious points
    X = np.concatenate([X, ghost], axis=1)
    X[rng.random(X.shape[:2]) < 0.15] = np.nan        # gaps
    out = label_from_template(tpl.points3d, X)
    truth = np.array([tpl.labels.index(tgt.labels[m]) for m in order] + [-1, -1])
    real = truth >= 0
    assert np.all(out.template_index[real] == truth[real])          # every point labelled
    assert np.all(out.template_index[~real] == -1)                   # ghosts get nothing
    assert np.all(out.confidence[real] > 0.7)
    missing = {tpl.labels.index(tgt.labels[m]) for m in set(range(M)) - set(order)}
    assert missing <= set(out.unmatched.tolist()) | set(out.rejected.tolist())


def test_ambiguous_labels_are_left_unassigned():
    tpl = np.array([[0, 0, 0], [20, 0, 0], [0, 20, 0], [20, 20, 0], [10, 40, 5.0]])
    take = tpl.copy()
    # the fifth point sits halfway between its marker and nothing else it could be: move
    # it next to the fourth marker's place, so two markers compete for two close points
    take[4] = [18.0, 21.0, 0.0]
    out = label_from_template(tpl, take, LabellingParameters(nonrigid_iterations=0))
    assert out.template_index[:3].tolist() == [0, 1, 2]
    assert out.template_index[3] == -1 or out.template_index[4] == -1
    assert out.confidence[3] < 0.5 or out.confidence[4] < 0.5


def test_threshold_and_cancel():
    rng = np.random.default_rng(0)
    face = rng.uniform(-60, 60, (30, 3))
    noisy = face + rng.normal(0, 1.0, face.shape)
    out = label_from_template(face, noisy, LabellingParameters(confidence_threshold=1.0))
    assert out.n_labelled == 0 and len(out.rejected) == 30     # nothing is certain
    stop = label_from_template(face, face, progress=lambda d, n: False)
    assert stop.n_labelled == 0
    with pytest.raises(ValueError, match="need 3 points"):
        label_from_template(face[:2], face)


def test_reference_cloud_uses_well_tracked_frames_and_falls_back():
    X = np.full((10, 4, 3), np.nan)
    X[:, 0] = [1, 2, 3]
    X[:, 1] = np.arange(10)[:, None]
    X[:8, 2] = 7                    # point 2 lost at frames 8-9
    X[9, 3] = 5                     # point 3 only at frame 9: frame 8 is the poor one
    ref = reference_cloud(X, 9)
    assert ref[0].tolist() == [1, 2, 3]
    assert np.allclose(ref[1], 4.0)        # median over frames 0-7 and 9 (not 8)
    ref1 = reference_cloud(X, 1)           # frame 0 only: point 3 falls back to its own
    assert np.allclose(ref1[1], 0.0) and ref1[2].tolist() == [7, 7, 7]
    assert ref1[3].tolist() == [5, 5, 5]

"""Bundle Sequence [Unconstrained]: cameras pulled back to truth, one undo step."""

from __future__ import annotations

import numpy as np
import pytest

from carapost.commands.bundle import BundleSequence
from carapost.commands.process import Initialize3D, SolveBrimAuto
from carapost.commands.recipe import ApplyResult
from carapost.commands.stack import CommandError, CommandStack
from carapost.model.project import new_project
from carapost.session import Session
from tests.algorithms.test_brim import camera_errors
from tests.commands.test_process import full_snapshot, synthetic_project


def _initialised():
    p, scene, _ = synthetic_project(seed=5)
    p.calibration.set_static(scene.nominal_R, scene.nominal_t)
    stack = CommandStack(p)
    for f in range(p.n_frames):
        stack.push(SolveBrimAuto(p, f))
    stack.push(Initialize3D(p, 0))
    # the same points at frame 1: attach by re-initialising with frame 0's points as seeds
    stack.push(Initialize3D(p, 1))
    return p, scene


def test_bundle_sequence_refines_perturbed_cameras_and_undoes_exactly():
    p, scene = _initialised()
    rng = np.random.default_rng(0)
    cal = p.calibration
    cal.t[:] += rng.normal(0, 0.6, cal.t.shape)  # ~1 mm off
    before_err = camera_errors(cal.R[1], cal.t[1], scene.cam_R[1], scene.cam_t[1])[0].max()
    before = full_snapshot(p)
    session = Session(p)
    cmd = session.bundle_sequence()  # over the active range, as the menu item
    assert isinstance(cmd, ApplyResult) and "frames" in cmd.message
    after_err = camera_errors(cal.R[1], cal.t[1], scene.cam_R[1], scene.cam_t[1])[0].max()
    assert after_err < 0.25 < before_err
    after = full_snapshot(p)
    session.undo()
    assert full_snapshot(p) == before
    session.redo()
    assert full_snapshot(p) == after


def test_bundle_sequence_refuses_without_calibration_or_points():
    p = new_project(3, 2)
    with pytest.raises(CommandError, match="no calibration"):
        BundleSequence(p)

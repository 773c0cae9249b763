"""The processing recipe: prepare (snapshot) -> compute (no project) -> ApplyResult.

For every Process step: the job holds no project and no view into its arrays, computing
it after the project it was prepared from is wrecked gives the same result, the result
applies and undoes/redoes bit for bit, and the one-call command gives the same project.
"""

from __future__ import annotations

import copy
from collections.abc import Callable

import numpy as np
import pytest

from carapost.commands.bundle import BundleSequence, prepare_bundle_sequence
from carapost.commands.process import (
    BundleCurrentFrame,
    DetectBlobs,
    Initialize3D,
    SolveBrimAuto,
    SolveBrimManual,
    prepare_bundle_frame,
    prepare_detect_blobs,
    prepare_initialize_3d,
    prepare_solve_brim_auto,
    prepare_solve_brim_manual,
)
from carapost.commands.recipe import ApplyResult, Job, Result, run_job
from carapost.commands.rom import InitializeFromRom, LoadRom, prepare_rom_initialisation
from carapost.commands.stack import Command, CommandStack
from carapost.commands.tracking import (
    TrackCommand,
    TrackTakeCommand,
    prepare_take_tracking,
    prepare_tracking,
)
from carapost.model.project import Project, new_project
from carapost.session import Session
from tests.algorithms.test_rom import rom_project, target_project
from tests.algorithms.test_tracking import scene_of, synth_detections, synth_project
from tests.commands.test_process import _disc_image, full_snapshot, synthetic_project


def _project_arrays(project: Project) -> list[np.ndarray]:
    cal = project.calibration
    return (list(project.points.arrays.values()) + list(project.detections.arrays.values())
            + [project.detections.offsets, cal.R, cal.t, cal.solved])


def _walk(obj: object, depth: int = 0):
    yield obj
    if depth > 4:
        return
    if isinstance(obj, dict):
        children = list(obj.values())
    elif isinstance(obj, list | tuple):
        children = list(obj)
    elif hasattr(obj, "__dict__") and not isinstance(obj, type) and not callable(obj):
        children = list(vars(obj).values())
    else:
        children = []
    for child in children:
        yield from _walk(child, depth + 1)


def _detection_arrays(project: Project) -> list[np.ndarray]:
    return [project.detections.offsets, *project.detections.arrays.values()]


def assert_snapshot_only(job: Job, project: Project) -> None:
    """The job keeps no project and no view into the project's arrays, except read-only
    views of the detections, which the store never changes in place (every edit rebuilds
    them, so a reference is a snapshot)."""
    detections = _detection_arrays(project)
    arrays = [a for a in _project_arrays(project) if not any(a is d for d in detections)]
    for obj in _walk(job):
        assert not isinstance(obj, Project), f"{type(job).__name__} keeps the project"
        if isinstance(obj, np.ndarray) and obj.size:
            assert not any(np.may_share_memory(obj, a) for a in arrays), \
                f"{type(job).__name__} keeps a view into the project"
            if any(np.may_share_memory(obj, d) for d in detections):
                assert not obj.flags.writeable, \
                    f"{type(job).__name__} keeps a writeable view of the detections"


def _wreck(project: Project) -> None:
    """Change what a job could read from its project (it must have snapshotted it): the
    point and camera arrays are overwritten in place, the detections replaced the only way
    the store changes them (rebuilt: here every image emptied)."""
    detections = _detection_arrays(project)
    for a in _project_arrays(project):
        if any(a is d for d in detections):
            continue
        if a.dtype.kind == "f":
            a[...] = np.nan
        elif a.dtype.kind in "iu":
            a[...] = 0
    det = project.detections
    images = [(f, c) for f in range(det.n_frames) for c in range(det.n_cameras)]
    det.replace_images(images, [{k: v[:0] for k, v in det.get(0, 0).items()}] * len(images))
    project.calibration.intrinsics = None


def roundtrip_recipe(project: Project, prepare: Callable[[Project], Job],
                     one_call: Callable[[Project], Command] | None = None) -> Result:
    """prepare on a twin, wreck the twin, compute, apply to ``project``: undo and redo
    bit-identical; the one-call command on another twin ends in the same state."""
    twin = copy.deepcopy(project)
    reference = copy.deepcopy(project)
    job = prepare(twin)
    assert isinstance(job, Job)
    assert_snapshot_only(job, twin)
    _wreck(twin)
    result = job.compute(None)
    stack = CommandStack(project)
    before = full_snapshot(project)
    cmd = stack.push(ApplyResult(result))
    after = full_snapshot(project)
    assert after != before, "the result changed nothing"
    assert cmd.description == result.description == job.description and cmd.memory() > 0
    assert stack.undo()
    assert full_snapshot(project) == before
    assert stack.redo()
    assert full_snapshot(project) == after
    if one_call is not None:
        CommandStack(reference).push(one_call(reference))
        assert full_snapshot(reference) == after
    return result


@pytest.fixture(scope="module")
def brim_project():
    p, scene, idents = synthetic_project(seed=3)
    p.calibration.set_static(scene.nominal_R, scene.nominal_t)
    return p, scene


def test_detect_blobs_recipe():
    p = new_project(3, 2, image_size=(160, 120))
    spots = {0: [(40, 40), (100, 60)], 1: [(30, 80)]}

    def get_image(f, c):
        return _disc_image([(x + 5 * f, y) for x, y in spots[c]])

    res = roundtrip_recipe(p, lambda q: prepare_detect_blobs(q, (0, 2), get_image=get_image,
                                                            workers=1),
                           lambda q: DetectBlobs(q, (0, 2), get_image=get_image, workers=1))
    assert len(res.images) == 6 and not res.cancelled


def test_brim_solves_initialize_3d_and_bundles_recipe(brim_project):
    p0, scene = brim_project
    p = copy.deepcopy(p0)
    roundtrip_recipe(p, lambda q: prepare_solve_brim_auto(q, 1),
                     lambda q: SolveBrimAuto(q, 1))
    roundtrip_recipe(p, lambda q: prepare_initialize_3d(q, 1), lambda q: Initialize3D(q, 1))
    roundtrip_recipe(p, lambda q: prepare_bundle_frame(q, 1),
                     lambda q: BundleCurrentFrame(q, 1))
    # manual solve at frame 0 from the matches the automatic solve attached
    q = copy.deepcopy(p0)
    roundtrip_recipe(q, lambda r: prepare_solve_brim_auto(r, 0))
    assert prepare_solve_brim_manual(q, 0).mode == "manual"
    roundtrip_recipe(q, lambda r: prepare_solve_brim_manual(r, 0),
                     lambda r: SolveBrimManual(r, 0))


def test_bundle_sequence_recipe(brim_project):
    p = copy.deepcopy(brim_project[0])
    stack = CommandStack(p)
    for f in range(p.n_frames):
        run_job(stack, prepare_solve_brim_auto(p, f))
    run_job(stack, prepare_initialize_3d(p, 0))
    run_job(stack, prepare_initialize_3d(p, 1))
    p.calibration.t[:] += np.random.default_rng(0).normal(0, 0.6, p.calibration.t.shape)
    res = roundtrip_recipe(p, lambda q: prepare_bundle_sequence(q, (0, 1)),
                           lambda q: BundleSequence(q, (0, 1)))
    assert "frames" in res.message


@pytest.fixture(scope="module")
def tracking_project():
    scene = scene_of("speech", 12)
    return synth_project(scene, synth_detections(scene))


@pytest.mark.parametrize("direction,single", [(1, False), (1, True)])
def test_tracking_recipe(tracking_project, direction, single):
    p = copy.deepcopy(tracking_project)
    roundtrip_recipe(p, lambda q: prepare_tracking(q, direction, single_frame=single),
                     lambda q: TrackCommand(q, direction, single_frame=single))


def test_backwards_tracking_recipe(tracking_project):
    p = copy.deepcopy(tracking_project)
    CommandStack(p).push(TrackCommand(p, 1))
    p.set_current_frame(p.n_frames - 1)
    roundtrip_recipe(p, lambda q: prepare_tracking(q, -1),
                     lambda q: TrackCommand(q, -1))


def test_track_take_recipe(tracking_project):
    p = copy.deepcopy(tracking_project)
    roundtrip_recipe(p, lambda q: prepare_take_tracking(q, 0),
                     lambda q: TrackTakeCommand(q, 0))


def test_initialize_from_rom_recipe(tmp_path):
    path = rom_project(tmp_path)
    p, _ = target_project()
    CommandStack(p).push(LoadRom(p, path))

    def wreck_rom_too(q: Project) -> Job:
        job = prepare_rom_initialisation(q)
        assert_snapshot_only(job, q.rom.project)
        _wreck(q.rom.project)
        return job

    roundtrip_recipe(p, wreck_rom_too, lambda q: InitializeFromRom(q))


def test_session_prepares_the_process_jobs_and_pushes_the_brim_commands(brim_project):
    """The window's Process items go through `Session.prepare` (one path per action)."""
    p = copy.deepcopy(brim_project[0])
    p.set_current_frame(1)
    session = Session(p)
    job = session.prepare("solve_brim")
    assert isinstance(job, Job)
    session.apply(job.compute(None))
    assert isinstance(session.initialize_3d(), ApplyResult)
    # the default brims have no algorithm (no job): the session pushes the command itself
    assert isinstance(session.initialize_default_brim("2.0"), Command)
    p.set_active_range((0, 1))
    job = session.prepare("detect_blobs", frames="current",
                          get_image=lambda f, c: _disc_image([]))
    assert job.description == "Detect Blobs [Current Frame]" and job.keys[0][0] == 1


def test_initialize_3d_and_take_tracking_take_their_caddies_from_the_rig(brim_project):
    """One definition of a caddy (`carapost.model.rig.caddies`) for both jobs."""
    p = copy.deepcopy(brim_project[0])
    run_job(CommandStack(p), prepare_solve_brim_auto(p, 1))
    assert prepare_initialize_3d(p, 1).caddies == ((0, 1), (2, 3))
    p.take.metadata["rig"] = {"caddies": [[0, 2], [1, 3]]}
    assert prepare_initialize_3d(p, 1).caddies == ((0, 2), (1, 3))
    run_job(CommandStack(p), prepare_initialize_3d(p, 1))
    assert prepare_take_tracking(p, 1).caddies == ((0, 2), (1, 3))

"""Initialize from ROM: a rom take of the same actor initialises a speech take."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from carapost.algorithms.codes import KIND_BRIM
from carapost.algorithms.rom import RomParameters, initialize_from_rom
from carapost.commands.stack import CommandError, CommandStack
from carapost.model.project import RECON_TRIANGULATED, Stick, new_project
from tests.algorithms.test_tracking import scene_of, snapshot, synth_detections, synth_project


def rom_inputs(rom, rf):
    M = len(rom.labels)
    X = np.concatenate([rom.points3d[rf], rom.brim3d])
    kind = np.r_[np.zeros(M, np.int8), np.full(len(rom.brim3d), KIND_BRIM, np.int8)]
    return X, kind


def score(res, target, f):
    M = len(target.labels)
    d = np.linalg.norm(res.positions[:M].astype(np.float64) - target.points3d[f], axis=-1)
    seen = target.visible[f].sum(-1) >= 2
    recovered = float(np.mean(d[seen] <= 2.0))
    mismatched = int(np.sum(d > 2.0))
    return recovered, mismatched


def test_rom_frame_initialises_other_take():
    rom = scene_of("rom", 20, seed=5)
    target = scene_of("speech", 40)
    dets = synth_detections(target)
    X, kind = rom_inputs(rom, 0)
    res = initialize_from_rom([(d[0], d[1]) for d in dets[0]], X, kind, rom.cam_R[0],
                              rom.cam_t[0], rom.intrinsics)
    recovered, mismatched = score(res, target, 0)
    assert recovered >= 0.98
    assert mismatched == 0
    # the brim is matched and the cameras solved for the new frame
    B = len(rom.brim3d)
    assert (res.recon[-B:] == RECON_TRIANGULATED).mean() > 0.8
    from carapost.algorithms.camera import project

    uv, _ = project(rom.brim3d, res.R, res.t, target.intrinsics)
    err = np.linalg.norm(uv - target.brim_uv[0], axis=-1)[target.brim_visible[0]]
    assert np.median(err) < 0.3


def test_rom_brim_only_matches_no_face():
    rom = scene_of("rom", 20, seed=5)
    target = scene_of("speech", 40)
    dets = synth_detections(target)
    X, kind = rom_inputs(rom, 0)
    res = initialize_from_rom([(d[0], d[1]) for d in dets[0]], X, kind, rom.cam_R[0],
                              rom.cam_t[0], rom.intrinsics, brim_only=True)
    M = len(rom.labels)
    assert np.isnan(res.positions[:M]).all()
    assert np.isfinite(res.positions[M:]).all(-1).mean() > 0.8


def test_rom_parameters_validate():
    with pytest.raises(ValueError, match="rom_face_point_tracking_distance"):
        RomParameters(rom_face_point_tracking_distance=-5.0)


def rom_project(tmp_path):
    from carapost.io.cara import save_project

    rom = scene_of("rom", 20, seed=5)
    dets = synth_detections(rom, seed=3)
    prj = synth_project(rom, dets)
    face = np.flatnonzero(prj.points.kind == 0)
    prj.sticks = [Stick(int(prj.points.ids[face[0]]), int(prj.points.ids[face[1]]))]
    prj.labels = list(prj.points.labels)
    path = tmp_path / "rom.cara"
    save_project(prj, path)
    return path


def target_project():
    target = scene_of("speech", 40)
    dets = synth_detections(target)
    F, M, C = target.visible.shape
    prj = new_project(F, C, image_size=target.size)
    images = [(f, c) for f in range(F) for c in range(C)]
    tables = []
    for f, c in images:
        cen, ax, _ = dets[f][c]
        n = len(cen)
        tables.append({"centre": cen, "axes": ax, "angle": np.zeros(n),
                       "colour": np.zeros(n, np.int8), "score": np.ones(n)})
    prj.detections.replace_images(images, tables)
    return prj, target


def test_initialize_from_rom_command(tmp_path, caplog):
    from carapost.commands.rom import InitializeFromRom, LoadRom

    path = rom_project(tmp_path)
    prj, target = target_project()
    stack = CommandStack(prj)
    with caplog.at_level(logging.ERROR, logger="carapost.process"):
        with pytest.raises(CommandError, match=r"no ROM is loaded \(Process > Load ROM first\)"):
            InitializeFromRom(prj)
    assert "no ROM is loaded" in caplog.text
    stack.push(LoadRom(prj, path))
    before = snapshot(prj)
    stack.push(InitializeFromRom(prj))
    after = snapshot(prj)
    # calibration, brim, labels, sticks carried over; labels right
    assert prj.calibration.intrinsics is not None and prj.calibration.solved[0]
    assert (prj.points.kind == KIND_BRIM).sum() == len(target.brim3d)
    assert len(prj.sticks) == 1
    M = len(target.labels)
    face = np.flatnonzero(prj.points.kind == 0)
    lab = [prj.points.labels[c] for c in face]
    truth = np.array([target.points3d[0, target.labels.index(s)] for s in lab])
    d = np.linalg.norm(prj.points.positions[0, face].astype(np.float64) - truth, axis=-1)
    seen = target.visible[0].sum(-1) >= 2
    found = {lab[i] for i in np.flatnonzero(d <= 2.0)}
    assert len(found) >= 0.98 * seen.sum()
    assert np.sum(d > 2.0) == 0
    assert len(face) <= M
    # undo / redo bit-identical
    assert stack.undo()
    assert snapshot(prj) == before
    assert stack.redo()
    assert snapshot(prj) == after
    # a second run warns and does not duplicate any point
    n = prj.points.count
    with caplog.at_level(logging.WARNING, logger="carapost.process"):
        stack.push(InitializeFromRom(prj))
    assert "already has" in caplog.text
    assert prj.points.count == n
    assert len(prj.sticks) == 1


def test_load_rom_refuses_bad_file(tmp_path):
    from carapost.commands.rom import LoadRom

    bad = tmp_path / "x.cara"
    bad.write_bytes(b"not a zip")
    prj, _ = target_project()
    with pytest.raises(CommandError, match="Load ROM"):
        LoadRom(prj, bad)
    assert prj.rom is None

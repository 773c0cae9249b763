"""The record codes and point-array layout are defined once and shared by the model."""

from __future__ import annotations

import numpy as np

from carapost.algorithms import codes


def test_model_reexports_the_same_objects():
    from carapost.model import project

    for name in codes.__all__:
        if name in ("POINT_FILLS", "PointArrays"):
            continue
        assert getattr(project, name) is getattr(codes, name), name


def test_point_fills_follow_point_arrays():
    assert set(codes.POINT_FILLS) == (set(codes.POINT_ARRAYS) - {"keyframe", "sigma"}
                                      - set(codes.RAW_POINT_ARRAYS))
    for k, fill in codes.POINT_FILLS.items():
        dt, f = codes.POINT_ARRAYS[k]
        assert np.asarray(fill, dt) == np.asarray(f, dt) or (np.isnan(fill) and np.isnan(f))


def test_track_and_rom_results_are_one_record():
    from carapost.algorithms.rom import RomResult
    from carapost.algorithms.tracking import TrackResult

    assert TrackResult is RomResult is codes.PointArrays

"""The shared parameter declarations (carapost.algorithms.params) and their use."""

from __future__ import annotations

import dataclasses
import doctest

import numpy as np
import pytest

from carapost.algorithms import params as mod
from carapost.algorithms.blobs import BlobParameters
from carapost.algorithms.brim import BrimSolveParameters
from carapost.algorithms.init3d import Init3DParameters
from carapost.algorithms.params import (
    check_number,
    from_mapping,
    param,
    property_fields,
    to_mapping,
    validate,
)
from carapost.algorithms.rom import RomParameters
from carapost.algorithms.tracking import TrackingParameters
from carapost.algorithms.triangulation import TriangulationParameters

ALL = (BlobParameters, BrimSolveParameters, Init3DParameters, RomParameters,
       TrackingParameters, TriangulationParameters)


def test_examples_run():
    result = doctest.testmod(mod, optionflags=doctest.ELLIPSIS)
    assert result.attempted > 0 and result.failed == 0


@pytest.mark.parametrize("cls", ALL, ids=lambda c: c.__name__)
def test_defaults_pass_their_own_validation(cls):
    obj = cls()
    validate(obj)
    assert from_mapping(cls, to_mapping(obj)) == obj
    for f, info in property_fields(cls):
        assert info.label and info.help, f.name
        assert type(f.default) in (bool, int, float), f.name


def test_message_names_label_field_and_range():
    with pytest.raises(ValueError, match=r"^Black Threshold \(BlobParameters\.black_threshold\) "
                                         r"must be between 0 and 1 \(got 1\.5\)$"):
        BlobParameters(black_threshold=1.5)
    with pytest.raises(ValueError, match=r"^TrackingParameters\.elastic_passes must be at least 1"):
        TrackingParameters(elastic_passes=0)
    with pytest.raises(ValueError, match=r"Minimum Ray Angle .* less than 90 \(got 90\)"):
        TriangulationParameters(min_ray_angle_deg=90.0)
    with pytest.raises(ValueError, match=r"reach_steps\[1\] must be at least 1"):
        Init3DParameters(reach_steps=(1.5, 0.5))
    with pytest.raises(ValueError, match=r"Patch Match Size .* whole number between 3 and 101"):
        TrackingParameters(patch_match_size=7.5)
    with pytest.raises(ValueError, match="finite"):
        RomParameters(rom_max_3d_point_error=float("nan"))


def test_values_are_checked_not_converted():
    p = TrackingParameters(patch_match_size=np.int64(21), max_3d_point_error=np.float32(2))
    assert type(p.patch_match_size) is np.int64 and type(p.max_3d_point_error) is np.float32
    assert TriangulationParameters(minimum_cameras=2.0).minimum_cameras == 2.0


def test_bounds_inclusive_unless_exclusive():
    assert BlobParameters(black_min_radius=1000.0, black_max_radius=1000.0)
    with pytest.raises(ValueError, match="greater than 0"):
        BlobParameters(black_min_radius=0.0)
    assert Init3DParameters(max_allowed_depth=1e6).max_allowed_depth == 1e6  # no cap
    assert check_number(3, "x", minimum=3) == 3.0
    with pytest.raises(ValueError, match="x must be greater than 3"):
        check_number(3, "x", minimum=3, min_exclusive=True)


def test_from_mapping_reads_properties_and_overrides():
    from carapost.model.properties import Properties

    props = Properties({"black_threshold": 0.7, "patch_match_threshold": 0.5})
    assert from_mapping(BlobParameters, props).black_threshold == 0.7
    tp = from_mapping(TrackingParameters, props.section("Tracking Parameters"),
                      elastic_passes=2)
    assert tp.patch_match_threshold == 0.5 and tp.elastic_passes == 2
    assert TrackingParameters.from_mapping({"neighbours": 4}).neighbours == 4
    with pytest.raises(TypeError):
        from_mapping(BlobParameters, {}, no_such_field=1)


def test_param_refuses_bad_declarations():
    with pytest.raises(TypeError, match="label"):
        param(1.0, section="Somewhere")
    with pytest.raises(TypeError, match="immutable"):
        param([1.0, 2.0])


def test_plain_fields_are_not_checked():
    @dataclasses.dataclass(frozen=True)
    class P:
        a: float = param(1.0, min=0.0)
        b: float = 2.0

        def __post_init__(self) -> None:
            validate(self)

    assert P(b=-5.0).b == -5.0
    with pytest.raises(ValueError, match=r"P\.a must be at least 0"):
        P(a=-1.0)

"""The one definition of the head rig's caddies (Initialize 3D, tracking, point info)."""

from __future__ import annotations

import logging

import pytest

from carapost.model.rig import caddies, caddy_groups


@pytest.mark.parametrize(("n", "groups", "pairs"), [
    (0, (), ()),
    (1, ((0,),), ()),
    (3, ((0, 1), (2,)), ((0, 1),)),
    (4, ((0, 1), (2, 3)), ((0, 1), (2, 3))),
    (6, ((0, 1), (2, 3), (4, 5)), ((0, 1), (2, 3), (4, 5))),
])
def test_without_metadata_cameras_pair_in_channel_order(n, groups, pairs) -> None:
    assert caddy_groups(n) == groups
    assert caddies(n) == pairs


def test_the_takes_rig_wins() -> None:
    # what a synthetic take writes: the two halves of the rig
    four = {"rig": {"caddies": [[0, 1], [2, 3]]}}
    assert caddies(4, four) == caddies(4) == ((0, 1), (2, 3))
    six = {"rig": {"caddies": [[0, 1, 2], [3, 4, 5]]}}
    assert caddy_groups(6, six) == ((0, 1, 2), (3, 4, 5))
    assert caddies(6, six) == ((0, 1), (1, 2), (3, 4), (4, 5))
    assert caddies(6, {"caddies": [[0, 3], [1, 4], [2, 5]]}) == ((0, 3), (1, 4), (2, 5))


@pytest.mark.parametrize("bad", [[[0, 1], [1, 2]], [[0, 9]], [[]], "01", [[0, "x"]]])
def test_invalid_metadata_falls_back_with_a_warning(bad, caplog) -> None:
    with caplog.at_level(logging.WARNING, logger="carapost.model"):
        assert caddy_groups(4, {"rig": {"caddies": bad}}) == ((0, 1), (2, 3))
    assert "Ignoring the take's caddies" in caplog.text

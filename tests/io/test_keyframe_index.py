"""`KeyframeIndex.keyframe_before` answers the same on a keyframe (no search) as the
search does everywhere else, for all-intra and sparse keyframes alike."""

from __future__ import annotations

import numpy as np
import pytest

from carapost.io.decode import KeyframeIndex


@pytest.mark.parametrize("every", [1, 3, 12])
def test_keyframe_before_is_the_last_keyframe_at_or_before(every):
    rng = np.random.default_rng(every)
    n = 200
    keys = (np.arange(n) % every == 0) | (rng.random(n) < 0.05)
    ix = KeyframeIndex(np.arange(n) * 100, keys)
    for index in range(-3, n + 5):
        at_or_before = np.flatnonzero(keys[:max(min(index, n - 1), 0) + 1])
        assert ix.keyframe_before(index) == int(at_or_before[-1]), index

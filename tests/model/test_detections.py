"""The detections store never changes its arrays in place (references are snapshots)."""

from __future__ import annotations

import numpy as np

from carapost.model.project import Detections


def _table(n: int, x: float) -> dict[str, np.ndarray]:
    return {"centre": np.full((n, 2), x, np.float32), "axes": np.ones((n, 2), np.float16),
            "angle": np.zeros(n, np.float16), "colour": np.zeros(n, np.int8),
            "score": np.ones(n, np.float16)}


def test_replace_images_rebuilds_instead_of_writing_in_place() -> None:
    det = Detections(3, 2)
    det.replace_images([(f, c) for f in range(3) for c in range(2)],
                       [_table(2 + f, float(10 * f + c)) for f in range(3) for c in range(2)])
    held = {"offsets": det.offsets, **det.arrays}
    before = {k: v.copy() for k, v in held.items()}
    det.replace_images([(1, 0)], [_table(5, -1.0)])          # grows an image
    det.replace_images([(0, 1), (2, 1)], [_table(0, 0.0)] * 2)  # empties two
    for k, v in held.items():
        assert np.array_equal(v, before[k]), k
        assert v is not (det.offsets if k == "offsets" else det.arrays[k])
    assert det.counts().tolist() == [[2, 0], [5, 3], [4, 0]]
    assert (det.centres(1, 0) == -1).all()

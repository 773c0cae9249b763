"""The lossless FFV1 writer: exact pixels for any reader, keyframes where asked, clear
errors."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from carapost.io.decode import AVReader
from carapost.io.encode import FFV1Writer
from carapost.io.errors import CaraFileError


def _images(n: int, seed: int = 2) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    base = cv2.GaussianBlur(rng.integers(0, 256, (72, 128), dtype=np.uint8), (5, 5), 0)
    return [np.clip(base.astype(int) + rng.normal(0, 3, base.shape), 0, 255).astype(np.uint8)
            for _ in range(n)]


@pytest.mark.parametrize("gop, slices", [(1, 4), (12, 1), (5, 4)])
def test_written_frames_are_exact_and_keyframes_as_asked(tmp_path, gop, slices):
    images = _images(26)
    path = tmp_path / "w_cam0.mkv"
    with FFV1Writer(path, (128, 72), 59.94, gop=gop, slices=slices) as w:
        for img in images:
            w.write(img)
    reader = AVReader(path)
    assert reader.n_frames == 26 and abs(reader.fps - 59.94) < 1e-3
    np.testing.assert_array_equal(np.flatnonzero(reader.index.keyframe),
                                  np.arange(0, 26, gop))
    for i in (25, 3, 17, 0, 11, 12):  # random access, backwards included
        np.testing.assert_array_equal(reader.read(i), images[i])
    cap = cv2.VideoCapture(str(path))  # an independent reader sees the same pixels
    for img in images:
        ok, frame = cap.read()
        assert ok
        np.testing.assert_array_equal(frame[..., 0] if frame.ndim == 3 else frame, img)
    cap.release()


def test_bad_images_and_paths_are_refused(tmp_path):
    with FFV1Writer(tmp_path / "x_cam0.mkv", (128, 72), 60) as w:
        with pytest.raises(ValueError, match="uint8 images of shape"):
            w.write(np.zeros((72, 100), np.uint8))
        with pytest.raises(ValueError, match="uint8"):
            w.write(np.zeros((72, 128), np.float32))
        w.write(np.zeros((72, 128), np.uint8))
    with pytest.raises(CaraFileError, match="cannot be written"):
        FFV1Writer(tmp_path / "no" / "such" / "x.mkv", (128, 72), 60)

"""Playback proxies read as gray straight from the luma plane: the same pixels as the
general colour path, any frame in any order, and a damaged proxy says so."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from carapost.io.decode import AVReader
from carapost.io.errors import CaraFileError
from carapost.io.proxy import ProxyReader, write_proxy

W, H, N = 96, 64, 40


@pytest.fixture(scope="module")
def proxy(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("proxy")
    rng = np.random.default_rng(3)
    base = cv2.GaussianBlur(rng.integers(0, 256, (H, W), dtype=np.uint8), (5, 5), 0)
    path = folder / "p_cam0.mkv"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"FFV1"), 60.0, (W, H),
                             isColor=False)
    for i in range(N):
        img = np.roll(base, 3 * i, axis=1)
        img[:4, :4] = (7 * i) % 256
        writer.write(img)
    writer.release()
    out = write_proxy(path)
    assert out is not None
    return out


def test_proxy_frames_match_the_colour_path_in_any_order(proxy):
    general = AVReader(proxy)  # YUV -> BGR -> gray, one frame at a time
    reference = [general.read(i) for i in range(N)]
    general.close()
    reader = ProxyReader(proxy)
    assert reader.n_frames == N
    order = list(range(N)) + list(range(N - 1, -1, -1)) + list(
        np.random.default_rng(5).integers(0, N, 60))
    for i in order:
        img = reader.read(int(i))
        assert img.dtype == np.uint8 and img.shape == (H, W) and img.flags.c_contiguous
        np.testing.assert_array_equal(img, reference[int(i)])
    # every proxy frame is a keyframe: a random frame costs one decode
    assert reader.decoded == len(order)
    reader.close()


def test_a_truncated_proxy_says_which_frame_is_missing(proxy, tmp_path):
    cut = tmp_path / "cut.avi"
    data = proxy.read_bytes()
    cut.write_bytes(data[: len(data) // 2])
    try:
        reader = ProxyReader(cut)
    except CaraFileError:
        return  # refused at opening: also a clear message
    with pytest.raises(CaraFileError, match="frame"):
        for i in range(N):
            reader.read(i)

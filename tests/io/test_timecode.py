"""Frame index <-> burnt-in frame number <-> SMPTE timecode (incl. drop-frame)."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from carapost.io.timecode import (
    Timecode,
    burnt_in_to_frame_index,
    frame_index_to_burnt_in,
    frame_index_to_timecode,
    frames_per_day,
    frames_to_timecode,
    nominal_rate,
    timecode_to_frame_index,
    timecode_to_frames,
)

RATES = [(23.976, False), (24, False), (25, False), (29.97, False), (29.97, True), (30, False),
         (50, False), (59.94, True), (59.94, False), (60, False)]


def _reference_labels(nominal: int, drop: int, count: int) -> list[str]:
    """Labels of the first ``count`` frames, by counting up and skipping dropped labels."""
    out = []
    h = m = s = f = 0
    while len(out) < count:
        skipped = drop and s == 0 and f < drop and m % 10 != 0
        if not skipped:
            out.append(f"{h:02d}:{m:02d}:{s:02d}{';' if drop else ':'}{f:02d}")
        f += 1
        if f == nominal:
            f, s = 0, s + 1
            if s == 60:
                s, m = 0, m + 1
                if m == 60:
                    m, h = 0, h + 1
    return out


@pytest.mark.parametrize(
    ("text", "rate", "frames"),
    [
        ("00:10:00;00", 29.97, 17982),
        ("01:00:00;00", 29.97, 107892),
        ("00:01:00;02", 29.97, 1800),
        ("00:00:59;29", 29.97, 1799),
        ("00:01:00;04", 59.94, 3600),
        ("00:10:00;00", 59.94, 35964),
        ("01:00:00;00", 59.94, 215784),
        ("01:00:00:00", 25, 90000),
        ("01:00:00:00", 23.976, 86400),
        ("10:00:00:00", 29.97, 1080000),  # non-drop 29.97 counts at 30
        ("23:59:59:59", 60, 24 * 3600 * 60 - 1),
    ],
)
def test_known_values(text: str, rate: float, frames: int) -> None:
    assert timecode_to_frames(text, rate) == frames
    assert str(frames_to_timecode(frames, rate, drop_frame=";" in text)) == text


@pytest.mark.parametrize(("rate", "nominal", "drop", "count"),
                         [(29.97, 30, 2, 40_000), (59.94, 60, 4, 40_000)])
def test_drop_frame_matches_counting_labels(rate: float, nominal: int, drop: int,
                                            count: int) -> None:
    labels = _reference_labels(nominal, drop, count)
    assert [str(frames_to_timecode(n, rate, True)) for n in range(count)] == labels
    assert all(timecode_to_frames(label, rate) == n for n, label in enumerate(labels))


@given(data=st.data())
def test_round_trip_over_the_day(data: st.DataObject) -> None:
    rate, drop = data.draw(st.sampled_from(RATES))
    n = data.draw(st.integers(0, frames_per_day(rate, drop) - 1))
    tc = frames_to_timecode(n, rate, drop)
    assert tc.frames < nominal_rate(rate)
    assert timecode_to_frames(tc, rate) == n
    assert Timecode.parse(str(tc)) == tc


def test_frames_per_day_and_wrap() -> None:
    assert frames_per_day(29.97, True) == 24 * 107892
    assert frames_per_day(25) == 24 * 3600 * 25
    assert str(frames_to_timecode(frames_per_day(29.97, True), 29.97, True)) == "00:00:00;00"
    assert str(frames_to_timecode(-1, 25)) == "23:59:59:24"


def test_parse_variants() -> None:
    assert Timecode.parse("01:02:03:04") == Timecode(1, 2, 3, 4, False)
    assert Timecode.parse(" 01:02:03;04 ").drop_frame
    assert Timecode.parse("01;02;03;04") == Timecode(1, 2, 3, 4, True)
    assert str(Timecode(1, 2, 3, 4, True)) == "01:02:03;04"


@pytest.mark.parametrize("text", ["", "1:2:3", "aa:bb:cc:dd", "00:60:00:00", "24:00:00:00",
                                  "00:00:60:00", "00:00:00:00:00", "-1:00:00:00"])
def test_bad_strings(text: str) -> None:
    with pytest.raises(ValueError, match="timecode"):
        Timecode.parse(text)


@pytest.mark.parametrize(
    ("text", "rate", "pattern"),
    [
        ("00:01:00;00", 29.97, "does not exist in drop-frame"),
        ("00:01:00;01", 29.97, "does not exist in drop-frame"),
        ("00:01:00;03", 59.94, "does not exist in drop-frame"),
        ("00:00:00:25", 25, "must be below 25"),
        ("00:00:00;30", 29.97, "must be below 30"),
        ("00:00:00;00", 25, "drop-frame timecode exists only"),
        ("00:00:00;00", 30, "drop-frame timecode exists only"),
        ("00:00:00:00", 27.5, "not a timecode rate"),
        ("00:00:00:00", 0, "frame rate"),
    ],
)
def test_invalid_labels_and_rates(text: str, rate: float, pattern: str) -> None:
    with pytest.raises(ValueError, match=pattern):
        timecode_to_frames(text, rate)


def test_ten_minute_labels_exist_in_drop_frame() -> None:
    assert timecode_to_frames("00:20:00;00", 29.97) == 2 * 17982
    assert timecode_to_frames("00:20:00;00", 29.97) - timecode_to_frames(
        "00:19:59;29", 29.97) == 1


def test_capture_rate_multiple_of_timecode_rate() -> None:
    got = [frame_index_to_timecode(i, "01:00:00:00", 60, 30) for i in range(5)]
    assert [(str(tc), sub) for tc, sub in got] == [
        ("01:00:00:00", 0), ("01:00:00:00", 1), ("01:00:00:01", 0), ("01:00:00:01", 1),
        ("01:00:00:02", 0)]
    # 59.94 capture on 29.97 drop-frame timecode, across a dropped minute boundary.
    tc, sub = frame_index_to_timecode(3, "00:00:59;29", 59.94, 29.97)
    assert (str(tc), sub) == ("00:01:00;02", 1)
    assert timecode_to_frame_index("00:01:00;02", "00:00:59;29", 59.94, 29.97, subframe=1) == 3
    # A take that starts on the second sub-frame.
    tc, sub = frame_index_to_timecode(0, "10:00:00:00", 120, 30, start_subframe=3)
    assert (str(tc), sub) == ("10:00:00:00", 3)
    assert str(frame_index_to_timecode(1, "10:00:00:00", 120, 30, start_subframe=3)[0]) == \
        "10:00:00:01"
    with pytest.raises(ValueError, match="whole multiple"):
        frame_index_to_timecode(0, "00:00:00:00", 50, 30)
    with pytest.raises(ValueError, match="sub-frame must be in 0..1"):
        timecode_to_frame_index("00:00:00:00", "00:00:00:00", 60, 30, subframe=2)


@given(data=st.data())
def test_frame_index_round_trip(data: st.DataObject) -> None:
    capture, tc_rate, drop = data.draw(st.sampled_from([
        (60, 30, False), (59.94, 29.97, True), (119.88, 29.97, True), (50, 25, False),
        (29.97, None, True), (25, None, False), (23.976, None, False), (240, 60, False)]))
    k = 1 if tc_rate is None else round(capture / tc_rate)
    rate = capture if tc_rate is None else tc_rate
    start = frames_to_timecode(data.draw(st.integers(0, frames_per_day(rate, drop) - 1)),
                               rate, drop)
    start_sub = data.draw(st.integers(0, k - 1))
    index = data.draw(st.integers(0, 36_000 * 4))
    tc, sub = frame_index_to_timecode(index, start, capture, tc_rate, start_subframe=start_sub)
    assert 0 <= sub < k and tc.drop_frame == drop
    back = timecode_to_frame_index(tc, start, capture, tc_rate, sub, start_subframe=start_sub)
    assert back == index
    # Consecutive frames are one sub-frame apart.
    tc2, sub2 = frame_index_to_timecode(index + 1, start, capture, tc_rate,
                                        start_subframe=start_sub)
    step = (timecode_to_frames(tc2, rate) * k + sub2) - (timecode_to_frames(tc, rate) * k + sub)
    assert step in (1, 1 - frames_per_day(rate, drop) * k)


def test_midnight_rollover() -> None:
    tc, _ = frame_index_to_timecode(1, "23:59:59:24", 25)
    assert str(tc) == "00:00:00:00"
    assert timecode_to_frame_index("00:00:00:00", "23:59:59:24", 25) == 1


def test_burnt_in_numbers() -> None:
    assert frame_index_to_burnt_in(0) == 1
    assert frame_index_to_burnt_in(41, first_burnt_in=1001) == 1042
    assert burnt_in_to_frame_index(1042, first_burnt_in=1001) == 41
    for i in range(0, 500, 7):
        assert burnt_in_to_frame_index(frame_index_to_burnt_in(i, 5), 5) == i
    with pytest.raises(ValueError, match="before the first frame"):
        burnt_in_to_frame_index(0)
    with pytest.raises(ValueError, match=">= 0"):
        frame_index_to_burnt_in(-1)
    with pytest.raises(ValueError, match="integer"):
        frame_index_to_burnt_in(1.5)  # type: ignore[arg-type]

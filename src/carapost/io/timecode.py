"""Frame indices, burnt-in frame numbers and SMPTE timecode.

Three ways of naming a frame of a take:

- the **frame index**: zero-based, used everywhere inside carapost;
- the **burnt-in frame number**: what the capture software printed on the image, by
  default ``index + 1``;
- the **SMPTE timecode** ``HH:MM:SS:FF`` (``HH:MM:SS;FF`` for drop-frame), counted at the
  timecode rate, which may be a whole fraction of the capture rate (60 fps video with
  30 fps timecode holds two capture frames, *sub-frames* 0 and 1, per timecode frame).

Timecode rates are 23.976, 24, 25, 29.97, 30, 47.952, 48, 50, 59.94, 60 (any whole rate
or NTSC ``n * 1000/1001`` rate). Labels count at the *nominal* rate (24, 30, 60, ...).
Drop-frame (only 29.97 and 59.94) skips the labels ``;00`` and ``;01`` (``;00``-``;03``
at 59.94) at the start of every minute except minutes 0, 10, 20, ... so that the labels
keep pace with the wall clock. Timecode wraps at 24 hours.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

__all__ = [
    "Timecode",
    "burnt_in_to_frame_index",
    "frame_index_to_burnt_in",
    "frame_index_to_timecode",
    "frames_per_day",
    "frames_to_timecode",
    "nominal_rate",
    "timecode_to_frame_index",
    "timecode_to_frames",
]

_TC_RE = re.compile(r"^\s*(\d{1,2})([:;])(\d{1,2})([:;])(\d{1,2})([:;.,])(\d{1,3})\s*$")


@dataclass(frozen=True)
class Timecode:
    """One SMPTE timecode label.

    Attributes
    ----------
    hours, minutes, seconds, frames : int
        The fields (0-23, 0-59, 0-59, 0 to nominal rate - 1; the last is checked
        against the rate by the conversion functions).
    drop_frame : bool
        Drop-frame label (written with ``;`` before the frames).
    """

    hours: int
    minutes: int
    seconds: int
    frames: int
    drop_frame: bool = False

    def __post_init__(self) -> None:
        for name, limit in (("hours", 24), ("minutes", 60), ("seconds", 60), ("frames", 1000)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int):
                raise ValueError(f"timecode {name} must be an integer, got {value!r}")
            if not 0 <= value < limit:
                raise ValueError(f"timecode {name} must be in 0..{limit - 1}, got {value}")

    def __str__(self) -> str:
        sep = ";" if self.drop_frame else ":"
        return f"{self.hours:02d}:{self.minutes:02d}:{self.seconds:02d}{sep}{self.frames:02d}"

    @classmethod
    def parse(cls, text: str) -> Timecode:
        """Parse ``"HH:MM:SS:FF"`` (non-drop) or ``"HH:MM:SS;FF"`` (drop-frame).

        Any ``;`` separator (``"01;00;00;00"``), or ``.``/``,`` before the frames, marks
        drop-frame as well.

        Raises
        ------
        ValueError
            If the text is not a timecode or a field is out of range.
        """
        if not isinstance(text, str):
            raise ValueError(f"timecode must be text, got {type(text).__name__}")
        m = _TC_RE.match(text)
        if m is None:
            raise ValueError(f"{text!r} is not a timecode (expected HH:MM:SS:FF, or "
                             "HH:MM:SS;FF for drop-frame)")
        h, s1, mi, s2, s, s3, f = m.groups()
        drop = ";" in (s1, s2, s3) or s3 in ".,"
        try:
            return cls(int(h), int(mi), int(s), int(f), drop)
        except ValueError as exc:
            raise ValueError(f"{text!r} is not a valid timecode: {exc}") from None


def nominal_rate(rate: float) -> int:
    """Frames per timecode second that label a ``rate`` fps signal (29.97 -> 30).

    Raises
    ------
    ValueError
        If ``rate`` is neither a whole number nor an NTSC ``n * 1000/1001`` rate.
    """
    try:
        rate = float(rate)
    except (TypeError, ValueError):
        raise ValueError(f"frame rate must be a number, got {rate!r}") from None
    if not rate > 0 or rate != rate or rate > 1000:
        raise ValueError(f"frame rate must be in (0, 1000] fps, got {rate}")
    whole = round(rate)
    ntsc = round(rate * 1001 / 1000)
    if abs(rate - whole) < 1e-6:
        return int(whole)
    if abs(rate - ntsc * 1000 / 1001) < 5e-3:
        return int(ntsc)
    raise ValueError(f"{rate} fps is not a timecode rate (use a whole rate such as 24, "
                     "25, 30 or an NTSC rate such as 23.976, 29.97, 59.94)")


def _drop_count(rate: float, drop_frame: bool) -> tuple[int, int]:
    """(nominal rate, labels dropped per minute) with validation."""
    nom = nominal_rate(rate)
    if not drop_frame:
        return nom, 0
    if nom not in (30, 60) or abs(float(rate) - nom) < 1e-6:
        raise ValueError(f"drop-frame timecode exists only at 29.97 and 59.94 fps "
                         f"(NTSC multiples of 30), not at {rate} fps")
    return nom, 2 * nom // 30


def frames_per_day(rate: float, drop_frame: bool = False) -> int:
    """Number of timecode labels in 24 hours (where timecode wraps to 00:00:00:00)."""
    nom, drop = _drop_count(rate, drop_frame)
    return 24 * (3600 * nom - 54 * drop)


def timecode_to_frames(tc: Timecode | str, rate: float, drop_frame: bool | None = None) -> int:
    """Count of timecode frames from 00:00:00:00 to ``tc``.

    Parameters
    ----------
    tc : Timecode or str
        The label.
    rate : float
        Timecode rate (fps), e.g. 25 or 29.97.
    drop_frame : bool, optional
        Count as drop-frame; defaults to the label's own ``drop_frame``.

    Returns
    -------
    int
        Frames since midnight, in ``[0, frames_per_day)``.

    Raises
    ------
    ValueError
        If the frames field is >= the nominal rate, the label is one that drop-frame
        skips (e.g. ``00:01:00;00``), or the rate does not allow drop-frame.

    Examples
    --------
    >>> timecode_to_frames("00:10:00;00", 29.97)
    17982
    """
    if isinstance(tc, str):
        tc = Timecode.parse(tc)
    drop_frame = tc.drop_frame if drop_frame is None else bool(drop_frame)
    nom, drop = _drop_count(rate, drop_frame)
    if tc.frames >= nom:
        raise ValueError(f"timecode {tc}: frames field {tc.frames} must be below {nom} at "
                         f"{rate} fps")
    minutes = 60 * tc.hours + tc.minutes
    if drop and tc.seconds == 0 and tc.frames < drop and tc.minutes % 10 != 0:
        raise ValueError(f"timecode {tc} does not exist in drop-frame at {rate} fps: frames "
                         f"00-{drop - 1:02d} are skipped at the start of each minute not "
                         "divisible by 10")
    return (3600 * tc.hours + 60 * tc.minutes + tc.seconds) * nom + tc.frames - drop * (
        minutes - minutes // 10)


def frames_to_timecode(n: int, rate: float, drop_frame: bool = False) -> Timecode:
    """Timecode label of the ``n``-th timecode frame since midnight (wrapping at 24 h).

    Parameters
    ----------
    n : int
        Frame count (negative or beyond a day wraps around midnight).
    rate : float
        Timecode rate (fps).
    drop_frame : bool
        Produce a drop-frame label.

    Returns
    -------
    Timecode

    Examples
    --------
    >>> str(frames_to_timecode(1800, 29.97, drop_frame=True))
    '00:01:00;02'
    """
    n = _as_int(n, "frame count")
    nom, drop = _drop_count(rate, drop_frame)
    n %= frames_per_day(rate, drop_frame)
    if drop:
        per_min = 60 * nom - drop            # labels in a minute that drops
        per_ten = 600 * nom - 9 * drop       # labels in ten minutes
        tens, rem = divmod(n, per_ten)
        # Add back the labels skipped before frame n, then count at the nominal rate.
        n += 9 * drop * tens + (drop * ((rem - drop) // per_min) if rem >= drop else 0)
    s, f = divmod(n, nom)
    m, s = divmod(s, 60)
    h, m = divmod(m, 60)
    return Timecode(h, m, s, f, drop_frame)


def _as_int(value: object, what: str) -> int:
    if isinstance(value, bool) or not hasattr(value, "__index__"):
        raise ValueError(f"{what} must be an integer, got {value!r}")
    return int(value)  # type: ignore[call-overload]


def _subframes(capture_rate: float, timecode_rate: float | None) -> tuple[float, int]:
    """(timecode rate, capture frames per timecode frame)."""
    nominal_rate(capture_rate)
    if timecode_rate is None:
        return capture_rate, 1
    nominal_rate(timecode_rate)
    ratio = float(capture_rate) / float(timecode_rate)
    k = round(ratio)
    if k < 1 or abs(ratio - k) > 1e-6 * k:
        raise ValueError(f"capture rate {capture_rate} fps must be a whole multiple of the "
                         f"timecode rate {timecode_rate} fps")
    return timecode_rate, int(k)


def frame_index_to_timecode(
    index: int,
    start_tc: Timecode | str,
    capture_rate: float,
    timecode_rate: float | None = None,
    *,
    start_subframe: int = 0,
) -> tuple[Timecode, int]:
    """Timecode (and sub-frame) of a zero-based frame index.

    Parameters
    ----------
    index : int
        Zero-based frame index in the take (>= 0).
    start_tc : Timecode or str
        Timecode of frame 0; its ``drop_frame`` sets the labelling of the result.
    capture_rate : float
        Capture frame rate (fps).
    timecode_rate : float, optional
        Timecode rate when it differs from the capture rate; the capture rate must be a
        whole multiple of it (e.g. 59.94 capture, 29.97 timecode).
    start_subframe : int
        Sub-frame of frame 0 within its timecode frame.

    Returns
    -------
    timecode : Timecode
    subframe : int
        Which capture frame within that timecode frame (0 when the rates are equal).

    Examples
    --------
    >>> tc, sub = frame_index_to_timecode(3, "01:00:00:00", 60, 30)
    >>> str(tc), sub
    ('01:00:00:01', 1)
    """
    if isinstance(start_tc, str):
        start_tc = Timecode.parse(start_tc)
    index = _as_int(index, "frame index")
    if index < 0:
        raise ValueError(f"frame index must be >= 0, got {index}")
    tc_rate, k = _subframes(capture_rate, timecode_rate)
    start_subframe = _as_int(start_subframe, "start sub-frame")
    if not 0 <= start_subframe < k:
        raise ValueError(f"start sub-frame must be in 0..{k - 1}, got {start_subframe}")
    start = timecode_to_frames(start_tc, tc_rate)
    n, sub = divmod(start * k + start_subframe + index, k)
    return frames_to_timecode(n, tc_rate, start_tc.drop_frame), sub


def timecode_to_frame_index(
    tc: Timecode | str,
    start_tc: Timecode | str,
    capture_rate: float,
    timecode_rate: float | None = None,
    subframe: int = 0,
    *,
    start_subframe: int = 0,
) -> int:
    """Zero-based frame index of a timecode (and sub-frame).

    Timecode is cyclic: a label earlier than ``start_tc`` is taken to be after the next
    midnight, so the result is always >= 0 (check it against the take's frame count).

    Parameters
    ----------
    tc : Timecode or str
        The label, read in the drop-frame mode of ``start_tc``.
    start_tc : Timecode or str
        Timecode of frame 0.
    capture_rate, timecode_rate : float
        As in `frame_index_to_timecode`.
    subframe : int
        Capture frame within the timecode frame (0 .. capture/timecode ratio - 1).
    start_subframe : int
        Sub-frame of frame 0.

    Returns
    -------
    int

    Raises
    ------
    ValueError
        On labels that do not exist at the rate, or sub-frames out of range.
    """
    if isinstance(start_tc, str):
        start_tc = Timecode.parse(start_tc)
    if isinstance(tc, str):
        tc = Timecode.parse(tc)
    tc_rate, k = _subframes(capture_rate, timecode_rate)
    subframe = _as_int(subframe, "sub-frame")
    start_subframe = _as_int(start_subframe, "start sub-frame")
    for name, value in (("sub-frame", subframe), ("start sub-frame", start_subframe)):
        if not 0 <= value < k:
            raise ValueError(f"{name} must be in 0..{k - 1}, got {value}")
    drop = start_tc.drop_frame
    n = timecode_to_frames(tc, tc_rate, drop)
    start = timecode_to_frames(start_tc, tc_rate, drop)
    total = frames_per_day(tc_rate, drop) * k
    return (n * k + subframe - start * k - start_subframe) % total


def frame_index_to_burnt_in(index: int, first_burnt_in: int = 1) -> int:
    """Burnt-in frame number shown on the image for a zero-based frame index.

    Parameters
    ----------
    index : int
        Zero-based frame index (>= 0).
    first_burnt_in : int
        Number burnt into frame 0 (1 by default).
    """
    index = _as_int(index, "frame index")
    if index < 0:
        raise ValueError(f"frame index must be >= 0, got {index}")
    return index + _as_int(first_burnt_in, "first burnt-in number")


def burnt_in_to_frame_index(number: int, first_burnt_in: int = 1) -> int:
    """Zero-based frame index of a burnt-in frame number.

    Raises
    ------
    ValueError
        If ``number`` is below ``first_burnt_in`` (before the take).
    """
    number = _as_int(number, "burnt-in frame number")
    first = _as_int(first_burnt_in, "first burnt-in number")
    if number < first:
        raise ValueError(f"burnt-in frame number {number} is before the first frame of the "
                         f"take ({first})")
    return number - first

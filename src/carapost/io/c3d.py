"""C3D export and import (our own numpy reader and writer).

Why our own code instead of ezc3d or py-c3d (details in docs/file-formats.md):

* ezc3d 1.7.2 swaps the two bytes of the fourth point word relative to the C3D spec and
  always writes a header scale of -1.0, so its residuals and camera masks are wrong in any
  spec-following reader; its Python objects also cost ~2 GB for a 10-minute take.
* py-c3d follows the spec but builds one Python object per frame and has no LABELS2 support.
* The data block is a plain array of little-endian float32, so numpy writes it in chunks at
  disk speed, and a pure-Python parameter parser cannot crash the process on a bad file.

Word 4 of every point sample is written exactly as the spec says: a signed 16-bit integer
stored as a float, residual byte (``residual / |POINT:SCALE|``) in the low byte, the
contribution mask of cameras 1-7 in bits 8-14 of the high byte, ``-1`` for invalid samples.
Samples marked *modified* (interpolated, filtered, ...) get word 4 = 0, which the spec
defines as "valid but processed" (mask cleared, residual 0). A measured sample always gets a
residual byte of at least 1 so that it is not mistaken for a processed one.

With more than 7 cameras the whole contribution mask is stored in extra analog channels at
the point rate (one channel per point, value = uint16 bit mask, bit c = camera c + 1), and the
``CARAPOST`` parameter group says so (``MASK_LAYOUT = "WORD4+ANALOG"``). Parameters cannot
hold it: a parameter is limited to 32 KB and the whole parameter section to 255 blocks.
"""

from __future__ import annotations

import os
import re
import struct
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from carapost import __version__
from carapost.io.atomic import atomic_output
from carapost.io.errors import CaraFileError

__all__ = ["C3DData", "read_c3d", "write_c3d", "choose_residual_scale"]

_BLOCK = 512
_INTEL, _DEC, _MIPS = 84, 85, 86
_CHAR, _BYTE, _INT, _FLOAT = -1, 1, 2, 4
# Nice residual quanta (mm); the smallest one whose 255 steps cover the largest residual wins.
_SCALE_LADDER = tuple(m * 10.0**e for e in range(-3, 3) for m in (1.0, 2.0, 5.0))
_FRAMES_PER_CHUNK = 2048
_TIMECODE_RE = re.compile(r"^\d{2}:\d{2}:\d{2}[:;.]\d{2,3}$")
_NAME_RE = re.compile(r"^[A-Z0-9_]{1,127}$")
_UNIT_TO_MM = {"mm": 1.0, "m": 1000.0, "cm": 10.0, "um": 1e-3}


# --------------------------------------------------------------------------------------
# Atomic output (shared with the FBX writer)
# --------------------------------------------------------------------------------------


# --------------------------------------------------------------------------------------
# Data returned by the reader
# --------------------------------------------------------------------------------------


@dataclass
class C3DData:
    """Contents of a C3D file, decoded as the C3D specification says.

    Attributes
    ----------
    positions : ndarray, shape (F, P, 3), float64
        Point coordinates in millimetres; NaN where the sample is invalid.
    residuals : ndarray, shape (F, P), float64
        Residual in millimetres (low byte of word 4 times ``|POINT:SCALE|``); NaN where invalid.
    camera_mask : ndarray, shape (F, P, 7), bool
        Camera contribution bits of word 4 (column k = camera k + 1); False where invalid.
    processed : ndarray, shape (F, P), bool
        Valid samples whose word 4 is 0 (spec: processed, e.g. interpolated or filtered).
    labels, descriptions : list of str
        One per point (``LABELS``, ``LABELS2``, ... concatenated).
    rate : float
        Point frame rate (Hz).
    first_frame : int
        Frame number of the first frame (1-based, as stored in the file).
    units : str
        ``POINT:UNITS`` as stored; positions and residuals are converted to mm anyway.
    scale : float
        ``POINT:SCALE`` (negative = float storage).
    has_camera_masks : bool
        True if the file carries a real contribution mask: non-zero on some valid samples and
        not one constant value on every valid sample (NDI writes bit 1 everywhere).
    camera_mask_full : ndarray, shape (F, P, C), bool, or None
        All cameras' contribution when a carapost file stored more than 7 cameras.
    camera_names : list of str
        ``CARAPOST:CAMERA_NAMES`` (empty for other files).
    timecode_start : str or None
        ``CARAPOST:START_TIMECODE``.
    timecode_rate : float or None
        ``CARAPOST:TIMECODE_RATE``.
    groups : dict
        Every parameter: ``groups[GROUP][PARAM]`` = str, list of str, scalar or ndarray.
    """

    positions: np.ndarray
    residuals: np.ndarray
    camera_mask: np.ndarray
    processed: np.ndarray
    labels: list[str]
    descriptions: list[str]
    rate: float
    first_frame: int
    units: str
    scale: float
    has_camera_masks: bool
    camera_mask_full: np.ndarray | None = None
    camera_names: list[str] = field(default_factory=list)
    timecode_start: str | None = None
    timecode_rate: float | None = None
    groups: dict[str, dict[str, Any]] = field(default_factory=dict)

    @property
    def valid(self) -> np.ndarray:
        """[F, P] bool: samples with a valid position."""
        return ~np.isnan(self.positions[..., 0])


# --------------------------------------------------------------------------------------
# Parameter section: writing
# --------------------------------------------------------------------------------------


@dataclass
class _Param:
    name: str
    ptype: int
    dims: tuple[int, ...]
    data: bytes
    desc: str = ""


def _char_param(name: str, value: str | Sequence[str], desc: str = "") -> _Param:
    if isinstance(value, str):
        raw = value.encode("utf-8")
        if len(raw) > 255:
            raise ValueError(f"C3D parameter {name}: text longer than 255 bytes")
        return _Param(name, _CHAR, (len(raw),) if raw else (0,), raw, desc)
    items = [str(v).encode("utf-8") for v in value]
    width = max((len(b) for b in items), default=0)
    width = max(width, 1)
    if width > 255 or len(items) > 255:
        raise ValueError(f"C3D parameter {name}: at most 255 strings of at most 255 bytes")
    raw = b"".join(b.ljust(width) for b in items)
    return _Param(name, _CHAR, (width, len(items)), raw, desc)


def _num_param(name: str, value: Any, desc: str = "", ptype: int | None = None) -> _Param:
    arr = np.asarray(value)
    if ptype is None:
        if arr.dtype == bool:
            ptype = _BYTE
        elif np.issubdtype(arr.dtype, np.integer):
            ptype = _INT
        elif np.issubdtype(arr.dtype, np.floating):
            ptype = _FLOAT
        else:
            raise ValueError(f"C3D parameter {name}: unsupported value type {arr.dtype}")
    if ptype == _INT:
        if arr.size and (arr.min() < -32768 or arr.max() > 65535):
            raise ValueError(f"C3D parameter {name}: integers must fit in 16 bits")
        data = arr.astype(np.int64).astype("<u2" if arr.size and arr.max() > 32767 else "<i2")
    elif ptype == _BYTE:
        data = arr.astype("<i1")
    else:
        data = arr.astype("<f4")
    if any(d > 255 for d in arr.shape) or arr.ndim > 7:
        raise ValueError(f"C3D parameter {name}: each dimension must be at most 255")
    # C3D lists dimensions fastest-first; numpy C order is slowest-first.
    return _Param(name, ptype, tuple(arr.shape[::-1]), data.tobytes(), desc)


def _value_param(name: str, value: Any) -> _Param:
    """A parameter from a Python value (str, list of str, number, array)."""
    if not _NAME_RE.match(name):
        raise ValueError(f"C3D parameter name {name!r}: use 1-127 characters A-Z, 0-9, _")
    if isinstance(value, str):
        return _char_param(name, value)
    if isinstance(value, Sequence) and value and all(isinstance(v, str) for v in value):
        return _char_param(name, list(value))
    arr = np.asarray(value)
    if arr.dtype.kind in "US":
        return _char_param(name, [str(v) for v in arr.ravel()])
    return _num_param(name, arr)


def _chunked_char(name: str, values: Sequence[str], desc: str) -> list[_Param]:
    """``NAME``, ``NAME2``, ``NAME3``, ... for more than 255 strings (C3D convention)."""
    width = max([len(v.encode("utf-8")) for v in values] + [1])
    per = max(1, min(255, 32000 // width))
    chunks = [values[i : i + per] for i in range(0, len(values), per)] or [[]]
    out = []
    for k, chunk in enumerate(chunks):
        pname = name if k == 0 else f"{name}{k + 1}"
        if chunk:
            out.append(_char_param(pname, list(chunk), desc))
        else:
            out.append(_Param(pname, _CHAR, (1, 0), b"", desc))
    return out


def _chunked_num(name: str, values: np.ndarray, desc: str, ptype: int) -> list[_Param]:
    chunks = [values[i : i + 255] for i in range(0, len(values), 255)] or [values[:0]]
    return [
        _num_param(name if k == 0 else f"{name}{k + 1}", c, desc, ptype)
        for k, c in enumerate(chunks)
    ]


def _encode_parameters(groups: list[tuple[str, str, list[_Param]]]) -> bytes:
    """Encode groups (name, description, params) as a C3D parameter section (no header)."""
    records: list[tuple[bytes, bytes]] = []  # (name part, body after the offset field)
    for gid, (gname, gdesc, params) in enumerate(groups, start=1):
        gn = gname.encode("ascii")
        gd = gdesc.encode("utf-8")[:255]
        records.append((struct.pack("<bb", len(gn), -gid) + gn, bytes([len(gd)]) + gd))
        for p in params:
            pn = p.name.encode("ascii")
            pd = p.desc.encode("utf-8")[:255]
            body = struct.pack("<bB", p.ptype, len(p.dims)) + bytes(p.dims) + p.data
            records.append((struct.pack("<bb", len(pn), gid) + pn, body + bytes([len(pd)]) + pd))
    out = bytearray()
    for k, (head, body) in enumerate(records):
        if len(body) + 2 > 32767:
            raise ValueError("C3D parameter too large (a parameter is limited to 32 KB)")
        # The offset points from itself to the next record; 0 marks the last record.
        offset = 0 if k == len(records) - 1 else len(body) + 2
        out += head + struct.pack("<h", offset) + body
    return bytes(out)


# --------------------------------------------------------------------------------------
# Writer
# --------------------------------------------------------------------------------------


def choose_residual_scale(max_residual: float) -> float:
    """Smallest "nice" residual quantum (mm) whose 255 steps cover ``max_residual``.

    Parameters
    ----------
    max_residual : float
        Largest residual to store (mm). Non-finite or non-positive gives 0.01.

    Returns
    -------
    float
        Positive quantum from 0.001, 0.002, 0.005, 0.01, ... ; ``POINT:SCALE`` is its negative.
    """
    if not np.isfinite(max_residual) or max_residual <= 0:
        return 0.01
    for s in _SCALE_LADDER:
        if 255.0 * s >= max_residual * (1 - 1e-9):
            return float(s)
    return float(_SCALE_LADDER[-1])


def _check_array(name: str, arr: Any, shape: tuple[int, ...], dtype: Any) -> np.ndarray:
    a = np.asarray(arr)
    if a.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {a.shape}")
    if dtype is bool:
        if a.dtype != bool:
            raise ValueError(f"{name} must be a bool array, got {a.dtype}")
        return a
    if not np.issubdtype(a.dtype, np.number):
        raise ValueError(f"{name} must be numeric, got {a.dtype}")
    return a


def _pack_mask(mask: np.ndarray) -> np.ndarray:
    """[..., C] bool -> [...] uint16 with bit c = camera c (C <= 16)."""
    packed = np.packbits(mask, axis=-1, bitorder="little")
    out = packed[..., 0].astype(np.uint16)
    if packed.shape[-1] > 1:
        out |= packed[..., 1].astype(np.uint16) << 8
    return out


def write_c3d(
    path: str | os.PathLike[str],
    positions: np.ndarray,
    *,
    labels: Sequence[str],
    rate: float,
    residuals: np.ndarray | None = None,
    camera_mask: np.ndarray | None = None,
    modified: np.ndarray | None = None,
    descriptions: Sequence[str] | None = None,
    first_frame: int = 1,
    timecode_start: str | None = None,
    timecode_rate: float | None = None,
    manufacturer: tuple[str, str] = ("carapost", __version__),
    extra_groups: Mapping[str, Mapping[str, Any]] | None = None,
    camera_names: Sequence[str] | None = None,
    residual_scale: float | None = None,
) -> None:
    """Write 3D point trajectories to a float-format, Intel C3D file.

    Parameters
    ----------
    path : str or PathLike
        Output file; written atomically (temporary file, fsync, rename).
    positions : array_like, shape (F, P, 3)
        Point positions in mm; NaN in any coordinate marks the sample invalid (missing).
    labels : sequence of str, length P
        Point labels (unique, non-empty). More than 255 go into ``LABELS2``, ``LABELS3``, ...
    rate : float
        Frame rate in Hz (> 0).
    residuals : array_like, shape (F, P), optional
        RMS distance (mm) of each point to its contributing rays. NaN = unknown.
    camera_mask : array_like of bool, shape (F, P, C), optional
        Which cameras contributed (1 <= C <= 16). Cameras 1-7 go into word 4; with C > 7
        the whole mask also goes into analog channels described by the ``CARAPOST`` group.
    modified : array_like of bool, shape (F, P), optional
        Interpolated / filtered / otherwise modified samples: written with word 4 = 0
        (mask cleared, residual 0), the spec's marker for processed data.
    descriptions : sequence of str, length P, optional
        Point descriptions (default: empty strings).
    first_frame : int
        Frame number of the first frame (>= 1); stored in the header and
        ``TRIAL:ACTUAL_START_FIELD``.
    timecode_start : str, optional
        Start timecode ``"HH:MM:SS:FF"`` (stored as ``CARAPOST:START_TIMECODE``).
    timecode_rate : float, optional
        Timecode rate in Hz (``CARAPOST:TIMECODE_RATE``).
    manufacturer : (str, str)
        Software name and version for the ``MANUFACTURER`` group.
    extra_groups : mapping, optional
        ``{GROUP: {PARAM: value}}`` with str, list of str, int, float or array values.
    camera_names : sequence of str, length C, optional
        Camera names (``CARAPOST:CAMERA_NAMES``; bit c of the mask = camera c).
    residual_scale : float, optional
        Residual quantum in mm (``POINT:SCALE = -residual_scale``). By default the smallest
        of 0.001, 0.002, 0.005, 0.01, ... that covers the largest residual.

    Raises
    ------
    ValueError
        For arrays of the wrong shape or type, bad labels or parameters.
    CaraFileError
        If the file cannot be written.
    """
    pos = np.asarray(positions)
    if pos.ndim != 3 or pos.shape[2] != 3 or not np.issubdtype(pos.dtype, np.number):
        raise ValueError(f"positions must be a numeric [F, P, 3] array, got shape {pos.shape}")
    n_frames, n_points, _ = pos.shape
    if n_frames < 1 or n_points < 1:
        raise ValueError("positions must hold at least one frame and one point")
    if n_points > 32767:
        raise ValueError("C3D files hold at most 32767 points")
    labels = [str(s) for s in labels]
    if len(labels) != n_points:
        raise ValueError(f"labels has {len(labels)} entries for {n_points} points")
    if any(not s.strip() for s in labels):
        raise ValueError("labels must not be empty")
    descriptions = [""] * n_points if descriptions is None else [str(s) for s in descriptions]
    if len(descriptions) != n_points:
        raise ValueError(f"descriptions has {len(descriptions)} entries for {n_points} points")
    rate = float(rate)
    if not np.isfinite(rate) or rate <= 0:
        raise ValueError(f"rate must be a positive frame rate in Hz, got {rate}")
    first_frame = int(first_frame)
    if first_frame < 1:
        raise ValueError(f"first_frame must be >= 1, got {first_frame}")
    if timecode_start is not None and not _TIMECODE_RE.match(timecode_start):
        raise ValueError(f"timecode_start must look like HH:MM:SS:FF, got {timecode_start!r}")
    shape_fp = (n_frames, n_points)
    res = None if residuals is None else _check_array("residuals", residuals, shape_fp, float)
    mod = None if modified is None else _check_array("modified", modified, shape_fp, bool)
    n_cams = 0
    if camera_mask is not None:
        cm = np.asarray(camera_mask)
        if cm.ndim != 3 or cm.shape[:2] != shape_fp or not 1 <= cm.shape[2] <= 16:
            raise ValueError(
                f"camera_mask must have shape ({n_frames}, {n_points}, C) with 1 <= C <= 16, "
                f"got {cm.shape}"
            )
        camera_mask = _check_array("camera_mask", cm, cm.shape, bool)
        n_cams = cm.shape[2]
    if camera_names is not None:
        camera_names = [str(s) for s in camera_names]
        if camera_mask is not None and len(camera_names) != n_cams:
            raise ValueError(f"camera_names has {len(camera_names)} names for {n_cams} cameras")
    valid_all = ~np.isnan(pos).any(axis=2)

    if residual_scale is None:
        if res is not None:
            keep = valid_all & np.isfinite(res)
            if mod is not None:
                keep &= ~mod
            residual_scale = choose_residual_scale(float(res[keep].max()) if keep.any() else 0)
        else:
            residual_scale = 0.01
    residual_scale = float(residual_scale)
    if not np.isfinite(residual_scale) or residual_scale <= 0:
        raise ValueError(f"residual_scale must be positive, got {residual_scale}")
    if res is not None and np.any(res[np.isfinite(res)] < 0):
        raise ValueError("residuals must be >= 0 (use NaN positions for invalid samples)")

    full_mask = n_cams > 7
    n_analog = n_points if full_mask else 0
    last_frame = first_frame + n_frames - 1
    scale32 = np.float32(-residual_scale)
    rate32 = np.float32(rate)

    # ---- parameters
    point = [
        _num_param("USED", n_points, "Number of points", _INT),
        _num_param("FRAMES", min(n_frames, 65535), "Number of frames", _INT),
        _num_param("DATA_START", 0, "First block of the data section", _INT),  # patched below
        _num_param("SCALE", scale32, "Residual quantum (mm); negative = float data", _FLOAT),
        _num_param("RATE", rate32, "Frame rate (Hz)", _FLOAT),
        _char_param("UNITS", "mm", "Units of the 3D data"),
        *_chunked_char("LABELS", labels, "Point labels"),
        *_chunked_char("DESCRIPTIONS", descriptions, "Point descriptions"),
    ]
    if n_frames > 65535:
        point.append(_num_param("LONG_FRAMES", np.float32(n_frames), "Number of frames", _FLOAT))
    analog = [
        _num_param("USED", n_analog, "Number of analog channels", _INT),
        _num_param("RATE", np.float32(rate if n_analog else 0.0), "Analog rate (Hz)", _FLOAT),
    ]
    if n_analog:
        mask_labels = [f"CAMMASK{k + 1}" for k in range(n_points)]
        analog += [
            *_chunked_char("LABELS", mask_labels, "Camera mask channels"),
            *_chunked_char("DESCRIPTIONS", labels, "Point of each mask channel"),
            *_chunked_num("SCALE", np.ones(n_points, np.float32), "", _FLOAT),
            *_chunked_num("OFFSET", np.zeros(n_points, np.int16), "", _INT),
            _num_param("GEN_SCALE", np.float32(1.0), "", _FLOAT),
            *_chunked_char("UNITS", ["mask"] * n_points, ""),
        ]
    force = [_num_param("USED", 0, "Number of force plates", _INT)]
    trial = [
        _num_param("ACTUAL_START_FIELD", [first_frame & 0xFFFF, first_frame >> 16], "", _INT),
        _num_param("ACTUAL_END_FIELD", [last_frame & 0xFFFF, last_frame >> 16], "", _INT),
        _num_param("CAMERA_RATE", rate32, "Frame rate (Hz)", _FLOAT),
    ]
    company, version = manufacturer
    manu = [
        _char_param("COMPANY", str(company)),
        _char_param("SOFTWARE", str(company)),
        _char_param("VERSION_LABEL", str(version)),
    ]
    cara = [
        _char_param("FORMAT_VERSION", "1", "Layout version of this group"),
        _num_param("CAMERA_COUNT", n_cams, "Cameras in the contribution mask", _INT),
        _char_param("MASK_LAYOUT", "WORD4+ANALOG" if full_mask else "WORD4"),
    ]
    if full_mask:
        cara.append(_num_param("MASK_ANALOG_FIRST", 1, "1-based first mask channel", _INT))
    if camera_names:
        cara += _chunked_char("CAMERA_NAMES", camera_names, "bit c of the mask = camera c")
    if timecode_start is not None:
        cara.append(_char_param("START_TIMECODE", timecode_start, "Timecode of the first frame"))
    if timecode_rate is not None:
        cara.append(_num_param("TIMECODE_RATE", np.float32(timecode_rate), "Hz", _FLOAT))
    groups: list[tuple[str, str, list[_Param]]] = [
        ("POINT", "3D point parameters", point),
        ("ANALOG", "Analog data parameters", analog),
        ("FORCE_PLATFORM", "Force platforms", force),
        ("TRIAL", "Trial information", trial),
        ("MANUFACTURER", "Software that wrote the file", manu),
        ("CARAPOST", "carapost export details", cara),
    ]
    taken = {g[0] for g in groups}
    for gname, params in (extra_groups or {}).items():
        gname = str(gname).upper()
        if not _NAME_RE.match(gname) or gname in taken:
            raise ValueError(f"extra_groups: invalid or reserved group name {gname!r}")
        taken.add(gname)
        groups.append((gname, "", [_value_param(str(k).upper(), v) for k, v in params.items()]))

    section = _encode_parameters(groups)
    n_param_blocks = -(-(len(section) + 4) // _BLOCK)
    if n_param_blocks > 255:
        raise ValueError("C3D parameter section too large (more than 255 blocks)")
    data_start = 2 + n_param_blocks
    if data_start > 65535:
        raise ValueError("C3D parameter section too large")
    point[2] = _num_param("DATA_START", data_start, "First block of the data section", _INT)
    section = _encode_parameters(groups)  # same length: only the value changed
    param_bytes = struct.pack("<BBBB", 1, 0x50, n_param_blocks, _INTEL) + section
    param_bytes = param_bytes.ljust(n_param_blocks * _BLOCK, b"\0")

    header = bytearray(_BLOCK)
    struct.pack_into(
        "<BBHHHHHfHHf",
        header,
        0,
        2,  # parameter section starts at block 2
        0x50,
        n_points,
        n_analog,
        min(first_frame, 65535),
        min(last_frame, 65535),
        0,
        scale32,
        data_start,
        1 if n_analog else 0,
        rate32,
    )

    # ---- data block, in chunks of frames to keep memory flat
    weights_ok = valid_all
    with atomic_output(path) as fh:
        fh.write(bytes(header))
        fh.write(param_bytes)
        stride = 4 * n_points + n_analog
        written = 0
        for a in range(0, n_frames, _FRAMES_PER_CHUNK):
            b = min(a + _FRAMES_PER_CHUNK, n_frames)
            n = b - a
            buf = np.zeros((n, stride), dtype="<f4")
            pts = buf[:, : 4 * n_points].reshape(n, n_points, 4)
            ok = weights_ok[a:b]
            pts[..., :3] = pos[a:b]
            if res is not None:
                r = res[a:b]
                rbyte = np.where(np.isfinite(r), np.rint(r / residual_scale), 0.0)
                rbyte = np.clip(rbyte, 1, 255).astype(np.int32)
                rbyte[~np.isfinite(r)] = 0
            else:
                rbyte = np.zeros((n, n_points), np.int32)
            if camera_mask is not None:
                bits = _pack_mask(camera_mask[a:b])
                word = rbyte | ((bits & 0x7F).astype(np.int32) << 8)
                if full_mask:
                    buf[:, 4 * n_points :] = np.where(ok, bits, 0)
            else:
                word = rbyte
            if mod is not None:
                word[mod[a:b]] = 0
                if full_mask:
                    buf[:, 4 * n_points :][mod[a:b]] = 0
            word[~ok] = -1
            pts[..., 3] = word
            pts[..., :3][~ok] = 0.0
            fh.write(memoryview(buf).cast("B"))
            written += buf.nbytes
        tail = written % _BLOCK
        if tail:
            fh.write(b"\0" * (_BLOCK - tail))


# --------------------------------------------------------------------------------------
# Reader
# --------------------------------------------------------------------------------------


class _Bytes:
    """Bounds-checked reads from a bytes object with a fixed byte order."""

    def __init__(self, data: bytes, endian: str) -> None:
        self.data = data
        self.e = endian

    def unpack(self, fmt: str, pos: int) -> tuple[Any, ...]:
        size = struct.calcsize(self.e + fmt)
        if pos < 0 or pos + size > len(self.data):
            raise ValueError(f"truncated at byte {pos}")
        return struct.unpack_from(self.e + fmt, self.data, pos)


def _dec_to_ieee(raw: np.ndarray) -> np.ndarray:
    """DEC (VAX F) float32 bytes, read as little-endian uint32, to IEEE float32."""
    u = raw.view("<u4") if raw.dtype != np.uint32 else raw
    swapped = ((u & 0xFFFF) << 16) | (u >> 16)
    return (swapped.astype(np.uint32).view("<f4") / 4.0).astype(np.float32)


def _text(raw: bytes) -> str:
    """C3D text is ASCII in theory; accept UTF-8 (what we write) and fall back to Latin-1."""
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        text = raw.decode("latin-1")
    return text.rstrip(" \0")


def _decode_value(ptype: int, dims: tuple[int, ...], raw: bytes, proc: int) -> Any:
    if ptype == _CHAR:
        if len(dims) <= 1:
            return _text(raw)
        width = dims[0]
        n = int(np.prod(dims[1:])) if width else 0
        return [_text(raw[i * width : (i + 1) * width]) for i in range(n)]
    big = proc == _MIPS
    if ptype == _BYTE:
        arr = np.frombuffer(raw, dtype=np.int8)
    elif ptype == _INT:
        arr = np.frombuffer(raw, dtype=">i2" if big else "<i2").astype(np.int16)
    elif ptype == _FLOAT:
        if proc == _DEC:
            arr = _dec_to_ieee(np.frombuffer(raw, dtype="<u4"))
        else:
            arr = np.frombuffer(raw, dtype=">f4" if big else "<f4").astype(np.float32)
    else:
        raise ValueError(f"unknown parameter type {ptype}")
    if not dims:
        return arr[0].item() if arr.size else None
    return arr.reshape(dims[::-1])


def _parse_parameters(buf: _Bytes, start: int, end: int, proc: int) -> dict[str, dict[str, Any]]:
    """Parse parameter records leniently: stop at a zero name, zero group or zero offset."""
    group_names: dict[int, str] = {}
    by_id: dict[int, dict[str, Any]] = {}
    pos = start
    if end > len(buf.data):
        raise ValueError("the parameter section is truncated")
    while pos + 2 <= end:
        nlen, gid = buf.unpack("bb", pos)
        if nlen == 0 or gid == 0:
            break
        nlen = abs(nlen)
        name = buf.data[pos + 2 : pos + 2 + nlen].decode("latin-1").strip().upper()
        off_pos = pos + 2 + nlen
        (offset,) = buf.unpack("h", off_pos)
        body = off_pos + 2
        if gid < 0:
            group_names[-gid] = name
            by_id.setdefault(-gid, {})
        else:
            ptype, ndims = buf.unpack("bB", body)
            dims = tuple(buf.data[body + 2 : body + 2 + ndims])
            nbytes = abs(ptype) * int(np.prod(dims)) if dims else abs(ptype)
            dstart = body + 2 + ndims
            if ptype not in (_CHAR, _BYTE, _INT, _FLOAT) or dstart + nbytes > len(buf.data):
                raise ValueError(f"parameter {name} is malformed")
            value = _decode_value(ptype, dims, buf.data[dstart : dstart + nbytes], proc)
            by_id.setdefault(gid, {})[name] = value
        if offset <= 0:
            break
        pos = off_pos + offset
    groups: dict[str, dict[str, Any]] = {}
    for gid, params in by_id.items():
        gname = group_names.get(gid, f"GROUP{gid}")
        groups.setdefault(gname, {}).update(params)
    return groups


def _strings(group: Mapping[str, Any], name: str) -> list[str]:
    """``NAME`` + ``NAME2`` + ``NAME3`` ... as one list of strings."""
    out: list[str] = []
    k = 1
    while True:
        key = name if k == 1 else f"{name}{k}"
        if key not in group:
            break
        v = group[key]
        out.extend([v] if isinstance(v, str) else list(v))
        k += 1
    return out


def _scalar(group: Mapping[str, Any], name: str) -> float | None:
    v = group.get(name)
    if v is None or isinstance(v, (str, list)):
        return None
    arr = np.asarray(v).ravel()
    return float(arr[0]) if arr.size else None


def _uint32_field(group: Mapping[str, Any], name: str) -> int | None:
    v = group.get(name)
    if v is None or isinstance(v, (str, list)):
        return None
    words = np.asarray(v).ravel().astype(np.int64) & 0xFFFF
    if words.size == 0:
        return None
    return int(words[0] + (words[1] << 16 if words.size > 1 else 0))


def read_c3d(path: str | os.PathLike[str]) -> C3DData:
    """Read the 3D points of a C3D file (Intel, DEC or MIPS; integer or float data).

    Parameters
    ----------
    path : str or PathLike
        The C3D file.

    Returns
    -------
    C3DData
        Positions in mm with NaN for invalid samples, word 4 decoded as the spec says
        (residual = low byte, cameras 1-7 = high byte; ``65535.0`` and ``-32768.0`` vendor
        sentinels wrap to negative int16 and read as invalid).

    Raises
    ------
    CaraFileError
        If the file is missing, unreadable or not a well-formed C3D file.
    """
    p = Path(path)
    try:
        data = p.read_bytes()
    except OSError as exc:
        raise CaraFileError(p, f"cannot be read: {exc.strerror or exc}") from exc
    try:
        return _read_c3d_bytes(data)
    except CaraFileError:
        raise
    except (ValueError, struct.error, IndexError, OverflowError, UnicodeError) as exc:
        raise CaraFileError(p, f"is not a readable C3D file ({exc})") from exc
    except _C3DProblem as exc:
        raise CaraFileError(p, str(exc)) from exc


class _C3DProblem(Exception):
    pass


def _read_c3d_bytes(data: bytes) -> C3DData:
    if len(data) < _BLOCK or data[1] != 0x50:
        raise _C3DProblem("is not a C3D file (no C3D header key)")
    pblock = data[0]
    pstart = (pblock - 1) * _BLOCK
    if pblock < 1 or pstart + 4 > len(data):
        raise _C3DProblem("is not a C3D file (bad parameter section pointer)")
    n_pblocks, proc = data[pstart + 2], data[pstart + 3]
    if proc not in (_INTEL, _DEC, _MIPS):
        raise _C3DProblem(f"has an unknown processor type {proc}")
    buf = _Bytes(data, ">" if proc == _MIPS else "<")
    (n_points, n_analog_per_frame, h_first, h_last, _gap) = buf.unpack("HHHHH", 2)
    (data_block,) = buf.unpack("H", 16)
    (analog_per_frame,) = buf.unpack("H", 18)
    if proc == _DEC:
        h_scale = float(_dec_to_ieee(np.frombuffer(data[12:16], "<u4"))[0])
        h_rate = float(_dec_to_ieee(np.frombuffer(data[20:24], "<u4"))[0])
    else:
        h_scale = buf.unpack("f", 12)[0]
        h_rate = buf.unpack("f", 20)[0]
    pend = pstart + max(n_pblocks, 1) * _BLOCK
    if data_block > pblock:
        pend = max(pend, min((data_block - 1) * _BLOCK, len(data)))
    groups = _parse_parameters(buf, pstart + 4, pend, proc)
    point = groups.get("POINT", {})

    if data_block == 0:
        data_block = int(_scalar(point, "DATA_START") or 0)
    if data_block < 2:
        raise _C3DProblem("has no data section pointer")
    scale = _scalar(point, "SCALE")
    if scale is None or scale == 0:
        scale = h_scale
    if scale == 0:
        raise _C3DProblem("has a zero POINT:SCALE")
    rate = _scalar(point, "RATE") or h_rate
    is_float = scale < 0

    first = h_first
    n_frames = h_last - h_first + 1 if h_last >= h_first else 0
    trial = groups.get("TRIAL", {})
    t_start, t_end = (
        _uint32_field(trial, "ACTUAL_START_FIELD"),
        _uint32_field(trial, "ACTUAL_END_FIELD"),
    )
    if t_start is not None and t_end is not None and t_end >= t_start and t_end >= h_last:
        first, n_frames = t_start, t_end - t_start + 1
    elif h_last == 65535:
        long_frames = _scalar(point, "LONG_FRAMES")
        if long_frames and long_frames > n_frames:
            n_frames = int(long_frames)

    word_bytes = 4 if is_float else 2
    stride_words = 4 * n_points + n_analog_per_frame
    frame_bytes = stride_words * word_bytes
    dstart = (data_block - 1) * _BLOCK
    available = max(0, len(data) - dstart)
    if frame_bytes:
        n_frames = min(n_frames, available // frame_bytes)
    else:
        n_frames = 0

    if n_points == 0:
        raise _C3DProblem("holds no 3D points")
    if n_frames == 0:
        raise _C3DProblem("holds no frames of 3D data (is the file truncated?)")
    raw = np.frombuffer(
        data, dtype=np.uint8, count=n_frames * frame_bytes, offset=min(dstart, len(data))
    )
    if is_float:
        if proc == _DEC:
            flat = _dec_to_ieee(raw.view("<u4"))
        else:
            flat = raw.view(">f4" if proc == _MIPS else "<f4")
    else:
        flat = raw.view(">i2" if proc == _MIPS else "<i2")
    frames = flat.reshape(n_frames, stride_words)
    pts = frames[:, : 4 * n_points].reshape(n_frames, n_points, 4)

    if is_float:
        w = np.nan_to_num(pts[..., 3].astype(np.float64), nan=-1.0, posinf=-1.0, neginf=-1.0)
        w = np.clip(w, -(2.0**31), 2.0**31 - 1).astype(np.int64)
        xyz = pts[..., :3].astype(np.float64)
    else:
        w = pts[..., 3].astype(np.int64)
        xyz = pts[..., :3].astype(np.float64) * scale
    w = ((w & 0xFFFF) ^ 0x8000) - 0x8000  # wrap to int16: 65535.0 -> -1 (vendor sentinel)
    valid = (w >= 0) & np.isfinite(xyz).all(axis=2)

    units = point.get("UNITS", "mm")
    units = units if isinstance(units, str) else (units[0] if units else "mm")
    to_mm = _UNIT_TO_MM.get(units.strip().lower(), 1.0)
    qscale = abs(scale) * to_mm
    positions = np.where(valid[..., None], xyz * to_mm, np.nan)
    residuals = np.where(valid, (w & 0xFF) * qscale, np.nan)
    bits = np.where(valid, (w >> 8) & 0x7F, 0).astype(np.uint8)
    camera_mask = np.unpackbits(bits[..., None], axis=-1, bitorder="little")[..., :7].astype(bool)
    processed = valid & (w == 0)

    labels = _strings(point, "LABELS")
    descriptions = _strings(point, "DESCRIPTIONS")
    labels = (labels + [f"point{i + 1}" for i in range(len(labels), n_points)])[:n_points]
    descriptions = (descriptions + [""] * n_points)[:n_points]

    cara = groups.get("CARAPOST", {})
    full = None
    if cara.get("MASK_LAYOUT") == "WORD4+ANALOG" and n_analog_per_frame >= n_points:
        n_cams = int(_scalar(cara, "CAMERA_COUNT") or 16)
        first_ch = int(_scalar(cara, "MASK_ANALOG_FIRST") or 1) - 1
        ana = frames[:, 4 * n_points + first_ch : 4 * n_points + first_ch + n_points]
        ana = np.rint(ana.astype(np.float64)).astype(np.int64) & 0xFFFF
        full = ((ana[..., None] >> np.arange(n_cams)) & 1).astype(bool)
        full &= valid[..., None]

    vbits = bits[valid]
    if "CARAPOST" in groups:
        has_masks = bool(int(_scalar(cara, "CAMERA_COUNT") or 0) > 0 and vbits.any())
    else:
        has_masks = bool(vbits.any() and np.unique(vbits).size > 1)
    tc_start = cara.get("START_TIMECODE")
    return C3DData(
        positions=positions,
        residuals=residuals,
        camera_mask=camera_mask,
        processed=processed,
        labels=labels,
        descriptions=descriptions,
        rate=float(rate),
        first_frame=int(first),
        units=units,
        scale=float(scale),
        has_camera_masks=has_masks,
        camera_mask_full=full,
        camera_names=_strings(cara, "CAMERA_NAMES"),
        timecode_start=tc_start if isinstance(tc_start, str) else None,
        timecode_rate=_scalar(cara, "TIMECODE_RATE"),
        groups=groups,
    )

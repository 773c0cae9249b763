"""C3D reader: Intel, DEC or MIPS files, integer or float data, parsed leniently."""

from __future__ import annotations

import math
import os
import struct
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from carapost.io.atomic import check_input_file
from carapost.io.c3d._format import BLOCK, BYTE, CHAR, DEC, FLOAT, INT, INTEL, MIPS, C3DData
from carapost.io.errors import CaraFileError, unexpected_error

__all__ = ["read_c3d"]

_UNIT_TO_MM = {"mm": 1.0, "m": 1000.0, "cm": 10.0, "um": 1e-3}


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
    if ptype == CHAR:
        if len(dims) <= 1:
            return _text(raw)
        width = dims[0]
        # Python integers: np.prod wraps around in int64 for 255-dimension garbage
        n = math.prod(dims[1:]) if width else 0
        if n * width > len(raw):
            raise ValueError("a text parameter is longer than its data")
        return [_text(raw[i * width : (i + 1) * width]) for i in range(n)]
    big = proc == MIPS
    if ptype == BYTE:
        arr = np.frombuffer(raw, dtype=np.int8)
    elif ptype == INT:
        arr = np.frombuffer(raw, dtype=">i2" if big else "<i2").astype(np.int16)
    elif ptype == FLOAT:
        if proc == DEC:
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
            # math.prod: exact Python integers (np.prod overflowed int64 for many large
            # dimensions, passed the bounds check and then looped ~1e18 times)
            nbytes = abs(ptype) * math.prod(dims) if dims else abs(ptype)
            dstart = body + 2 + ndims
            if ptype not in (CHAR, BYTE, INT, FLOAT) or dstart + nbytes > len(buf.data):
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
        if isinstance(v, str):
            out.append(v)
        elif isinstance(v, list):
            out.extend(str(x) for x in v)
        else:  # a number where text was expected: not labels
            break
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
    check_input_file(p)
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
    except MemoryError:
        raise CaraFileError(p, "is too large to read (out of memory)") from None
    except Exception as exc:
        raise unexpected_error(p, "is not a readable C3D file", exc) from exc


class _C3DProblem(Exception):
    pass


def _read_c3d_bytes(data: bytes) -> C3DData:
    if len(data) < BLOCK or data[1] != 0x50:
        raise _C3DProblem("is not a C3D file (no C3D header key)")
    pblock = data[0]
    pstart = (pblock - 1) * BLOCK
    if pblock < 1 or pstart + 4 > len(data):
        raise _C3DProblem("is not a C3D file (bad parameter section pointer)")
    n_pblocks, proc = data[pstart + 2], data[pstart + 3]
    if proc not in (INTEL, DEC, MIPS):
        raise _C3DProblem(f"has an unknown processor type {proc}")
    buf = _Bytes(data, ">" if proc == MIPS else "<")
    (n_points, n_analog_per_frame, h_first, h_last, _gap) = buf.unpack("HHHHH", 2)
    (data_block,) = buf.unpack("H", 16)
    (analog_per_frame,) = buf.unpack("H", 18)
    if proc == DEC:
        h_scale = float(_dec_to_ieee(np.frombuffer(data[12:16], "<u4"))[0])
        h_rate = float(_dec_to_ieee(np.frombuffer(data[20:24], "<u4"))[0])
    else:
        h_scale = buf.unpack("f", 12)[0]
        h_rate = buf.unpack("f", 20)[0]
    pend = pstart + max(n_pblocks, 1) * BLOCK
    if data_block > pblock:
        pend = max(pend, min((data_block - 1) * BLOCK, len(data)))
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
    dstart = (data_block - 1) * BLOCK
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
        if proc == DEC:
            flat = _dec_to_ieee(raw.view("<u4"))
        else:
            flat = raw.view(">f4" if proc == MIPS else "<f4")
    else:
        flat = raw.view(">i2" if proc == MIPS else "<i2")
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

"""C3D writer: float-format, Intel files written in chunks of frames."""

from __future__ import annotations

import os
import re
import struct
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from carapost import __version__
from carapost.io.atomic import atomic_output
from carapost.io.c3d._format import BLOCK, FLOAT, INT, INTEL, NAME_RE
from carapost.io.c3d._params import (
    Param,
    char_param,
    chunked_char,
    chunked_num,
    encode_parameters,
    num_param,
    value_param,
)

__all__ = ["choose_residual_scale", "write_c3d"]

# Nice residual quanta (mm); the smallest one whose 255 steps cover the largest residual wins.
_SCALE_LADDER = tuple(m * 10.0**e for e in range(-3, 3) for m in (1.0, 2.0, 5.0))
_FRAMES_PER_CHUNK = 2048
_TIMECODE_RE = re.compile(r"^\d{2}:\d{2}:\d{2}[:;.]\d{2,3}$")


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
        num_param("USED", n_points, "Number of points", INT),
        num_param("FRAMES", min(n_frames, 65535), "Number of frames", INT),
        num_param("DATA_START", 0, "First block of the data section", INT),  # patched below
        num_param("SCALE", scale32, "Residual quantum (mm); negative = float data", FLOAT),
        num_param("RATE", rate32, "Frame rate (Hz)", FLOAT),
        char_param("UNITS", "mm", "Units of the 3D data"),
        *chunked_char("LABELS", labels, "Point labels"),
        *chunked_char("DESCRIPTIONS", descriptions, "Point descriptions"),
    ]
    if n_frames > 65535:
        point.append(num_param("LONG_FRAMES", np.float32(n_frames), "Number of frames", FLOAT))
    analog = [
        num_param("USED", n_analog, "Number of analog channels", INT),
        num_param("RATE", np.float32(rate if n_analog else 0.0), "Analog rate (Hz)", FLOAT),
    ]
    if n_analog:
        mask_labels = [f"CAMMASK{k + 1}" for k in range(n_points)]
        analog += [
            *chunked_char("LABELS", mask_labels, "Camera mask channels"),
            *chunked_char("DESCRIPTIONS", labels, "Point of each mask channel"),
            *chunked_num("SCALE", np.ones(n_points, np.float32), "", FLOAT),
            *chunked_num("OFFSET", np.zeros(n_points, np.int16), "", INT),
            num_param("GEN_SCALE", np.float32(1.0), "", FLOAT),
            *chunked_char("UNITS", ["mask"] * n_points, ""),
        ]
    force = [num_param("USED", 0, "Number of force plates", INT)]
    trial = [
        num_param("ACTUAL_START_FIELD", [first_frame & 0xFFFF, first_frame >> 16], "", INT),
        num_param("ACTUAL_END_FIELD", [last_frame & 0xFFFF, last_frame >> 16], "", INT),
        num_param("CAMERA_RATE", rate32, "Frame rate (Hz)", FLOAT),
    ]
    company, version = manufacturer
    manu = [
        char_param("COMPANY", str(company)),
        char_param("SOFTWARE", str(company)),
        char_param("VERSION_LABEL", str(version)),
    ]
    cara = [
        char_param("FORMAT_VERSION", "1", "Layout version of this group"),
        num_param("CAMERA_COUNT", n_cams, "Cameras in the contribution mask", INT),
        char_param("MASK_LAYOUT", "WORD4+ANALOG" if full_mask else "WORD4"),
    ]
    if full_mask:
        cara.append(num_param("MASK_ANALOG_FIRST", 1, "1-based first mask channel", INT))
    if camera_names:
        cara += chunked_char("CAMERA_NAMES", camera_names, "bit c of the mask = camera c")
    if timecode_start is not None:
        cara.append(char_param("START_TIMECODE", timecode_start, "Timecode of the first frame"))
    if timecode_rate is not None:
        cara.append(num_param("TIMECODE_RATE", np.float32(timecode_rate), "Hz", FLOAT))
    groups: list[tuple[str, str, list[Param]]] = [
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
        if not NAME_RE.match(gname) or gname in taken:
            raise ValueError(f"extra_groups: invalid or reserved group name {gname!r}")
        taken.add(gname)
        groups.append((gname, "", [value_param(str(k).upper(), v) for k, v in params.items()]))

    section = encode_parameters(groups)
    n_param_blocks = -(-(len(section) + 4) // BLOCK)
    if n_param_blocks > 255:
        raise ValueError("C3D parameter section too large (more than 255 blocks)")
    data_start = 2 + n_param_blocks
    if data_start > 65535:
        raise ValueError("C3D parameter section too large")
    point[2] = num_param("DATA_START", data_start, "First block of the data section", INT)
    section = encode_parameters(groups)  # same length: only the value changed
    param_bytes = struct.pack("<BBBB", 1, 0x50, n_param_blocks, INTEL) + section
    param_bytes = param_bytes.ljust(n_param_blocks * BLOCK, b"\0")

    header = bytearray(BLOCK)
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
        tail = written % BLOCK
        if tail:
            fh.write(b"\0" * (BLOCK - tail))

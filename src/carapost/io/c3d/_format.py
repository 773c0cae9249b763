"""The C3D layout both sides share: block size, processor and parameter type codes, and
the decoded contents of a file (`C3DData`)."""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["BLOCK", "BYTE", "C3DData", "CHAR", "DEC", "FLOAT", "INT", "INTEL", "MIPS",
           "NAME_RE"]

BLOCK = 512
INTEL, DEC, MIPS = 84, 85, 86
CHAR, BYTE, INT, FLOAT = -1, 1, 2, 4
NAME_RE = re.compile(r"^[A-Z0-9_]{1,127}$")


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

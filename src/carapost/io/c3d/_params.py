"""C3D parameter section: building parameters and encoding groups of them (writer side)."""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from carapost.io.c3d._format import BYTE, CHAR, FLOAT, INT, NAME_RE

__all__ = ["Param", "char_param", "chunked_char", "chunked_num", "encode_parameters",
           "num_param", "value_param"]


@dataclass
class Param:
    name: str
    ptype: int
    dims: tuple[int, ...]
    data: bytes
    desc: str = ""


def char_param(name: str, value: str | Sequence[str], desc: str = "") -> Param:
    if isinstance(value, str):
        raw = value.encode("utf-8")
        if len(raw) > 255:
            raise ValueError(f"C3D parameter {name}: text longer than 255 bytes")
        return Param(name, CHAR, (len(raw),) if raw else (0,), raw, desc)
    items = [str(v).encode("utf-8") for v in value]
    width = max((len(b) for b in items), default=0)
    width = max(width, 1)
    if width > 255 or len(items) > 255:
        raise ValueError(f"C3D parameter {name}: at most 255 strings of at most 255 bytes")
    raw = b"".join(b.ljust(width) for b in items)
    return Param(name, CHAR, (width, len(items)), raw, desc)


def num_param(name: str, value: Any, desc: str = "", ptype: int | None = None) -> Param:
    arr = np.asarray(value)
    if ptype is None:
        if arr.dtype == bool:
            ptype = BYTE
        elif np.issubdtype(arr.dtype, np.integer):
            ptype = INT
        elif np.issubdtype(arr.dtype, np.floating):
            ptype = FLOAT
        else:
            raise ValueError(f"C3D parameter {name}: unsupported value type {arr.dtype}")
    if ptype == INT:
        if arr.size and (arr.min() < -32768 or arr.max() > 65535):
            raise ValueError(f"C3D parameter {name}: integers must fit in 16 bits")
        data = arr.astype(np.int64).astype("<u2" if arr.size and arr.max() > 32767 else "<i2")
    elif ptype == BYTE:
        data = arr.astype("<i1")
    else:
        data = arr.astype("<f4")
    if any(d > 255 for d in arr.shape) or arr.ndim > 7:
        raise ValueError(f"C3D parameter {name}: each dimension must be at most 255")
    # C3D lists dimensions fastest-first; numpy C order is slowest-first.
    return Param(name, ptype, tuple(arr.shape[::-1]), data.tobytes(), desc)


def value_param(name: str, value: Any) -> Param:
    """A parameter from a Python value (str, list of str, number, array)."""
    if not NAME_RE.match(name):
        raise ValueError(f"C3D parameter name {name!r}: use 1-127 characters A-Z, 0-9, _")
    if isinstance(value, str):
        return char_param(name, value)
    if isinstance(value, Sequence) and value and all(isinstance(v, str) for v in value):
        return char_param(name, list(value))
    arr = np.asarray(value)
    if arr.dtype.kind in "US":
        return char_param(name, [str(v) for v in arr.ravel()])
    return num_param(name, arr)


def chunked_char(name: str, values: Sequence[str], desc: str) -> list[Param]:
    """``NAME``, ``NAME2``, ``NAME3``, ... for more than 255 strings (C3D convention)."""
    width = max([len(v.encode("utf-8")) for v in values] + [1])
    per = max(1, min(255, 32000 // width))
    chunks = [values[i : i + per] for i in range(0, len(values), per)] or [[]]
    out = []
    for k, chunk in enumerate(chunks):
        pname = name if k == 0 else f"{name}{k + 1}"
        if chunk:
            out.append(char_param(pname, list(chunk), desc))
        else:
            out.append(Param(pname, CHAR, (1, 0), b"", desc))
    return out


def chunked_num(name: str, values: np.ndarray, desc: str, ptype: int) -> list[Param]:
    chunks = [values[i : i + 255] for i in range(0, len(values), 255)] or [values[:0]]
    return [
        num_param(name if k == 0 else f"{name}{k + 1}", c, desc, ptype)
        for k, c in enumerate(chunks)
    ]


def encode_parameters(groups: list[tuple[str, str, list[Param]]]) -> bytes:
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

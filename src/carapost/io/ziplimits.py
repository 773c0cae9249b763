"""Checked reads of ZIP containers and JSON from untrusted files.

Every size a file declares is checked before anything is allocated or inflated: a
member flagged encrypted or compressed with a method other than stored/deflate is
refused, a deflated member may not claim to inflate to more than `MAX_RATIO` times its
compressed size (beyond a small allowance), and reads are bounded by the limit whatever
the header says. JSON nesting is bounded (`MAX_JSON_DEPTH`). Every failure is a
`CaraFileError` naming the file and the member.
"""

from __future__ import annotations

import io
import json
import re
import zipfile
import zlib
from pathlib import Path
from typing import Any

import numpy as np

from carapost.io.errors import CaraFileError

__all__ = ["MANIFEST_LIMIT", "MAX_JSON_DEPTH", "MAX_RATIO", "check_member", "load_json",
           "npy_spec", "parse_npy_header",
           "open_zip", "read_member"]

#: Largest ``manifest.json`` accepted (bytes, inflated).
MANIFEST_LIMIT = 64 << 20
#: Largest inflate ratio of a deflated member bigger than `SMALL_MEMBER`. Deflate
#: cannot exceed ~1032:1; real project arrays stay far below 100:1 except when blank.
MAX_RATIO = 100
#: Deflated members up to this size (bytes) may have any ratio.
SMALL_MEMBER = 64 << 20
#: Deepest JSON nesting accepted (a project manifest needs 5).
MAX_JSON_DEPTH = 64

_METHODS = {zipfile.ZIP_STORED: "stored", zipfile.ZIP_DEFLATED: "deflate"}


def open_zip(path: Path, what: str = "not a carapost project") -> zipfile.ZipFile:
    """Open ``path`` as a ZIP container; every failure is a `CaraFileError`."""
    try:
        return zipfile.ZipFile(path, "r")
    except zipfile.BadZipFile:
        raise CaraFileError(path, f"{what} (not a ZIP container, or truncated)") from None
    except OSError as exc:
        raise CaraFileError(path, f"cannot be read: {exc.strerror or exc}") from None
    except Exception as exc:
        raise CaraFileError(path, f"{what} (its ZIP directory is damaged: {exc})") from None


def check_member(path: Path, info: zipfile.ZipInfo, limit: int) -> None:
    """Refuse a member that is encrypted, oddly compressed or too large, before reading it.

    Parameters
    ----------
    path : Path
        The container (for the message).
    info : ZipInfo
        The member's central-directory entry.
    limit : int
        Largest inflated size accepted (bytes).
    """
    name = info.filename
    if info.flag_bits & 0x1:
        raise CaraFileError(path, f"the member {name} is encrypted; carapost projects never "
                                  "are")
    if info.compress_type not in _METHODS:
        raise CaraFileError(path, f"the member {name} is compressed with method "
                                  f"{info.compress_type}, which carapost does not read "
                                  "(only stored and deflate)")
    if info.file_size > limit:
        raise CaraFileError(path, f"the member {name} claims {info.file_size:,} bytes, more "
                                  f"than the {limit:,} bytes it may have")
    if info.compress_type == zipfile.ZIP_STORED and info.compress_size != info.file_size:
        raise CaraFileError(path, f"the member {name} is damaged (stored sizes differ)")
    if (info.compress_type == zipfile.ZIP_DEFLATED and info.file_size > SMALL_MEMBER
            and info.file_size > MAX_RATIO * max(info.compress_size, 1)):
        raise CaraFileError(
            path, f"the member {name} would inflate {info.compress_size:,} bytes to "
                  f"{info.file_size:,} (more than {MAX_RATIO}:1): refused as a ZIP bomb")


def read_member(zf: zipfile.ZipFile, path: Path, name: str, limit: int) -> bytes:
    """The bytes of member ``name``, at most ``limit`` of them, CRC checked.

    Raises
    ------
    CaraFileError
        Missing, encrypted, unknown method, too large (declared or actual), damaged.
    """
    try:
        info = zf.getinfo(name)
    except KeyError:
        raise CaraFileError(path, f"the member {name} is missing") from None
    check_member(path, info, limit)
    try:
        with zf.open(info) as fh:
            # never more than the header declares: a lying header cannot make us inflate
            # further than that (zipfile then finds the CRC-32 wrong)
            data = fh.read(info.file_size + 1)
            if len(data) > info.file_size:
                raise CaraFileError(path, f"the member {name} is longer than its header says")
            fh.read(1)  # at the end: lets zipfile compare the CRC-32
    except CaraFileError:
        raise
    except (zipfile.BadZipFile, zlib.error, EOFError, OSError, ValueError,
            NotImplementedError, RuntimeError) as exc:
        raise CaraFileError(path, f"the member {name} is damaged ({exc})") from None
    return data


def _depth(text: str) -> int:
    """Deepest bracket nesting of JSON ``text`` (brackets inside strings ignored)."""
    depth = deepest = 0
    for tok in re.finditer(r'"(?:[^"\\]|\\.)*"|[\[\]{}]', text):
        ch = tok.group(0)
        if ch in "[{":
            depth += 1
            deepest = max(deepest, depth)
        elif ch in "]}":
            depth -= 1
    return deepest


def load_json(path: Path, raw: bytes | str, what: str, *, max_depth: int = MAX_JSON_DEPTH
              ) -> Any:
    """Parse JSON ``raw`` with its nesting bounded; `CaraFileError` names ``what``.

    ``what`` names the document in messages (empty: the file itself).

    Examples
    --------
    >>> load_json(Path("x.json"), b'{"a": [1, 2]}', "x.json")
    {'a': [1, 2]}
    >>> load_json(Path("x.json"), b"[" * 100 + b"]" * 100, "x.json")
    Traceback (most recent call last):
    ...
    carapost.io.errors.CaraFileError: x.json: x.json is nested more than 64 levels deep
    """
    lead = f"{what} " if what else ""
    try:
        text = raw.decode("utf-8-sig") if isinstance(raw, bytes) else raw
    except UnicodeDecodeError as exc:
        raise CaraFileError(path, f"{lead}is not UTF-8 text ({exc})") from None
    if _depth(text) > max_depth:
        raise CaraFileError(path, f"{lead}is nested more than {max_depth} levels deep")
    try:
        return json.loads(text)
    except RecursionError:
        raise CaraFileError(path, f"{lead}is nested too deeply") from None
    except ValueError as exc:
        raise CaraFileError(path, f"{lead}is not valid JSON ({exc})") from None


def npy_spec(path: Path, name: str, spec: Any) -> tuple[tuple[int, ...], np.dtype[Any]]:
    """Shape and dtype the manifest gives a member, checked to be plain and sane."""
    try:
        shape = tuple(int(n) for n in spec["shape"])
        dtype = np.dtype(str(spec["dtype"]))
    except Exception:
        raise CaraFileError(path, f"the manifest's entry for {name} is malformed") from None
    if any(n < 0 for n in shape) or dtype.hasobject or dtype.itemsize == 0 or len(shape) > 8:
        raise CaraFileError(path, f"the manifest's entry for {name} is malformed")
    return shape, dtype


def parse_npy_header(raw: bytes | io.BufferedIOBase) -> tuple[tuple[int, ...], np.dtype[Any], int]:
    """Shape, dtype and header length of an ``.npy`` stream (no pickles, no Fortran)."""
    buf = io.BytesIO(raw) if isinstance(raw, bytes) else raw
    try:
        version = np.lib.format.read_magic(buf)
        if version == (1, 0):
            shape, fortran, dtype = np.lib.format.read_array_header_1_0(buf)
        elif version == (2, 0):
            shape, fortran, dtype = np.lib.format.read_array_header_2_0(buf)
        else:
            raise ValueError(f"unsupported .npy version {version}")
    except Exception as exc:  # numpy's parser raises tokenize and syntax errors too
        raise ValueError(f"its .npy header is malformed: {exc}") from None
    if dtype.hasobject or fortran:
        raise ValueError("object or Fortran-ordered arrays are not allowed")
    return tuple(shape), dtype, buf.tell()

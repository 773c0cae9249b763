"""Atomic file output: every writer of carapost goes through here.

A file is written to a temporary file in the destination folder, flushed to disk with
fsync, and renamed over the destination (then the folder is fsynced so the rename
itself survives a crash). On any failure the temporary file is removed and the
destination is left as it was, so no reader ever sees a half-written file.
"""

from __future__ import annotations

import os
import secrets
import stat
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import BinaryIO

from carapost.io.errors import CaraFileError


def _fsync_folder(folder: Path) -> None:
    """Make a rename durable (POSIX; a no-op where folders cannot be opened)."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def check_output_path(path: str | os.PathLike[str]) -> Path:
    """Check that a file can be written at ``path``, before any work is done for it.

    Raises
    ------
    CaraFileError
        When ``path`` is a folder or its folder does not exist.
    """
    target = Path(path)
    if target.is_dir():
        raise CaraFileError(target, "is a folder, not a file name")
    if not target.parent.is_dir():
        raise CaraFileError(target, f"the folder {target.parent} does not exist")
    return target


@contextmanager
def atomic_output(path: str | os.PathLike[str]) -> Iterator[BinaryIO]:
    """Open a temporary binary file beside ``path``; on success it replaces ``path``.

    The new file gets the permissions of the file it replaces (or the umask's for a new
    file). ``OSError`` becomes :class:`CaraFileError` naming ``path``; any exception
    leaves ``path`` untouched and removes the temporary file.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> target = pathlib.Path(tempfile.mkdtemp()) / "out.bin"
    >>> with atomic_output(target) as fh:
    ...     _ = fh.write(b"data")
    >>> target.read_bytes()
    b'data'
    """
    target = check_output_path(path)
    folder = target.parent
    tmp = folder / f".{target.name}.{secrets.token_hex(6)}.part"
    try:
        # os.open with 0o666 honours the umask (mkstemp would make the file 0600)
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    except OSError as exc:
        raise CaraFileError(target, f"cannot create a file in {folder}: {exc}") from exc
    try:
        with os.fdopen(fd, "wb") as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        with suppress(FileNotFoundError):
            os.chmod(tmp, stat.S_IMODE(target.stat().st_mode))
        os.replace(tmp, target)
        _fsync_folder(folder)
    except BaseException as exc:
        with suppress(OSError):
            os.unlink(tmp)
        if isinstance(exc, OSError):
            raise CaraFileError(target, f"could not be written: {exc.strerror or exc}") from exc
        raise


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (see :func:`atomic_output`)."""
    with atomic_output(path) as fh:
        fh.write(data)

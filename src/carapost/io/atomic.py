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
import time
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


#: A ``.part`` file of ours older than this is stale even where locks cannot be taken.
STALE_PART_AGE_S = 24 * 3600.0

_NAME_MAX = 255


def checked_path(path: str | os.PathLike[str]) -> Path:
    """``path`` as a Path, with the problems no system call should see refused first."""
    try:
        text = os.fspath(path)
    except TypeError:
        raise CaraFileError(str(path), "is not a file name") from None
    if isinstance(text, bytes):
        text = os.fsdecode(text)
    if not text.strip():
        raise CaraFileError(repr(text), "the file name is empty")
    if "\0" in text:
        raise CaraFileError(text.replace("\0", "\\0"), "the file name contains a NUL "
                            "character")
    return Path(text)


def check_input_file(path: Path) -> None:
    """Refuse, before opening it, a path that is not a readable regular file.

    A FIFO, socket or device would block or never end; a folder is not a file.

    Raises
    ------
    CaraFileError
        Naming ``path``: missing, a folder, not a regular file, or not readable.
    """
    path = checked_path(path)
    try:
        st = path.stat()
    except FileNotFoundError:
        raise CaraFileError(path, "cannot be read: no such file") from None
    except OSError as exc:
        raise CaraFileError(path, f"cannot be read: {exc.strerror or exc}") from None
    if stat.S_ISDIR(st.st_mode):
        raise CaraFileError(path, "is a folder, not a file")
    if not stat.S_ISREG(st.st_mode):
        raise CaraFileError(path, "is not a regular file (a pipe, socket or device)")


def check_output_path(path: str | os.PathLike[str]) -> Path:
    """Check that a file can be written at ``path``, before any work is done for it.

    A symbolic link is followed: the file it points to is the one written.

    Raises
    ------
    CaraFileError
        When ``path`` is empty, holds a NUL, is a folder, has a name too long for the
        file system, or its folder does not exist.
    """
    target = checked_path(path)
    try:
        if target.is_symlink():
            target = Path(os.path.realpath(target))
        if target.is_dir():
            raise CaraFileError(target, "is a folder, not a file name")
        if not target.parent.is_dir():
            raise CaraFileError(target, f"the folder {target.parent} does not exist")
    except OSError as exc:
        raise CaraFileError(target, f"cannot be written: {exc.strerror or exc}") from None
    limit = _name_max(target.parent)
    if len(os.fsencode(target.name)) > limit:
        raise CaraFileError(target, f"the file name is longer than the {limit} bytes the "
                                    "file system allows")
    return target


def _name_max(folder: Path) -> int:
    try:
        return int(os.pathconf(folder, "PC_NAME_MAX"))
    except (OSError, ValueError, AttributeError):
        return _NAME_MAX


def _part_prefix(target: Path) -> str:
    """Start of the names of our temporary files for ``target`` (fits NAME_MAX)."""
    room = _name_max(target.parent) - len(".") - len(".0123456789ab.part")
    name = target.name
    raw = os.fsencode(name)
    if len(raw) > room:
        name = raw[:room].decode("utf-8", "ignore")  # a cut multibyte char is dropped
        while len(os.fsencode(name)) > room:
            name = name[:-1]
    return f".{name}."


def _is_ours(entry: str, prefix: str) -> bool:
    rest = entry[len(prefix):]
    return (entry.startswith(prefix) and len(rest) == 17 and rest.endswith(".part")
            and all(c in "0123456789abcdef" for c in rest[:12]))


def clean_stale_parts(path: str | os.PathLike[str]) -> list[Path]:
    """Remove temporary files that an interrupted save of ``path`` left behind.

    Only our own names (``.<name>.<12 hex>.part``) are considered, and only those no
    live writer holds: a writer keeps an exclusive lock on its file while it writes, so
    a file whose lock can be taken belongs to a save that died (killed, power cut).
    Where locks are not available, files older than `STALE_PART_AGE_S` are removed.

    Returns
    -------
    list of Path
        The files removed.
    """
    try:
        target = Path(os.path.realpath(checked_path(path)))
        folder = target.parent
        prefix = _part_prefix(target)
        entries = [e for e in os.listdir(folder) if _is_ours(e, prefix)]
    except (OSError, CaraFileError):
        return []
    removed = []
    for entry in entries:
        part = folder / entry
        try:
            if _held_by_writer(part):
                continue
            os.unlink(part)
            removed.append(part)
        except OSError:
            continue
    return removed


def _held_by_writer(part: Path) -> bool:
    try:
        import fcntl
    except ImportError:  # no flock: fall back on the age of the file
        return time.time() - part.stat().st_mtime < STALE_PART_AGE_S
    fd = os.open(part, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        return True
    finally:
        os.close(fd)  # closing releases the lock we may have taken
    return False


def _lock(fd: int) -> None:
    try:
        import fcntl

        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except (ImportError, OSError):
        pass


@contextmanager
def atomic_output(path: str | os.PathLike[str]) -> Iterator[BinaryIO]:
    """Open a temporary binary file beside ``path``; on success it replaces ``path``.

    The new file gets the permissions of the file it replaces (or the umask's for a new
    file); a symbolic link at ``path`` keeps pointing at the file it names, which is the
    one replaced. ``OSError`` becomes :class:`CaraFileError` naming ``path``; any
    exception leaves ``path`` untouched and removes the temporary file. The temporary
    file is locked while it is written, so that `clean_stale_parts` (run here first)
    removes only the leftovers of saves that died.

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
    clean_stale_parts(target)
    tmp = folder / f"{_part_prefix(target)}{secrets.token_hex(6)}.part"
    try:
        # os.open with 0o666 honours the umask (mkstemp would make the file 0600)
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    except OSError as exc:
        raise CaraFileError(target, f"cannot create a file in {folder}: "
                                    f"{exc.strerror or exc}") from exc
    _lock(fd)
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

"""Marker label lists: ``.txt`` label files and the labels of a ``.cara`` project.

A label file holds label names separated by whitespace, one or several per line; a name
cannot contain a space. Importing labels adds to the labels a project already has: a
name that is already taken gets ``" - Copy"`` appended, then ``" - Copy (2)"``, ...
(see `merge_labels`).
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Sequence
from pathlib import Path

from carapost.io.atomic import atomic_write_bytes, check_input_file
from carapost.io.errors import CaraFileError
from carapost.io.ziplimits import MANIFEST_LIMIT, load_json, open_zip, read_member

__all__ = ["COPY_SUFFIX", "merge_labels", "read_label_file", "read_labels_from_cara",
           "unique_names", "write_label_file"]

#: Appended to an imported label whose name is already taken.
COPY_SUFFIX = " - Copy"


def read_label_file(path: str | os.PathLike[str]) -> list[str]:
    """Read the label names of a ``.txt`` label file.

    Parameters
    ----------
    path : str or PathLike
        A text file of whitespace-separated names (any number per line, blank lines
        ignored). UTF-8 (with or without BOM) is expected; other bytes are read as
        Latin-1 so that files from older Windows tools still load.

    Returns
    -------
    list of str
        The names in file order, repeats included (`merge_labels` renames them).

    Raises
    ------
    CaraFileError
        If the file cannot be read or is binary.
    """
    path = Path(path)
    check_input_file(path)  # a FIFO would block the read
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise CaraFileError(path, f"cannot be read ({exc.strerror or exc})") from exc
    if b"\x00" in data:
        raise CaraFileError(path, "is not a text label file (it contains binary data)")
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError:
        text = data.decode("latin-1")
    return text.split()


def merge_labels(existing: Sequence[str], new: Iterable[str]) -> list[str]:
    """Names under which ``new`` labels are added next to ``existing`` ones.

    A name already present in ``existing`` (or earlier in ``new``) gets ``" - Copy"``
    appended; when that is taken too, ``" - Copy (2)"``, ``" - Copy (3)"``, ... (the
    first number that is free). Names stay short and the time is linear in the number
    of names, even for a file that repeats one name thousands of times.

    Parameters
    ----------
    existing : sequence of str
        Labels the project already has (unchanged).
    new : iterable of str
        Labels to add, in order.

    Returns
    -------
    list of str
        One name per entry of ``new``, all distinct from each other and from
        ``existing``.

    Examples
    --------
    >>> merge_labels(["Nose_Tip", "Chin"], ["Chin", "Brow", "Chin", "Chin"])
    ['Chin - Copy', 'Brow', 'Chin - Copy (2)', 'Chin - Copy (3)']
    """
    taken = set(existing)
    # Per name, the copy number tried last: the next repeat starts after it, so n
    # repeats of a name cost O(n) lookups in all.
    copies: dict[str, int] = {}
    out: list[str] = []
    for name in new:
        if name in taken:
            k = copies.get(name, 0)
            candidate = name
            while candidate in taken:
                k += 1
                candidate = name + COPY_SUFFIX + ("" if k == 1 else f" ({k})")
            copies[name] = k
            name = candidate
        taken.add(name)
        out.append(name)
    return out


def unique_names(names: Iterable[str]) -> list[str]:
    """``names`` with repeats made unique: the second ``"A"`` becomes ``"A (2)"``.

    For formats whose names are keys (C3D point labels, XCP camera names). A number is
    added until the name is free, so a name already in the list is never produced twice.

    Examples
    --------
    >>> unique_names(["A", "B", "A", "A (2)", "A"])
    ['A', 'B', 'A (2)', 'A (2) (2)', 'A (3)']
    """
    seen: dict[str, int] = {}
    out = []
    for name in names:
        candidate = name
        while candidate in seen:
            seen[name] += 1
            candidate = f"{name} ({seen[name]})"
        seen[candidate] = 1
        out.append(candidate)
    return out


def read_labels_from_cara(path: str | os.PathLike[str]) -> list[str]:
    """Read the label names stored in a ``.cara`` project.

    A ``.cara`` file is a ZIP container whose ``manifest.json`` lists the labels under
    ``"labels"`` (strings; entries that are objects contribute their ``"name"``).

    Parameters
    ----------
    path : str or PathLike
        The project file.

    Returns
    -------
    list of str
        The labels in project order (empty if the project has none).

    Raises
    ------
    CaraFileError
        If the file is not a ZIP archive, has no readable ``manifest.json``, or its
        labels are not a list of names.
    """
    path = Path(path)
    check_input_file(path)
    with open_zip(path) as zf:
        if "manifest.json" not in zf.NameToInfo:
            raise CaraFileError(path, "is not a carapost project: it has no manifest.json")
        raw = read_member(zf, path, "manifest.json", MANIFEST_LIMIT)
    try:
        manifest = load_json(path, raw, "")
    except CaraFileError as exc:
        raise CaraFileError(path, f"has a damaged manifest.json ({exc.problem})") from None
    if not isinstance(manifest, dict):
        raise CaraFileError(path, "has a damaged manifest.json (not a JSON object)")
    labels = manifest.get("labels", [])
    if not isinstance(labels, list):
        raise CaraFileError(path, "manifest.json: 'labels' is not a list")
    names = []
    for i, entry in enumerate(labels):
        name = entry.get("name") if isinstance(entry, dict) else entry
        if not isinstance(name, str) or not name:
            raise CaraFileError(path, f"manifest.json: label {i} is not a name ({entry!r})")
        names.append(name)
    return names


def write_label_file(path: str | os.PathLike[str], labels: Iterable[str]) -> None:
    """Write label names to a ``.txt`` label file, one per line (UTF-8), atomically.

    Parameters
    ----------
    path : str or PathLike
        Destination.
    labels : iterable of str
        Names; none may be empty or contain whitespace (the file format could not
        read them back).

    Raises
    ------
    ValueError
        If a name is empty or contains whitespace (nothing is written).
    CaraFileError
        If the file cannot be written.
    """
    names = list(labels)
    for name in names:
        if not isinstance(name, str) or not name or len(name.split()) != 1 or name != name.strip():
            raise ValueError(f"label {name!r} cannot be written to a label file: names must "
                             "be non-empty and contain no spaces")
    text = "".join(f"{name}\n" for name in names)
    atomic_write_bytes(path, text.encode("utf-8"))  # not Path(""): "" is refused as empty

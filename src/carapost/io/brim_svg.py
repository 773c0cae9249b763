"""Calibration brim models: the default brims shipped with carapost and custom SVG brims.

Default brims (``resources/brims/brim_v1_0.csv`` ...) are our own geometries of dark
dots on a conical band above the forehead; Vicon's brim geometries are not public, so
these are not them. A custom brim is a flat sheet drawn in an SVG file: every
``<circle>`` and ``<ellipse>`` is a dot, placed on the plane z = 0 of the brim frame in
millimetres (x right, y up: the SVG's y axis, which points down, is flipped).
"""

from __future__ import annotations

import re
from collections import Counter
from importlib import resources
from pathlib import Path

import numpy as np
from lxml import etree
from numpy.typing import NDArray

from carapost.io.atomic import check_input_file
from carapost.io.errors import CaraFileError

__all__ = ["DEFAULT_BRIM_VERSIONS", "default_brim", "read_brim_svg"]

#: Versions of the default brim, as in the Process menu.
DEFAULT_BRIM_VERSIONS = ("v1.0", "v1.1", "v2.0")

#: Millimetres per SVG length unit (CSS absolute units; px = 1/96 in).
_UNITS_MM = {"mm": 1.0, "cm": 10.0, "in": 25.4, "pt": 25.4 / 72.0, "pc": 25.4 / 6.0,
             "px": 25.4 / 96.0, "": 25.4 / 96.0, "q": 0.25}

_LENGTH = re.compile(r"^\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*([a-zA-Z%]*)\s*$")
_TRANSFORM = re.compile(r"(matrix|translate|scale|rotate|skewX|skewY)\s*\(([^)]*)\)")
_NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")


def default_brim(version: str) -> tuple[list[str], NDArray[np.float64]]:
    """The default brim model of a version (``"v1.0"``, ``"v1.1"`` or ``"v2.0"``).

    Returns
    -------
    labels : list of str
    xyz : ndarray, shape (B, 3)
        Dot centres (mm) in the brim (helmet) frame: x actor's left, y up, z forward.

    Raises
    ------
    ValueError
        For an unknown version.
    """
    from carapost.io.take_import import read_brim_csv

    v = version.strip().lower()
    if not v.startswith("v"):
        v = "v" + v
    if v not in DEFAULT_BRIM_VERSIONS:
        raise ValueError(f"unknown default brim {version!r}; versions are "
                         f"{', '.join(DEFAULT_BRIM_VERSIONS)}")
    ref = resources.files("carapost") / "resources" / "brims" / f"brim_{v.replace('.', '_')}.csv"
    with resources.as_file(ref) as path:
        return read_brim_csv(path)


def _length_mm(path: Path, text: str | None, what: str) -> tuple[float, str] | None:
    if text is None:
        return None
    m = _LENGTH.match(text)
    if not m:
        raise CaraFileError(path, f"the {what} {text!r} is not a length")
    unit = m.group(2).lower()
    if unit == "%":
        return None
    if unit not in _UNITS_MM:
        raise CaraFileError(path, f"the {what} {text!r} has an unknown unit {unit!r}")
    return float(m.group(1)), unit


def _parse_transform(path: Path, text: str | None) -> NDArray[np.float64]:
    """3x3 affine matrix of an SVG ``transform`` attribute."""
    M = np.eye(3)
    if not text:
        return M
    pos = 0
    for m in _TRANSFORM.finditer(text):
        if text[pos:m.start()].strip(" ,\t\n"):
            raise CaraFileError(path, f"cannot read the transform {text!r}")
        pos = m.end()
        name = m.group(1)
        v = [float(x) for x in _NUMBER.findall(m.group(2))]
        T = np.eye(3)
        try:
            if name == "matrix":
                a, b, c, d, e, f = v
                T = np.array([[a, c, e], [b, d, f], [0, 0, 1.0]])
            elif name == "translate":
                T[0, 2] = v[0]
                T[1, 2] = v[1] if len(v) > 1 else 0.0
            elif name == "scale":
                T[0, 0] = v[0]
                T[1, 1] = v[1] if len(v) > 1 else v[0]
            elif name == "rotate":
                ang = np.radians(v[0])
                Rm = np.array([[np.cos(ang), -np.sin(ang), 0], [np.sin(ang), np.cos(ang), 0],
                               [0, 0, 1.0]])
                if len(v) == 3:
                    Tp = np.array([[1, 0, v[1]], [0, 1, v[2]], [0, 0, 1.0]])
                    Tm = np.array([[1, 0, -v[1]], [0, 1, -v[2]], [0, 0, 1.0]])
                    Rm = Tp @ Rm @ Tm
                T = Rm
            elif name == "skewX":
                T[0, 1] = np.tan(np.radians(v[0]))
            elif name == "skewY":
                T[1, 0] = np.tan(np.radians(v[0]))
        except (ValueError, IndexError):
            raise CaraFileError(path, f"cannot read the transform {m.group(0)!r}") from None
        M = M @ T
    if text[pos:].strip(" ,\t\n"):
        raise CaraFileError(path, f"cannot read the transform {text!r}")
    return M


def _float_attr(path: Path, el: etree._Element, name: str, default: float | None) -> float:
    v = el.get(name)
    if v is None:
        if default is None:
            raise CaraFileError(path, f"line {el.sourceline}: <{etree.QName(el).localname}> "
                                      f"has no {name}")
        return default
    m = _LENGTH.match(v)
    if not m or m.group(2) not in ("", "px"):
        raise CaraFileError(path, f"line {el.sourceline}: {name}={v!r} is not a number in "
                                  "user units")
    return float(m.group(1))


def read_brim_svg(path: str | Path) -> tuple[list[str], NDArray[np.float64]]:
    """Read a planar calibration brim from an SVG file.

    Every ``<circle>`` and ``<ellipse>`` (in any group, after the ``transform`` of
    itself and its ancestors) is a dot; its label is its ``id`` (``Brim01``, ... when it
    has none). Document units are converted to millimetres with the root's ``width`` /
    ``height`` and ``viewBox``; without a physical width, user units are CSS pixels
    (1/96 in).

    Returns
    -------
    labels : list of str, length B
    xyz : ndarray, shape (B, 3)
        Dot centres (mm) on the plane z = 0, x right, y up.

    Raises
    ------
    CaraFileError
        If the file cannot be read, is not well-formed SVG, has a bad length or
        transform, repeats a label, or holds fewer than 4 dots (the message names the
        file and the problem).
    """
    path = Path(path)
    check_input_file(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise CaraFileError(path, f"cannot be read ({exc.strerror or exc})") from None
    parser = etree.XMLParser(resolve_entities=False, no_network=True, huge_tree=False)
    try:
        root = etree.fromstring(data, parser)
    except etree.XMLSyntaxError as exc:
        raise CaraFileError(path, f"is not a well-formed SVG file ({exc.msg}, line "
                                  f"{exc.lineno})") from None
    if etree.QName(root).localname != "svg":
        raise CaraFileError(path, f"is not an SVG file (root element "
                                  f"<{etree.QName(root).localname}>)")
    # document units -> mm
    vb = root.get("viewBox")
    width = _length_mm(path, root.get("width"), "width")
    height = _length_mm(path, root.get("height"), "height")
    scale_x = scale_y = _UNITS_MM["px"]
    offset = np.zeros(2)
    if vb is not None:
        nums = [float(x) for x in _NUMBER.findall(vb)]
        if len(nums) != 4 or nums[2] <= 0 or nums[3] <= 0:
            raise CaraFileError(path, f"the viewBox {vb!r} is not 'min-x min-y width height'")
        offset = np.array(nums[:2])
        if width is not None:
            scale_x = width[0] * _UNITS_MM[width[1]] / nums[2]
            scale_y = (height[0] * _UNITS_MM[height[1]] / nums[3]) if height else scale_x
        elif height is not None:
            scale_y = height[0] * _UNITS_MM[height[1]] / nums[3]
            scale_x = scale_y
    labels: list[str] = []
    xy: list[NDArray] = []
    # transform of each element to the document, computed once per group: walking every
    # dot's ancestors again was quadratic in the depth of nested groups
    transforms: dict[etree._Element, NDArray[np.float64]] = {}

    def to_document(node: etree._Element) -> NDArray[np.float64]:
        chain = []
        while node is not None and node not in transforms:
            chain.append(node)
            node = node.getparent()
        M = transforms[node] if node is not None else np.eye(3)
        for n in reversed(chain):
            own = _parse_transform(path, n.get("transform")) if isinstance(n.tag, str) \
                else np.eye(3)
            M = M @ own
            transforms[n] = M
        return M

    for el in root.iter():
        if not isinstance(el.tag, str):
            continue
        name = etree.QName(el).localname
        if name not in ("circle", "ellipse"):
            continue
        cx = _float_attr(path, el, "cx", 0.0)
        cy = _float_attr(path, el, "cy", 0.0)
        if name == "circle":
            r = _float_attr(path, el, "r", None)
            rx = ry = r
        else:
            rx = _float_attr(path, el, "rx", None)
            ry = _float_attr(path, el, "ry", None)
        if not (rx > 0 and ry > 0):
            raise CaraFileError(path, f"line {el.sourceline}: a dot must have a positive "
                                      "radius")
        p = to_document(el) @ np.array([cx, cy, 1.0])
        xy.append(p[:2])
        labels.append(el.get("id") or f"Brim{len(labels) + 1:02d}")
    if len(xy) < 4:
        raise CaraFileError(path, f"holds {len(xy)} dot(s) (circle or ellipse elements); a "
                                  "brim needs at least 4")
    if len(set(labels)) != len(labels):
        dup = sorted(lab for lab, n in Counter(labels).items() if n > 1)[:20]
        raise CaraFileError(path, f"dot labels (id attributes) repeat: {', '.join(dup)}")
    if any(" " in lab for lab in labels):
        raise CaraFileError(path, "a dot label (id) contains a space")
    P = np.array(xy)
    xyz = np.zeros((len(P), 3))
    xyz[:, 0] = (P[:, 0] - offset[0]) * scale_x
    xyz[:, 1] = -(P[:, 1] - offset[1]) * scale_y
    if not np.all(np.isfinite(xyz)):
        raise CaraFileError(path, "a dot position is not a finite number")
    return labels, xyz

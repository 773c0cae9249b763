"""Vicon ``.xcp`` camera calibration files: import and export.

An XCP file is XML: a ``<Cameras>`` root holding one ``<Camera>`` per device, each with
a ``<KeyFrames>`` list. Every ``<KeyFrame>`` carries the calibration valid from its
``FRAME`` until the next KeyFrame's (run-length encoding; static cameras have one).

Conventions (verified on real Nexus/Tracker files, see ``docs/file-formats.md``):

- ``ORIENTATION`` is the quaternion ``qx qy qz qw`` (real part last) of the world->camera
  rotation ``R``.
- ``POSITION`` is the camera centre ``C`` in world millimetres, so ``t = -R C`` and
  ``x_cam = R X + t``; the camera looks down +z.
- Distortion is either ``VICON_RADIAL="w0 w1"`` (centre = principal point) or
  ``VICON_RADIAL2="Vicon3Parameter cx cy k1 k2 k3"`` (own centre); see
  `carapost.algorithms.camera`.

Everything this module does not interpret (unknown attributes of the root, cameras and
KeyFrames, child elements such as ``ThresholdGrid`` or ``Capture``) is kept in
`XcpCalibration.extras` as plain JSON-compatible data and written back on export.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from lxml import etree
from numpy.typing import ArrayLike, NDArray

from carapost.algorithms.camera import (
    VICON_RADIAL,
    VICON_RADIAL2,
    CameraIntrinsics,
    matrix_to_quaternion,
    quaternion_to_matrix,
)
from carapost.io.atomic import atomic_write_bytes, check_input_file
from carapost.io.errors import CaraFileError
from carapost.io.labels import unique_names

__all__ = ["XcpCalibration", "read_xcp", "write_xcp"]

#: Quaternions whose norm differs from 1 by more than this are rejected; closer ones are
#: normalised (real files are unit to ~1e-15; hand-edited or truncated ones to ~1e-8).
QUATERNION_NORM_TOL = 1e-3

_EXTRAS_VERSION = 1
_KEYFRAMES_SLOT = "__KEYFRAMES__"

#: Largest KeyFrame ``FRAME`` accepted (a frame index; 2^31 - 1).
MAX_FRAME = 2**31 - 1
_VICON3 = "Vicon3Parameter"
# Attributes this module reads and rewrites; everything else is carried in extras.
_CAMERA_KNOWN = {"PIXEL_ASPECT_RATIO", "SENSOR_SIZE", "SKEW"}
_KEYFRAME_KNOWN = {
    "FRAME", "FOCAL_LENGTH", "PRINCIPAL_POINT", "ORIENTATION", "POSITION",
    "VICON_RADIAL", "VICON_RADIAL2", "IMAGE_ERROR",
}


@dataclass
class XcpCalibration:
    """Calibration of ``C`` cameras as read from (or to be written to) an XCP file.

    Attributes
    ----------
    intrinsics : CameraIntrinsics
        Per-camera intrinsics (from each camera's first KeyFrame).
    keyframes : list of ndarray of int64, each shape (K_c,)
        Per camera, the sorted ``FRAME`` values of its KeyFrames: the first frame at
        which each KeyFrame is valid.
    R : list of ndarray, each shape (K_c, 3, 3)
        Per camera and KeyFrame, the world->camera rotation.
    t : list of ndarray, each shape (K_c, 3)
        Per camera and KeyFrame, the translation (mm), ``x_cam = R X + t``.
    image_error : list of ndarray, each shape (K_c,)
        Per camera and KeyFrame, ``IMAGE_ERROR`` (px; 0 where absent).
    extras : Any
        Opaque, JSON-compatible record of what the file held that is not modelled here
        (root attributes, unknown camera/KeyFrame attributes, child elements). ``None``
        for a calibration built from arrays.
    notes : list of str
        Things worth telling the user about the import (e.g. intrinsics that vary
        between KeyFrames, of which only the first is used). Empty for clean files.
    """

    intrinsics: CameraIntrinsics
    keyframes: list[NDArray[np.int64]]
    R: list[NDArray[np.float64]]
    t: list[NDArray[np.float64]]
    image_error: list[NDArray[np.float64]]
    extras: Any = None
    notes: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        n = self.intrinsics.n_cameras
        lists = {"keyframes": self.keyframes, "R": self.R, "t": self.t,
                 "image_error": self.image_error}
        for name, value in lists.items():
            if len(value) != n:
                raise ValueError(f"XcpCalibration.{name} needs one entry per camera ({n}), "
                                 f"got {len(value)}")
        # New lists, so the caller's lists are not modified in place.
        self.keyframes = [np.asarray(k, dtype=np.int64).reshape(-1) for k in self.keyframes]
        self.R, self.t, self.image_error = list(self.R), list(self.t), list(self.image_error)
        for c in range(n):
            k = self.keyframes[c].shape[0]
            self.R[c] = np.asarray(self.R[c], dtype=np.float64).reshape(k, 3, 3)
            self.t[c] = np.asarray(self.t[c], dtype=np.float64).reshape(k, 3)
            self.image_error[c] = np.asarray(self.image_error[c], np.float64).reshape(k)
            if k == 0:
                raise ValueError(f"camera {self.intrinsics.names[c]!r} has no KeyFrame")
            if np.any(np.diff(self.keyframes[c]) <= 0):
                raise ValueError(f"camera {self.intrinsics.names[c]!r}: KeyFrame frames must "
                                 "be strictly increasing")

    @property
    def n_cameras(self) -> int:
        """Number of cameras ``C``."""
        return self.intrinsics.n_cameras

    def extrinsics_at(self, frames: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Extrinsics in force at the given frames.

        Each camera uses the last KeyFrame whose ``FRAME`` is <= the frame; frames before
        a camera's first KeyFrame use that first KeyFrame.

        Parameters
        ----------
        frames : array_like of int, shape (F,)
            Zero-based frame indices.

        Returns
        -------
        R : ndarray, shape (F, C, 3, 3)
            World->camera rotations.
        t : ndarray, shape (F, C, 3)
            Translations (mm).
        """
        frames = np.asarray(frames, dtype=np.int64).reshape(-1)
        n = self.n_cameras
        R = np.empty((frames.shape[0], n, 3, 3))
        t = np.empty((frames.shape[0], n, 3))
        for c in range(n):
            idx = np.searchsorted(self.keyframes[c], frames, side="right") - 1
            np.clip(idx, 0, None, out=idx)
            R[:, c] = self.R[c][idx]
            t[:, c] = self.t[c][idx]
        return R, t

    @classmethod
    def from_arrays(
        cls,
        intrinsics: CameraIntrinsics,
        R: ArrayLike,
        t: ArrayLike,
        *,
        first_frame: int = 0,
        atol: float = 1e-9,
        image_error: ArrayLike | None = None,
        extras: Any = None,
    ) -> XcpCalibration:
        """Build a calibration from static or per-frame extrinsics.

        Per-frame extrinsics are run-length encoded: a camera gets a new KeyFrame at the
        first frame whose ``R`` or ``t`` differs from those of the KeyFrame in force by
        more than ``atol`` (so `extrinsics_at` reproduces the input to within ``atol``).

        Parameters
        ----------
        intrinsics : CameraIntrinsics
            Intrinsics of the ``C`` cameras.
        R : array_like, shape (C, 3, 3) or (F, C, 3, 3)
            World->camera rotations.
        t : array_like, shape (C, 3) or (F, C, 3)
            Translations (mm).
        first_frame : int
            Frame index of ``R[0]`` (the ``FRAME`` of the first KeyFrame).
        atol : float
            Largest change (absolute, in rotation-matrix entries and mm) that does not
            start a new KeyFrame.
        image_error : array_like, shape (C,) or (F, C), optional
            ``IMAGE_ERROR`` per camera (and frame); 0 when not given.
        extras : optional
            The `extras` of an imported calibration, to keep its unknown content.

        Returns
        -------
        XcpCalibration

        Raises
        ------
        ValueError
            On shapes that do not match or non-finite values.
        """
        n = intrinsics.n_cameras
        R = np.asarray(R, dtype=np.float64)
        t = np.asarray(t, dtype=np.float64)
        if R.shape == (n, 3, 3) and t.shape == (n, 3):
            R, t = R[None], t[None]
        if R.ndim != 4 or R.shape[1:] != (n, 3, 3) or t.shape != (R.shape[0], n, 3):
            raise ValueError(f"R must be (C,3,3) or (F,C,3,3) and t (C,3) or (F,C,3) with "
                             f"C={n}; got R {R.shape}, t {t.shape}")
        if R.shape[0] == 0:
            raise ValueError("R and t hold no frames")
        bad = ~(np.isfinite(R).all(axis=(2, 3)) & np.isfinite(t).all(axis=2))
        if bad.any():
            f, c = np.argwhere(bad)[0]
            raise ValueError(f"non-finite extrinsics at frame {first_frame + f}, camera "
                             f"{intrinsics.names[c]!r}")
        n_frames = R.shape[0]
        err = np.zeros((n_frames, n)) if image_error is None else np.broadcast_to(
            np.asarray(image_error, np.float64), (n_frames, n))
        # One row of 12 numbers per frame and camera; a KeyFrame starts where it changes.
        rows = np.concatenate([R.reshape(n_frames, n, 9), t], axis=2)
        keyframes, Rs, ts, errs = [], [], [], []
        for c in range(n):
            starts = _run_starts(rows[:, c], atol)
            keyframes.append(starts.astype(np.int64) + int(first_frame))
            Rs.append(R[starts, c].copy())
            ts.append(t[starts, c].copy())
            errs.append(np.array(err[starts, c], dtype=np.float64))
        return cls(intrinsics.copy(), keyframes, Rs, ts, errs, extras=extras)


def _run_starts(rows: NDArray[np.float64], atol: float, window: int = 256) -> NDArray[np.intp]:
    """Indices where a new run starts: the first row differing from the run's first row.

    ``rows`` has shape (F, D). Vectorised where every frame changes (per-frame solves);
    long static stretches are scanned in windows, one pass per KeyFrame.
    """
    n = rows.shape[0]
    step = np.abs(np.diff(rows, axis=0)).max(axis=1) > atol if n > 1 else np.zeros(0, bool)
    # Consecutive changes always start a run; within a run of small steps, drift can
    # still add up beyond atol, so those runs are scanned against their first row.
    coarse = np.concatenate([[0], np.flatnonzero(step) + 1])
    ends = np.append(coarse[1:], n)
    starts: list[int] = []
    for s, e in zip(coarse.tolist(), ends.tolist(), strict=True):
        starts.append(s)
        if e - s < 2:
            continue
        ref = s
        pos = s + 1
        while pos < e:
            stop = min(pos + window, e)
            dev = np.abs(rows[pos:stop] - rows[ref]).max(axis=1) > atol
            hit = np.flatnonzero(dev)
            if hit.size:
                ref = pos + int(hit[0])
                starts.append(ref)
                pos = ref + 1
            else:
                pos = stop
    return np.asarray(starts, dtype=np.intp)


# --------------------------------------------------------------------------- reading


def read_xcp(path: str | os.PathLike[str]) -> XcpCalibration:
    """Read a Vicon ``.xcp`` calibration file.

    Parameters
    ----------
    path : str or PathLike
        The file.

    Returns
    -------
    XcpCalibration
        Cameras in file order; names are ``NAME`` when non-empty, else ``DEVICEID``,
        else ``USERID``, else ``Camera <i>`` (made unique).

    Raises
    ------
    CaraFileError
        If the file cannot be read, is not XML, has no ``Cameras`` root or no camera, or
        a camera lacks KeyFrames or has a missing, non-numeric or malformed attribute.
    """
    path = Path(path)
    check_input_file(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise CaraFileError(path, f"cannot be read ({exc.strerror or exc})") from exc
    parser = etree.XMLParser(remove_blank_text=True, resolve_entities=False, no_network=True)
    try:
        root = etree.fromstring(data, parser)
    except etree.XMLSyntaxError as exc:
        raise CaraFileError(path, f"is not a valid XML file ({exc})") from exc
    if root.tag != "Cameras":
        raise CaraFileError(path, f"is not an XCP calibration file: the root element is "
                            f"<{root.tag}>, expected <Cameras>")

    extras: dict[str, Any] = {
        "format": "xcp", "version": _EXTRAS_VERSION,
        "root_attrib": dict(root.attrib), "root_children": [], "cameras": [],
        "prolog": [_to_xml(n) for n in reversed(list(root.itersiblings(preceding=True)))],
        "epilog": [_to_xml(n) for n in root.itersiblings()],
    }
    parsed: list[dict[str, Any]] = []
    notes: list[str] = []
    n_cam = 0
    for child in root:
        if child.tag == "Camera":
            cam = _read_camera(path, child, n_cam, notes)
            parsed.append(cam)
            extras["cameras"].append(cam.pop("extras"))
            n_cam += 1
        else:
            # Position = number of cameras before it, so it is written back in place.
            extras["root_children"].append([n_cam, _to_xml(child)])
    if not parsed:
        raise CaraFileError(path, "contains no <Camera> element")

    names = unique_names([p["name"] for p in parsed])
    for cam_extras, name in zip(extras["cameras"], names, strict=True):
        cam_extras["name"] = name
    intr = CameraIntrinsics(
        focal=[p["focal"] for p in parsed],
        principal_point=[p["pp"] for p in parsed],
        aspect=[p["aspect"] for p in parsed],
        skew=[p["skew"] for p in parsed],
        radial=[p["radial"] for p in parsed],
        distortion_centre=[p["centre"] for p in parsed],
        image_size=[p["size"] for p in parsed],
        radial_model=[p["model"] for p in parsed],
        names=names,
    )
    return XcpCalibration(
        intrinsics=intr,
        keyframes=[p["frames"] for p in parsed],
        R=[p["R"] for p in parsed],
        t=[p["t"] for p in parsed],
        image_error=[p["image_error"] for p in parsed],
        extras=extras,
        notes=notes,
    )


def _read_camera(path: Path, el: etree._Element, index: int, notes: list[str]) -> dict[str, Any]:
    """Parse one <Camera>; returns plain values plus its extras record.

    KeyFrame attributes are parsed column-wise (one attribute over all KeyFrames at once),
    so per-frame files with tens of thousands of KeyFrames load quickly; only when a
    column is bad are the KeyFrames visited one by one to name the culprit.
    """
    attrib = dict(el.attrib)
    name = next((attrib[k].strip() for k in ("NAME", "DEVICEID", "USERID")
                 if attrib.get(k, "").strip()), f"Camera {index}")
    label = f"camera {index} ({name!r})"

    def camera_number(key: str, count: int, default: float | None = None) -> list[float]:
        if key not in attrib:
            if default is not None:
                return [default]
            raise CaraFileError(path, f"{label}: attribute {key} is missing")
        return _numbers(path, attrib[key], key, count, label)

    aspect = camera_number("PIXEL_ASPECT_RATIO", 1, 1.0)[0]
    size = camera_number("SENSOR_SIZE", 2)
    skew = camera_number("SKEW", 1, 0.0)[0]
    if aspect <= 0:
        raise CaraFileError(path, f"{label}: PIXEL_ASPECT_RATIO must be positive, got {aspect}")
    if min(size) <= 0:
        raise CaraFileError(path, f"{label}: SENSOR_SIZE must be positive, got {size}")

    children: list[str] = []
    kf_container = None
    for child in el:
        if child.tag == "KeyFrames" and kf_container is None:
            kf_container = child
            children.append(_KEYFRAMES_SLOT)
        else:
            children.append(_to_xml(child))
    if kf_container is None:
        raise CaraFileError(path, f"{label} has no <KeyFrames> element")
    kfa = [dict(k.attrib) for k in kf_container if k.tag == "KeyFrame"]
    if not kfa:
        raise CaraFileError(path, f"{label} has no <KeyFrame> inside <KeyFrames>")
    n_kf = len(kfa)

    if all("FRAME" in ka for ka in kfa):
        frame_col = _column(path, kfa, "FRAME", 1, lambda j: f"{label}, KeyFrame {j}")[:, 0]
        # FRAME is a frame index: beyond 2^31 it cannot be one (and >= 2^63 wrapped
        # negative in int64)
        bad = np.flatnonzero((frame_col != np.round(frame_col)) | (frame_col < 0)
                             | (frame_col > MAX_FRAME))
        if bad.size:
            j = int(bad[0])
            raise CaraFileError(path, f"{label}, KeyFrame {j}: FRAME must be an integer from "
                                f"0 to {MAX_FRAME}, got {kfa[j]['FRAME']!r}")
        frames_arr = frame_col.astype(np.int64)
    elif n_kf == 1:
        frames_arr = np.zeros(1, dtype=np.int64)
    else:
        j = next(j for j, ka in enumerate(kfa) if "FRAME" not in ka)
        raise CaraFileError(path, f"{label}, KeyFrame {j}: attribute FRAME is missing (needed "
                            "when a camera has several KeyFrames)")

    def where(j: int) -> str:
        return f"{label}, KeyFrame FRAME={frames_arr[j]}"

    focal = _column(path, kfa, "FOCAL_LENGTH", 1, where)[:, 0]
    bad = np.flatnonzero(focal <= 0)
    if bad.size:
        raise CaraFileError(path, f"{where(int(bad[0]))}: FOCAL_LENGTH must be positive, got "
                            f"{focal[bad[0]]}")
    pp = _column(path, kfa, "PRINCIPAL_POINT", 2, where)
    q = _column(path, kfa, "ORIENTATION", 4, where)
    norm = np.linalg.norm(q, axis=1)
    bad = np.flatnonzero(np.abs(norm - 1.0) > QUATERNION_NORM_TOL)
    if bad.size:
        raise CaraFileError(path, f"{where(int(bad[0]))}: ORIENTATION is not a unit quaternion "
                            f"(norm {norm[bad[0]]:.6g})")
    centres = _column(path, kfa, "POSITION", 3, where)
    errors = _column(path, kfa, "IMAGE_ERROR", 1, where, default=[0.0])[:, 0]

    # Distortion: VICON_RADIAL2 wins where both are present (the older one is kept verbatim).
    models = [VICON_RADIAL2 if "VICON_RADIAL2" in ka else VICON_RADIAL for ka in kfa]
    dcentre = pp.copy()
    radial = np.zeros((n_kf, 3))
    two = np.flatnonzero([m == VICON_RADIAL2 for m in models])
    if two.size:
        sub = [kfa[j] for j in two.tolist()]
        for k, ka in zip(two.tolist(), sub, strict=True):
            if ka["VICON_RADIAL2"].split()[:1] != [_VICON3]:
                raise CaraFileError(path, f"{where(k)}: VICON_RADIAL2 must start with "
                                    f"'{_VICON3}', got {ka['VICON_RADIAL2'][:40]!r}")
        stripped = [{"VICON_RADIAL2": ka["VICON_RADIAL2"].lstrip()[len(_VICON3):]} for ka in sub]
        vals = _column(path, stripped, "VICON_RADIAL2", 5, lambda j: where(int(two[j])),
                       what="5 numbers after 'Vicon3Parameter'")
        dcentre[two], radial[two] = vals[:, :2], vals[:, 2:]
    one = np.flatnonzero([m == VICON_RADIAL and "VICON_RADIAL" in ka
                          for m, ka in zip(models, kfa, strict=True)])
    if one.size:
        # A KeyFrame with neither attribute is an ideal pinhole (written back as "0 0").
        vals = _column(path, [kfa[j] for j in one.tolist()], "VICON_RADIAL", 2,
                       lambda j: where(int(one[j])))
        radial[one, :2] = vals

    if np.unique(frames_arr).size != n_kf:
        raise CaraFileError(path, f"{label}: two KeyFrames have the same FRAME")
    order = np.argsort(frames_arr, kind="stable")
    first = int(order[0])
    model = models[first]
    rows = np.concatenate([focal[:, None], pp, dcentre, radial], axis=1)
    if any(m != model for m in models) or not np.allclose(rows, rows[first], rtol=1e-12, atol=0):
        notes.append(f"{label}: intrinsics differ between KeyFrames; those of the first "
                     f"KeyFrame (FRAME={frames_arr[first]}) are used")
    R = quaternion_to_matrix(q[order] / norm[order, None])
    t = -np.einsum("kij,kj->ki", R, centres[order])

    kf_extra: dict[str, dict[str, str]] = {}
    for j, ka in enumerate(kfa):
        unknown = {k: v for k, v in ka.items() if k not in _KEYFRAME_KNOWN}
        if models[j] == VICON_RADIAL2 and "VICON_RADIAL" in ka:
            unknown["VICON_RADIAL"] = ka["VICON_RADIAL"]  # superseded; kept verbatim
        if unknown:
            kf_extra[str(frames_arr[j])] = unknown
    frames_sorted = frames_arr[order]
    return {
        "name": name,
        "focal": rows[first, 0], "pp": rows[first, 1:3], "centre": rows[first, 3:5],
        "radial": rows[first, 5:8], "model": model, "aspect": aspect, "skew": skew,
        "size": size, "frames": frames_sorted, "R": R, "t": t,
        "image_error": errors[order],
        "extras": {
            "attrib": attrib,
            "children": children,
            "keyframes_attrib": dict(kf_container.attrib),
            "keyframes_other": [_to_xml(k) for k in kf_container if k.tag != "KeyFrame"],
            "keyframe_attrib": kf_extra,
            # The file's own digits, written back where the values did not change, so that
            # exporting an imported file does not churn last digits (quaternion -> matrix
            # -> quaternion is not exact): intrinsics of the first KeyFrame, pose per frame.
            "intrinsics_text": {k: v for k, v in kfa[first].items()
                                if k in _KEYFRAME_KNOWN - {"FRAME", "ORIENTATION", "POSITION"}},
            "poses": {str(frames_arr[j]): [kfa[j]["ORIENTATION"], kfa[j]["POSITION"]]
                      for j in range(n_kf)},
        },
    }


def _column(path: Path, kfa: list[dict[str, str]], key: str, count: int,
            where: Callable[[int], str], default: list[float] | None = None,
            what: str | None = None) -> NDArray[np.float64]:
    """One numeric attribute over all KeyFrames, shape (K, count); errors name the KeyFrame."""
    texts = [ka.get(key) for ka in kfa]
    if default is not None:
        texts = [" ".join(map(repr, default)) if s is None else s for s in texts]
    try:
        tokens = " ".join(texts).split()  # type: ignore[arg-type]
        if len(tokens) == count * len(kfa):
            vals = np.array(tokens, dtype=np.float64).reshape(len(kfa), count)
            if np.isfinite(vals).all():
                return vals
    except (TypeError, ValueError):
        pass
    # Slow path: find and name the first bad KeyFrame (a count can also balance out).
    out = np.empty((len(kfa), count))
    for j, text in enumerate(texts):
        if text is None:
            raise CaraFileError(path, f"{where(j)}: attribute {key} is missing")
        out[j] = _numbers(path, text, key, count, where(j), what)
    return out


def _numbers(path: Path, text: str, key: str, count: int, where: str,
             what: str | None = None) -> list[float]:
    """Parse ``count`` whitespace-separated finite numbers or raise CaraFileError."""
    tokens = text.split()
    what = what or (f"{count} number" + ("s" if count > 1 else ""))
    if len(tokens) != count:
        raise CaraFileError(path, f"{where}: {key} must hold {what}, got {len(tokens)} "
                            f"({text[:60]!r})")
    try:
        vals = [float(x) for x in tokens]
    except ValueError:
        raise CaraFileError(path, f"{where}: {key} is not numeric ({text[:60]!r})") from None
    if not all(math.isfinite(v) for v in vals):
        raise CaraFileError(path, f"{where}: {key} holds a non-finite value ({text[:60]!r})")
    return vals


def _to_xml(el: etree._Element) -> str:
    return etree.tostring(el, encoding="unicode", with_tail=False)


def _from_xml(text: str) -> etree._Element:
    """The node ``_to_xml`` wrote: an element, or a comment, processing instruction or
    entity reference (which cannot be parsed as a document of their own)."""
    text = text.strip()
    if text.startswith("<!--") and text.endswith("-->"):
        return etree.Comment(text[4:-3])
    if text.startswith("<?") and text.endswith("?>"):
        target, _, data = text[2:-2].partition(" ")
        return etree.ProcessingInstruction(target, data or None)
    if text.startswith("&") and text.endswith(";") and " " not in text:
        return etree.Entity(text[1:-1])
    parser = etree.XMLParser(remove_blank_text=True, resolve_entities=False, no_network=True)
    return etree.fromstring(text, parser)


# --------------------------------------------------------------------------- writing


def write_xcp(path: str | os.PathLike[str], calib: XcpCalibration, *,
              frame: int | None = None) -> None:
    """Write a calibration as a Vicon ``.xcp`` file, atomically.

    Unknown content recorded in ``calib.extras`` by `read_xcp` (root attributes, camera
    and KeyFrame attributes, child elements) is written back. Each camera keeps its
    radial model; a ``VICON_RADIAL`` camera whose distortion no longer fits the two-term
    model (``k3 != 0`` or a centre away from the principal point) is written as
    ``VICON_RADIAL2`` so nothing is lost.

    Parameters
    ----------
    path : str or PathLike
        Destination; replaced only once the new file is completely on disk.
    calib : XcpCalibration
        The cameras to write.
    frame : int, optional
        Write only the extrinsics in force at this frame, as a single ``FRAME="0"``
        KeyFrame per camera (File > Export XCP [Current Frame]). By default every
        KeyFrame is written.

    Raises
    ------
    ValueError
        If the calibration holds non-finite values.
    CaraFileError
        If the file cannot be written (the destination is then left untouched).
    """
    path = Path(path)
    root = _build_tree(calib, frame)
    body = etree.tostring(root, encoding="UTF-8", pretty_print=True)
    ex = calib.extras if isinstance(calib.extras, dict) else {}
    # comments and processing instructions around the root element, kept by read_xcp
    before = "".join(f"{t}\n" for t in ex.get("prolog", []) if isinstance(t, str))
    after = "".join(f"{t}\n" for t in ex.get("epilog", []) if isinstance(t, str))
    data = (b'<?xml version="1.0" encoding="UTF-8" standalone="no" ?>\n'
            + before.encode("utf-8") + body + after.encode("utf-8"))
    atomic_write_bytes(path, data)


def _camera_extras(calib: XcpCalibration) -> list[dict[str, Any] | None]:
    """Per-camera extras records, matched by camera name (so subsets and reordering keep
    each camera's own content), else by position when the camera count is unchanged."""
    ex = calib.extras
    n = calib.n_cameras
    if not isinstance(ex, dict) or ex.get("format") != "xcp":
        return [None] * n
    cams = ex.get("cameras", [])
    by_name = {c.get("name"): c for c in cams}
    return [by_name.get(name, cams[i] if len(cams) == n else None)
            for i, name in enumerate(calib.intrinsics.names)]


def _build_tree(calib: XcpCalibration, frame: int | None) -> etree._Element:
    intr = calib.intrinsics
    n = calib.n_cameras
    arrays = [intr.focal, intr.principal_point, intr.aspect, intr.skew, intr.radial,
              intr.distortion_centre, intr.image_size, *calib.R, *calib.t, *calib.image_error]
    if not all(np.all(np.isfinite(a)) for a in arrays):
        raise ValueError("the calibration holds non-finite values; nothing was written")
    ex = calib.extras if isinstance(calib.extras, dict) and calib.extras.get(
        "format") == "xcp" else {}
    root = etree.Element("Cameras")
    root_attrib = dict(ex.get("root_attrib", {"VERSION": "2.0"}))
    root_attrib.setdefault("VERSION", "2.0")
    root_attrib.setdefault("SOURCE", "carapost")
    _set_sorted(root, root_attrib)
    root_children: dict[int, list[str]] = {}
    for pos, xml in ex.get("root_children", []):
        root_children.setdefault(int(pos), []).append(xml)

    cam_extras = _camera_extras(calib)
    for c in range(n):
        for xml in root_children.pop(c, []):
            root.append(_from_xml(xml))
        root.append(_camera_element(calib, c, cam_extras[c], frame))
    for pos in sorted(root_children):
        for xml in root_children[pos]:
            root.append(_from_xml(xml))
    return root


def _camera_element(calib: XcpCalibration, c: int, cex: dict[str, Any] | None,
                    frame: int | None) -> etree._Element:
    intr = calib.intrinsics
    cex = cex or {}
    attrib = dict(cex.get("attrib", {}))
    name = intr.names[c]
    original_name = attrib.get("NAME", "")
    # An unnamed Vicon camera was given its DEVICEID/USERID as name on import; keep the
    # file's empty NAME unless the user renamed it.
    if not (original_name == "" and cex.get("name") == name and "attrib" in cex):
        attrib["NAME"] = name
    if "DEVICEID" not in attrib:
        attrib["DEVICEID"] = str(c)
    original = dict(attrib)
    attrib["PIXEL_ASPECT_RATIO"] = _fmt(intr.aspect[c])
    attrib["SENSOR_SIZE"] = _fmt(intr.image_size[c])
    if "SKEW" in attrib or intr.skew[c] != 0.0:
        attrib["SKEW"] = _fmt(intr.skew[c])
    _keep_digits(attrib, original)
    el = etree.Element("Camera")
    _set_sorted(el, attrib)

    radial_model = intr.radial_model[c]
    centre, pp, k = intr.distortion_centre[c], intr.principal_point[c], intr.radial[c]
    if radial_model == VICON_RADIAL and (k[2] != 0.0 or np.any(np.abs(centre - pp) > 1e-9)):
        radial_model = VICON_RADIAL2
    radial_attr: dict[str, str]
    if radial_model == VICON_RADIAL:
        radial_attr = {"VICON_RADIAL": _fmt(k[:2])}
    else:
        radial_attr = {"VICON_RADIAL2": f"{_VICON3} {_fmt(centre)} {_fmt(k)}"}
    common = {"FOCAL_LENGTH": _fmt(intr.focal[c]), "PRINCIPAL_POINT": _fmt(pp), **radial_attr}

    frames = calib.keyframes[c]
    if frame is None:
        rows = list(range(frames.shape[0]))
        out_frames = frames.tolist()
    else:
        idx = max(int(np.searchsorted(frames, int(frame), side="right")) - 1, 0)
        rows, out_frames = [idx], [0]
    kf_extra = cex.get("keyframe_attrib", {})
    poses = cex.get("poses", {})
    intr_text = cex.get("intrinsics_text", {})
    kfs = etree.Element("KeyFrames")
    _set_sorted(kfs, cex.get("keyframes_attrib", {}))
    for xml in cex.get("keyframes_other", []):
        kfs.append(_from_xml(xml))
    R, t = calib.R[c][rows], calib.t[c][rows]
    quats = matrix_to_quaternion(R)
    centres = -np.einsum("kji,kj->ki", R, t)
    same_pose = _same_poses([poses.get(str(int(frames[j]))) for j in rows], R, t)
    for i, (j, out_frame) in enumerate(zip(rows, out_frames, strict=True)):
        ka = dict(kf_extra.get(str(int(frames[j])), {}))
        ka.update(common)
        ka["FRAME"] = str(int(out_frame))
        ka["IMAGE_ERROR"] = _fmt(calib.image_error[c][j])
        pose = poses.get(str(int(frames[j])))
        if pose is not None and same_pose[i]:
            ka["ORIENTATION"], ka["POSITION"] = pose[0], pose[1]
        else:
            ka["ORIENTATION"], ka["POSITION"] = _fmt(quats[i]), _fmt(centres[i])
        kf = etree.SubElement(kfs, "KeyFrame")
        _keep_digits(ka, intr_text)
        _set_sorted(kf, ka)

    children = cex.get("children", [_KEYFRAMES_SLOT])
    if _KEYFRAMES_SLOT not in children:
        children = [*children, _KEYFRAMES_SLOT]
    for item in children:
        el.append(kfs if item == _KEYFRAMES_SLOT else _from_xml(item))
    return el


def _same_poses(texts: list[list[str] | None], R: NDArray[np.float64],
                t: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Per KeyFrame: does the file's ORIENTATION/POSITION text read back to exactly R, t?"""
    same = np.zeros(len(texts), dtype=bool)
    have = [i for i, p in enumerate(texts) if p is not None]
    if not have:
        return same
    try:
        q = np.array(" ".join(texts[i][0] for i in have).split(),  # type: ignore[index]
                     dtype=np.float64).reshape(len(have), 4)
        centre = np.array(" ".join(texts[i][1] for i in have).split(),  # type: ignore[index]
                          dtype=np.float64).reshape(len(have), 3)
    except ValueError:
        return same
    # Exactly the arithmetic of read_xcp, so unchanged poses compare equal bit for bit.
    R0 = quaternion_to_matrix(q / np.linalg.norm(q, axis=1)[:, None])
    t0 = -np.einsum("kij,kj->ki", R0, centre)
    same[have] = (R0 == R[have]).all(axis=(1, 2)) & (t0 == t[have]).all(axis=1)
    return same


def _keep_digits(attrib: dict[str, str], original: dict[str, str]) -> None:
    """Use the file's own text for attributes whose values did not change."""
    for key, text in original.items():
        if key in attrib and attrib[key] != text and _same_numbers(attrib[key], text):
            attrib[key] = text


def _same_numbers(a: str, b: str) -> bool:
    ta, tb = a.split(), b.split()
    if len(ta) != len(tb):
        return False
    for x, y in zip(ta, tb, strict=True):
        if x == y:
            continue
        try:
            if float(x) != float(y):
                return False
        except ValueError:
            return False
    return True


def _set_sorted(el: etree._Element, attrib: dict[str, str]) -> None:
    # Vicon writes attributes in alphabetical order; so do we.
    for key in sorted(attrib):
        el.set(key, str(attrib[key]))


def _fmt(values: ArrayLike) -> str:
    """Shortest text that reads back to the same doubles; whole numbers without '.0'."""
    arr = np.atleast_1d(np.asarray(values, dtype=np.float64))
    return " ".join(_fmt_one(float(v)) for v in arr)


def _fmt_one(v: float) -> str:
    if v == int(v) and abs(v) < 1e15:
        return str(int(v))
    return repr(v)

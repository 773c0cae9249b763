"""The ``.cara`` project file: a ZIP container of ``manifest.json`` and ``.npy`` arrays.

Layout (format version 1)::

    manifest.json              metadata (see :func:`_manifest`)
    points/<name>.npy          per-point arrays [F, P, ...] (positions, recon, obs, ...)
    detections/offsets.npy     [F*C+1] int64 run offsets
    detections/<field>.npy     flat detection fields (centre, axes, angle, colour, score)
    calibration/R.npy, t.npy, solved.npy   per-frame extrinsics

Members are stored uncompressed: the arrays are mostly noise-like floats that deflate
barely shrinks, and storing keeps save and open close to disk speed.

Saving is atomic: the project is written to a temporary file in the same folder,
flushed to disk with fsync and renamed over the target, so a crash or a full disk never
leaves a half-written project and a failed save never touches the original.
"""

from __future__ import annotations

import io
import json
import logging
import mmap
import os
import struct
import time
import zipfile
import zlib
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from carapost import __version__
from carapost.algorithms.camera import CameraIntrinsics
from carapost.io.atomic import atomic_output
from carapost.io.errors import CaraFileError
from carapost.model.project import (
    OPTIONAL_POINT_ARRAYS,
    POINT_ARRAYS,
    CameraChannel,
    Detections,
    Project,
    RomReference,
    Selection,
    Stick,
    Take,
    blank_point_array,
)

log = logging.getLogger("carapost.io")

FORMAT_VERSION = 1
AUTOSAVE_SUFFIX = ".autosave"

#: Called with (camera name, missing path); returns a replacement path or None.
RelocateCallback = Callable[[str, str], "str | None"]


# ----------------------------------------------------------------------------------------
# Saving
# ----------------------------------------------------------------------------------------
def _rel(path: str, base: Path) -> str:
    if not path:
        return ""
    try:
        return os.path.relpath(path, base)
    except ValueError:  # another drive on Windows
        return ""


def _manifest(project: Project, folder: Path) -> dict[str, Any]:
    take = project.take
    cal = project.calibration
    intr = cal.intrinsics
    return {
        "format": "carapost-project",
        "format_version": FORMAT_VERSION,
        "app_version": __version__,
        "saved": time.strftime("%Y-%m-%dT%H:%M:%S"),
        "take": {
            "name": take.name,
            "n_frames": take.n_frames,
            "fps": take.fps,
            "timecode_start": take.timecode_start,
            "metadata": take.metadata,
            "cameras": [
                {
                    "name": c.name,
                    "video_path": str(Path(c.video_path).resolve()) if c.video_path else "",
                    "video_path_relative": _rel(c.video_path, folder),
                    "image_size": list(c.image_size),
                    "rotation": c.rotation,
                    "frame_offset": c.frame_offset,
                }
                for c in take.cameras
            ],
        },
        "intrinsics": None
        if intr is None
        else {
            "focal": intr.focal.tolist(),
            "principal_point": intr.principal_point.tolist(),
            "aspect": intr.aspect.tolist(),
            "skew": intr.skew.tolist(),
            "radial": intr.radial.tolist(),
            "distortion_centre": intr.distortion_centre.tolist(),
            "image_size": intr.image_size.tolist(),
            "radial_model": intr.radial_model,
            "names": intr.names,
        },
        "points": {
            "ids": project.points.ids.tolist(),
            "labels": project.points.labels,
            "kind": project.points.kind.tolist(),
            "next_id": project.points.next_id,
        },
        "labels": project.labels,
        "sticks": [[s.a, s.b, list(s.colour)] for s in project.sticks],
        "properties": project.properties.to_dict(),
        "current_frame": project.current_frame,
        "active_range": list(project.active_range),
        "view_range": list(project.view_range),
        "selected_cameras": sorted(project.selection.cameras),
        "selected_points": sorted(project.selection.points),
        "rom": project.rom.path if project.rom else None,
        "imported_blob_parameters": project.imported_blob_parameters,
        # optional: the Session calls that made the project (`carapost history --python`)
        **({"script": project.script} if project.script is not None else {}),
    }


def _arrays(project: Project) -> dict[str, np.ndarray]:
    out: dict[str, np.ndarray] = {}
    for name, arr in project.points.arrays.items():
        out[f"points/{name}.npy"] = arr
    out["detections/offsets.npy"] = project.detections.offsets
    for name, arr in project.detections.arrays.items():
        out[f"detections/{name}.npy"] = arr
    cal = project.calibration
    out["calibration/R.npy"] = cal.R
    out["calibration/t.npy"] = cal.t
    out["calibration/solved.npy"] = cal.solved
    return out


def _write_npy(zf: zipfile.ZipFile, name: str, arr: np.ndarray) -> None:
    arr = np.ascontiguousarray(arr)
    info = zipfile.ZipInfo(name, date_time=time.localtime()[:6])
    info.compress_type = zipfile.ZIP_STORED
    with zf.open(info, "w", force_zip64=arr.nbytes > 2**31) as fh:
        # header, then the raw buffer in one write: no tobytes() copy of large arrays
        np.lib.format.write_array_header_1_0(fh, np.lib.format.header_data_from_array_1_0(arr))
        if arr.size:
            fh.write(memoryview(arr.reshape(-1).view(np.uint8)))


def save_project(project: Project, path: str | Path, *, autosave: bool = False) -> Path:
    """Save a project to a ``.cara`` file atomically.

    Parameters
    ----------
    project : Project
    path : str or Path
        Destination; ``.cara`` is appended when missing.
    autosave : bool
        Writing the autosave copy: the project's own path and modified flag are left alone.

    Returns
    -------
    Path
        The file written.
    """
    path = Path(path)
    if not autosave and path.suffix.lower() != ".cara":
        path = path.with_name(path.name + ".cara")
    path = path.absolute()
    manifest = _manifest(project, path.parent)
    arrays = _arrays(project)
    manifest["arrays"] = {
        name: {"dtype": str(a.dtype), "shape": list(a.shape)} for name, a in arrays.items()
    }

    # atomic_output refuses a missing folder (CaraFileError) before writing anything
    with atomic_output(path) as fh, zipfile.ZipFile(
        fh, "w", zipfile.ZIP_STORED, allowZip64=True
    ) as zf:
        zf.writestr("manifest.json", json.dumps(manifest, indent=1))
        for name, arr in arrays.items():
            _write_npy(zf, name, arr)
    if not autosave:
        project.path = str(path)
        project.modified = False
        project.events.emit("file")
        stale = autosave_path(path)
        if stale.exists():
            stale.unlink()
    log.info("Saved %s", path)
    return path


def autosave_path(path: str | Path) -> Path:
    """Where the autosave copy of a project lives (beside it)."""
    path = Path(path)
    return path.with_name(path.name + AUTOSAVE_SUFFIX)


def autosave_project(project: Project, path: str | Path | None = None) -> Path | None:
    """Write the autosave copy of a project (beside its file, or ``path``)."""
    target = path or project.path
    if target is None:
        return None
    return save_project(project, autosave_path(target), autosave=True)


def recoverable_autosave(path: str | Path) -> Path | None:
    """The autosave copy of ``path`` when it is newer than the project (crash recovery)."""
    path = Path(path)
    auto = autosave_path(path)
    if not auto.exists():
        return None
    if path.exists() and auto.stat().st_mtime <= path.stat().st_mtime:
        return None
    return auto


# ----------------------------------------------------------------------------------------
# Loading
# ----------------------------------------------------------------------------------------
def _read_manifest(zf: zipfile.ZipFile, path: Path) -> dict[str, Any]:
    try:
        raw = zf.read("manifest.json")
    except KeyError:
        raise CaraFileError(path, "not a carapost project: manifest.json is missing") from None
    try:
        manifest = json.loads(raw)
    except (ValueError, UnicodeDecodeError) as exc:
        raise CaraFileError(path, f"manifest.json is not valid JSON ({exc})") from None
    if not isinstance(manifest, dict) or manifest.get("format") != "carapost-project":
        raise CaraFileError(path, "not a carapost project (manifest has no carapost format tag)")
    version = manifest.get("format_version")
    if not isinstance(version, int):
        raise CaraFileError(path, "the manifest has no format version")
    if version > FORMAT_VERSION:
        raise CaraFileError(
            path,
            f"written by a newer carapost ({manifest.get('app_version', '?')}, project format "
            f"{version}); this carapost {__version__} reads format {FORMAT_VERSION} and older. "
            "Update carapost to open it.",
        )
    return manifest


class _Members:
    """Arrays of a project file, mapped copy-on-write instead of read.

    Members are stored uncompressed, so each ``.npy`` payload is a contiguous run of the
    file: it is mapped privately (edits stay in memory, the file is never written) and
    pages come in as they are used, which keeps Open fast for long takes. Every member's
    CRC-32 is still checked, on both cores, before the project is handed out.
    """

    def __init__(self, zf: zipfile.ZipFile, path: Path) -> None:
        self.zf = zf
        self.path = path
        self._fh = open(path, "rb")  # closed in close()
        try:
            self._map: mmap.mmap | None = mmap.mmap(self._fh.fileno(), 0,
                                                    access=mmap.ACCESS_COPY)
        except (OSError, ValueError):  # empty file or a file system without mmap
            self._map = None
        self._checks: list[tuple[str, int, int, int]] = []

    def close(self) -> None:
        self._fh.close()  # the mapping stays valid on its own

    def _payload(self, info: zipfile.ZipInfo) -> tuple[int, int]:
        """Start and end (file offsets) of a stored member's bytes."""
        self._fh.seek(info.header_offset)
        header = self._fh.read(30)
        if len(header) != 30 or header[:4] != b"PK\x03\x04":
            raise CaraFileError(self.path, f"the member {info.filename} is damaged")
        n_name, n_extra = struct.unpack("<HH", header[26:30])
        start = info.header_offset + 30 + n_name + n_extra
        return start, start + info.compress_size

    def read(self, name: str, spec: dict[str, Any]) -> np.ndarray:
        """The array of member ``name``, checked against the manifest's ``spec``."""
        path = self.path
        try:
            info = self.zf.getinfo(name)
        except KeyError:
            raise CaraFileError(path, f"the array {name} is missing") from None
        try:
            if self._map is None or info.compress_type != zipfile.ZIP_STORED:
                with self.zf.open(name) as fh:
                    arr = np.lib.format.read_array(fh, allow_pickle=False)
            else:
                start, end = self._payload(info)
                if end > len(self._map):
                    raise CaraFileError(path, f"the array {name} is truncated")
                buf = io.BytesIO(self._map[start : min(start + 4096, end)])
                version = np.lib.format.read_magic(buf)
                read_header = (np.lib.format.read_array_header_1_0 if version == (1, 0)
                               else np.lib.format.read_array_header_2_0)
                shape, fortran, dtype = read_header(buf)
                if dtype.hasobject or fortran:
                    raise ValueError("object or Fortran-ordered arrays are not allowed")
                offset = start + buf.tell()
                count = int(np.prod(shape, dtype=np.int64))
                if offset + count * dtype.itemsize != end:
                    raise ValueError("its size does not match its header")
                arr = np.frombuffer(self._map, dtype=dtype, count=count,
                                    offset=offset).reshape(shape)
                self._checks.append((name, start, end, info.CRC))
        except CaraFileError:
            raise
        except (ValueError, OSError, EOFError, zipfile.BadZipFile) as exc:
            raise CaraFileError(path, f"the array {name} is damaged ({exc})") from None
        if list(arr.shape) != list(spec["shape"]) or str(arr.dtype) != spec["dtype"]:
            raise CaraFileError(
                path,
                f"the array {name} is {arr.dtype}{list(arr.shape)}, the manifest says "
                f"{spec['dtype']}{spec['shape']}",
            )
        return arr

    def verify(self) -> None:
        """Check the CRC-32 of every mapped member (zlib releases the GIL: two threads)."""
        if not self._checks:
            return
        view = memoryview(self._map)

        def crc(item: tuple[str, int, int, int]) -> tuple[str, bool]:
            name, start, end, expected = item
            value = 0
            for a in range(start, end, 1 << 26):  # 64 MB steps
                value = zlib.crc32(view[a : min(a + (1 << 26), end)], value)
            return name, value == expected

        with ThreadPoolExecutor(max_workers=2) as pool:
            results = list(pool.map(crc, sorted(self._checks, key=lambda c: c[1] - c[2])))
        view.release()
        bad = [name for name, ok in results if not ok]
        if bad:
            raise CaraFileError(self.path, f"the array {bad[0]} is damaged (checksum mismatch)")


def _resolve_video(
    cam: dict[str, Any], folder: Path, relocate: RelocateCallback | None
) -> str:
    abs_path = cam.get("video_path", "")
    if not abs_path:
        return ""
    if Path(abs_path).exists():
        return abs_path
    rel = cam.get("video_path_relative", "")
    candidates = []
    if rel:
        candidates.append(folder / rel)
    candidates.append(folder / Path(abs_path).name)
    for cand in candidates:
        if cand.exists():
            log.info("Camera %s: video found at %s", cam.get("name"), cand)
            return str(cand.resolve())
    if relocate is not None:
        new = relocate(cam.get("name", ""), abs_path)
        if new and Path(new).exists():
            return str(Path(new).resolve())
    log.warning("Camera %s: video %s not found (use Relocate Files)", cam.get("name"), abs_path)
    return abs_path


def load_project(path: str | Path, *, relocate: RelocateCallback | None = None) -> Project:
    """Open a ``.cara`` project.

    Parameters
    ----------
    path : str or Path
    relocate : callable, optional
        Asked for a camera video that is neither at its saved absolute path nor beside
        the project: ``relocate(camera_name, missing_path) -> new path or None``.

    Returns
    -------
    Project

    Raises
    ------
    CaraFileError
        Missing, truncated, corrupt or foreign files, and projects of a newer format.
    """
    path = Path(path)
    if not path.exists():
        raise CaraFileError(path, "no such file")
    try:
        zf = zipfile.ZipFile(path, "r")
    except zipfile.BadZipFile:
        raise CaraFileError(path, "not a carapost project (not a ZIP container, or truncated)")\
            from None
    except OSError as exc:
        raise CaraFileError(path, f"cannot be read: {exc.strerror or exc}") from None
    with zf:
        manifest = _read_manifest(zf, path)
        members = _Members(zf, path)
        try:
            project = _build(members, manifest, path, relocate)
            members.verify()
            return project
        except CaraFileError:
            raise
        except (KeyError, TypeError, ValueError, IndexError) as exc:
            raise CaraFileError(path, f"the manifest is inconsistent ({exc!r})") from None
        finally:
            members.close()


def _build(
    members: _Members, m: dict[str, Any], path: Path, relocate: RelocateCallback | None
) -> Project:
    from carapost.model.properties import Properties

    folder = path.parent.absolute()
    t = m["take"]
    cameras = [
        CameraChannel(
            name=str(c["name"]),
            video_path=_resolve_video(c, folder, relocate),
            image_size=(int(c["image_size"][0]), int(c["image_size"][1])),
            rotation=int(c.get("rotation", 0)),
            frame_offset=int(c.get("frame_offset", 0)),
        )
        for c in t["cameras"]
    ]
    take = Take(
        name=str(t["name"]),
        cameras=cameras,
        n_frames=int(t["n_frames"]),
        fps=float(t["fps"]),
        timecode_start=str(t.get("timecode_start", "00:00:00:00")),
        metadata=dict(t.get("metadata", {})),
    )
    project = Project(take)
    specs = m["arrays"]
    F, C = take.n_frames, take.n_cameras
    pm = m["points"]
    P = len(pm["ids"])
    if len(pm["labels"]) != P or len(pm["kind"]) != P:
        raise CaraFileError(path, "the point labels or kinds do not match the point count")
    pts = project.points
    pts.ids = np.asarray(pm["ids"], dtype=np.int64).reshape(P)
    pts.labels = [str(x) for x in pm["labels"]]
    pts.kind = np.asarray(pm["kind"], dtype=np.int8).reshape(P)
    pts.next_id = int(pm["next_id"])
    for name in POINT_ARRAYS:
        if name in OPTIONAL_POINT_ARRAYS and f"points/{name}.npy" not in specs:
            pts.arrays[name] = blank_point_array(name, F, P, C)
            continue
        arr = members.read(f"points/{name}.npy", specs[f"points/{name}.npy"])
        if arr.shape[:2] != (F, P) or (name in ("obs", "source") and arr.shape[2] != C):
            raise CaraFileError(path, f"points/{name} does not fit {F} frames x {P} points")
        pts.arrays[name] = arr
    det = Detections(F, C)
    det.offsets = members.read("detections/offsets.npy", specs["detections/offsets.npy"])
    if det.offsets.shape != (F * C + 1,) or np.any(np.diff(det.offsets) < 0):
        raise CaraFileError(path, "detections/offsets is inconsistent")
    for name in Detections.FIELDS:
        key = f"detections/{name}.npy"
        det.arrays[name] = members.read(key, specs[key])
        if len(det.arrays[name]) != det.offsets[-1]:
            raise CaraFileError(path, f"{key} has the wrong number of detections")
    project.detections = det
    cal = project.calibration
    cal.R = members.read("calibration/R.npy", specs["calibration/R.npy"])
    cal.t = members.read("calibration/t.npy", specs["calibration/t.npy"])
    cal.solved = members.read("calibration/solved.npy", specs["calibration/solved.npy"])
    if cal.R.shape != (F, C, 3, 3) or cal.t.shape != (F, C, 3) or cal.solved.shape != (F,):
        raise CaraFileError(path, "the calibration arrays do not fit the take")
    intr = m.get("intrinsics")
    if intr is not None:
        cal.intrinsics = CameraIntrinsics(**intr)
    project.labels = [str(x) for x in m.get("labels", [])]
    project.sticks = [Stick(int(a), int(b), tuple(col)) for a, b, col in m.get("sticks", [])]
    project.properties = Properties.from_dict(
        m.get("properties", {}), on_change=lambda keys: project.events.emit("properties")
    )
    project.current_frame = int(m.get("current_frame", 0))
    project.active_range = tuple(m.get("active_range", project.active_range))  # type: ignore[assignment]
    project.view_range = tuple(m.get("view_range", project.view_range))  # type: ignore[assignment]
    project.selection = Selection(
        points=frozenset(int(p) for p in m.get("selected_points", [])),
        cameras=frozenset(int(c) for c in m.get("selected_cameras", [])),
    )
    if m.get("rom"):
        project.rom = RomReference(path=str(m["rom"]))
    project.imported_blob_parameters = m.get("imported_blob_parameters")
    script = m.get("script")
    project.script = list(script) if isinstance(script, list) else None
    project.path = str(path.absolute())
    project.modified = False
    return project

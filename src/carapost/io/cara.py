"""The ``.cara`` project file: a ZIP container of ``manifest.json`` and ``.npy`` arrays.

Layout (format version 2)::

    manifest.json              metadata (see :func:`_manifest`)
    points/<name>.npy          per-point arrays [F, P, ...] (positions, recon, obs, ...)
    detections/offsets.npy     [F*C+1] int64 run offsets
    detections/<field>.npy     flat detection fields (centre, axes, angle, colour, score)
    calibration/R.npy, t.npy, solved.npy   per-frame extrinsics
    calibration/xcp_extras.json    optional: unknown content of an imported XCP file
    stabilization/transforms.npy           [F, 4, 4] float64, only in a stabilised project

Version 2 added the stabilisation (manifest ``stabilization`` + the transforms member),
the alignment (manifest ``alignment``) and ``show_stabilized``; a version-1 file opens
with none of them.

Members are stored uncompressed: the arrays are mostly noise-like floats that deflate
barely shrinks, and storing keeps save and open close to disk speed.

Saving is atomic: the project is written to a temporary file in the same folder,
flushed to disk with fsync and renamed over the target, so a crash or a full disk never
leaves a half-written project and a failed save never touches the original.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import mmap
import os
import struct
import threading
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
from carapost.io.atomic import atomic_output, check_input_file, checked_path, clean_stale_parts
from carapost.io.autosave import autosave_path
from carapost.io.cara_target_sizes import read_target_sizes, target_sizes_manifest
from carapost.io.errors import CaraFileError
from carapost.io.ziplimits import (
    MANIFEST_LIMIT,
    check_member,
    load_json,
    npy_spec,
    open_zip,
    parse_npy_header,
    read_member,
)
from carapost.model.project import (
    OPTIONAL_POINT_ARRAYS,
    POINT_ARRAYS,
    RAW_POINT_ARRAYS,
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

FORMAT_VERSION = 2
#: Optional member: the unknown content of the imported XCP calibration (JSON).
XCP_EXTRAS_MEMBER = "calibration/xcp_extras.json"

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
        "selected_points": project.selection.ordered_points(),  # in selection order
        "rom": project.rom.path if project.rom else None,
        "imported_blob_parameters": project.imported_blob_parameters,
        # optional: the Session calls that made the project (`carapost history --python`)
        **({"script": project.script} if project.script is not None else {}),
        # optional: per-track Target Tracker sizes, [point id, camera, pattern, search]
        **({"target_sizes": target_sizes_manifest(project)} if project.target_sizes else {}),
        "stabilization": None if project.stabilization is None
        else project.stabilization.to_manifest(),
        "alignment": None if project.alignment is None else project.alignment.to_manifest(),
        "show_stabilized": bool(project.show_stabilized),
    }


def _is_blank(arr: np.ndarray, fill: Any) -> bool:
    """Every value of ``arr`` is its array's fill value (NaN counts as NaN)."""
    if isinstance(fill, float) and math.isnan(fill):
        return bool(np.isnan(arr).all())
    return bool((arr == fill).all())


def _arrays(project: Project) -> dict[str, np.ndarray]:
    out: dict[str, np.ndarray] = {}
    # the raw values of filtered samples only when some are held: a file of a project
    # never filtered stays as it was (an absent member reads as blank)
    arrays = project.points.arrays
    keep_raw = any(not _is_blank(arrays[n], POINT_ARRAYS[n][1]) for n in RAW_POINT_ARRAYS)
    for name, arr in arrays.items():
        if name in RAW_POINT_ARRAYS and not keep_raw:
            continue
        out[f"points/{name}.npy"] = arr
    out["detections/offsets.npy"] = project.detections.offsets
    for name, arr in project.detections.arrays.items():
        out[f"detections/{name}.npy"] = arr
    cal = project.calibration
    out["calibration/R.npy"] = cal.R
    out["calibration/t.npy"] = cal.t
    out["calibration/solved.npy"] = cal.solved
    if project.stabilization is not None:
        out["stabilization/transforms.npy"] = np.asarray(project.stabilization.transforms,
                                                         np.float64)
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


def _is_folder(path: Path) -> bool:
    try:
        return path.is_dir()
    except OSError:  # a name too long: atomic_output says so
        return False


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
    path = checked_path(path)
    if not autosave and _is_folder(path):
        raise CaraFileError(path, "is a folder, not a file name")
    if not autosave and path.suffix.lower() != ".cara":
        path = path.with_name(path.name + ".cara")
    path = path.absolute()
    check_mapped_source(project)
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
        if project.calibration.xcp_extras is not None:
            # optional member: the unknown content of an imported XCP, written back on
            # export (older carapost versions ignore it)
            zf.writestr(XCP_EXTRAS_MEMBER, json.dumps(project.calibration.xcp_extras))
    if not autosave:
        previous = project.path
        project.path = str(path)
        project.modified = False
        project.events.emit("file")
        # the saved file is now the newest: autosave copies of this name, of the name
        # it had before a Save As, and of the never-saved project are all stale
        stale = [autosave_path(path), project.untitled_autosave]
        if previous and Path(previous).absolute() != path:
            stale.append(autosave_path(previous))
        for copy in stale:
            if copy is not None:
                with contextlib.suppress(OSError):
                    Path(copy).unlink(missing_ok=True)
        project.untitled_autosave = None
        project.session_autosave = None
        source = project.mapped_source
        if source is not None and Path(source[0]) == path:
            # the mapping keeps the replaced file's data alive, and no one can reach
            # that file by its name any more: nothing left to guard
            project.mapped_source = None
    log.info("Saved %s", path)
    return path


def check_mapped_source(project: Project) -> None:
    """Refuse to read the arrays of a project mapped from a file that changed since.

    Only projects larger than `PRIVATE_COPY_LIMIT` are mapped. If another program
    truncated or rewrote their file in place, reading the mapping would crash the
    process (truncation) or see other data; this check turns that into a clear error
    before a save or an autosave reads them.

    Raises
    ------
    CaraFileError
        Naming the file, when its size, modification time or identity changed.
    """
    source = project.mapped_source
    if source is None:
        return
    path, size, mtime_ns, ino = source
    try:
        st = os.stat(path)
        same = (st.st_size, st.st_mtime_ns, st.st_ino) == (size, mtime_ns, ino)
    except OSError:
        same = False
    if not same:
        raise CaraFileError(path, "was changed or removed by another program while open; the "
                                  "open project reads its arrays from it, so it can no longer "
                                  "be saved safely. Restore the file (or close without "
                                  "saving) and reopen it.")


# ----------------------------------------------------------------------------------------
# Loading
# ----------------------------------------------------------------------------------------
def _read_manifest(zf: zipfile.ZipFile, path: Path) -> dict[str, Any]:
    if "manifest.json" not in zf.NameToInfo:
        raise CaraFileError(path, "not a carapost project: manifest.json is missing")
    # bounded: the declared size is checked before inflating, the read stops at the limit
    raw = read_member(zf, path, "manifest.json", MANIFEST_LIMIT)
    manifest = load_json(path, raw, "manifest.json")
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


def _private_copy_limit() -> int:
    env = os.environ.get("CARAPOST_COPY_ON_OPEN_MB")
    if env and env.strip().isdigit():
        return int(env) << 20
    try:
        ram = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (OSError, ValueError, AttributeError):
        ram = 16 << 30
    return int(min(4 << 30, ram // 4))


#: Projects up to this size (4 GiB, or a quarter of the memory if less;
#: ``CARAPOST_COPY_ON_OPEN_MB`` overrides, 0 maps every project) are read into private
#: memory at open (copy-on-open); larger ones are mapped copy-on-write (see
#: `load_project`).
PRIVATE_COPY_LIMIT = _private_copy_limit()

_NPY_HEADER_MAX = 1 << 16
#: Private reads of members bigger than this wait for `_Members.verify` (bytes).
_DEFERRED_READ = 8 << 20
#: Read and checksum step (bytes).
_CHUNK = 1 << 24


class _Members:
    """Arrays of a project file, read into private memory or mapped copy-on-write.

    Members are stored uncompressed, so each ``.npy`` payload is a contiguous run of the
    file. With ``private`` (the default up to `PRIVATE_COPY_LIMIT`) every array is read
    into memory of its own: the open project no longer depends on its file, which may then
    be truncated, overwritten or deleted by anyone. Otherwise it is mapped privately (edits
    stay in memory, the file is never written) and pages come in as they are used. Every
    member's CRC-32 is checked, on both cores, before the project is handed out.
    Deflated members (a project re-zipped by another tool) are inflated with their size
    and shape checked first.
    """

    def __init__(self, zf: zipfile.ZipFile, path: Path, *, private: bool | None = None) -> None:
        self.zf = zf
        self.path = path
        self._fh = open(path, "rb")  # closed in close()
        self._lock = threading.Lock()
        self.size = os.fstat(self._fh.fileno()).st_size
        if private is None:
            private = self.size <= PRIVATE_COPY_LIMIT
        self.private = private
        self._map: mmap.mmap | None = None
        if not private:
            try:
                self._map = mmap.mmap(self._fh.fileno(), 0, access=mmap.ACCESS_COPY)
            except (OSError, ValueError):  # empty file or a file system without mmap
                self._map = None
        # (name, expected CRC, buffers whose concatenation is the member's bytes)
        self._checks: list[tuple[str, int, list[Any]]] = []
        # deferred private reads: (name, expected CRC, npy header, destination, offset)
        self._reads: list[tuple[str, int, bytes, memoryview, int]] = []

    @property
    def mapped(self) -> bool:
        """Arrays are views of the file's mapping (not private copies)."""
        return self._map is not None

    def close(self) -> None:
        self._fh.close()  # the mapping stays valid on its own

    def _pread(self, offset: int, n: int) -> bytes:
        if hasattr(os, "pread"):
            return os.pread(self._fh.fileno(), n, offset)
        with self._lock:  # Windows: no positional reads, one file position for all
            self._fh.seek(offset)
            return self._fh.read(n)

    def _preadv(self, view: memoryview, offset: int) -> int:
        if hasattr(os, "preadv"):
            return os.preadv(self._fh.fileno(), [view], offset)
        with self._lock:
            self._fh.seek(offset)
            return self._fh.readinto(view) or 0

    def _payload(self, info: zipfile.ZipInfo) -> tuple[int, int]:
        """Start and end (file offsets) of a stored member's bytes."""
        header = self._pread(info.header_offset, 30)
        if len(header) != 30 or header[:4] != b"PK\x03\x04":
            raise CaraFileError(self.path, f"the member {info.filename} is damaged "
                                           "(bad local header)")
        n_name, n_extra = struct.unpack("<HH", header[26:30])
        start = info.header_offset + 30 + n_name + n_extra
        return start, start + info.compress_size

    def read(self, name: str, spec: dict[str, Any]) -> np.ndarray:
        """The array of member ``name``, checked against the manifest's ``spec``."""
        path = self.path
        shape, dtype = npy_spec(path, name, spec)
        nbytes = math.prod(shape) * dtype.itemsize
        try:
            info = self.zf.getinfo(name)
        except KeyError:
            raise CaraFileError(path, f"the array {name} is missing") from None
        # sizes from the directory, checked before anything is allocated or inflated
        check_member(path, info, nbytes + _NPY_HEADER_MAX)
        if info.file_size < nbytes:
            raise CaraFileError(path, f"the array {name} is {info.file_size:,} bytes, too "
                                      f"small for {dtype}{list(shape)}")
        try:
            if info.compress_type == zipfile.ZIP_STORED:
                arr = self._read_stored(name, info, shape, dtype, nbytes)
            else:
                arr = self._read_deflated(name, info, shape, dtype, nbytes)
        except CaraFileError:
            raise
        except MemoryError:
            raise CaraFileError(path, f"the array {name} ({nbytes:,} bytes) does not fit in "
                                      "memory") from None
        except Exception as exc:
            raise CaraFileError(path, f"the array {name} is damaged ({exc})") from None
        return arr

    def _check_header(self, name: str, got: tuple[tuple[int, ...], np.dtype[Any]],
                      shape: tuple[int, ...], dtype: np.dtype[Any]) -> None:
        if got[0] != shape or got[1] != dtype:
            raise CaraFileError(
                self.path, f"the array {name} is {got[1]}{list(got[0])}, the manifest says "
                           f"{dtype}{list(shape)}")

    def _read_stored(self, name: str, info: zipfile.ZipInfo, shape: tuple[int, ...],
                     dtype: np.dtype[Any], nbytes: int) -> np.ndarray:
        start, end = self._payload(info)
        if end > self.size:
            raise CaraFileError(self.path, f"the array {name} is truncated")
        head = self._pread(start, min(_NPY_HEADER_MAX, end - start))
        got_shape, got_dtype, hlen = parse_npy_header(head)
        self._check_header(name, (got_shape, got_dtype), shape, dtype)
        if start + hlen + nbytes != end:
            raise CaraFileError(self.path, f"the array {name} is damaged (its size does not "
                                           "match its header)")
        count = math.prod(shape)
        if self._map is not None:
            arr = np.frombuffer(self._map, dtype=dtype, count=count,
                                offset=start + hlen).reshape(shape)
            self._checks.append((name, info.CRC, [memoryview(self._map)[start:end]]))
            return arr
        arr = np.empty(shape, dtype=dtype)
        flat = memoryview(arr.reshape(-1).view(np.uint8)) if arr.size else memoryview(b"")
        if nbytes > _DEFERRED_READ:
            # read in verify(), on two threads together with the CRC (only shapes of
            # the big arrays are looked at before that)
            self._reads.append((name, info.CRC, head[:hlen], flat, start + hlen))
            return arr
        if self._pread_into(name, flat, start + hlen, zlib.crc32(head[:hlen])) != info.CRC:
            raise CaraFileError(self.path, f"the array {name} is damaged (checksum mismatch)")
        return arr

    def _pread_into(self, name: str, flat: memoryview, pos: int, crc: int = 0) -> int:
        """Fill ``flat`` from file offset ``pos``; returns the CRC-32 of what was read
        (continuing ``crc``)."""
        done = 0
        while done < len(flat):
            n = self._preadv(flat[done:done + _CHUNK], pos + done)
            if n <= 0:
                raise CaraFileError(self.path, f"the array {name} is truncated")
            crc = zlib.crc32(flat[done:done + n], crc)
            done += n
        return crc

    def _read_deflated(self, name: str, info: zipfile.ZipInfo, shape: tuple[int, ...],
                       dtype: np.dtype[Any], nbytes: int) -> np.ndarray:
        with self.zf.open(info) as fh:
            # the header is read (a few hundred bytes inflated) and checked first
            got_shape, got_dtype, hlen = parse_npy_header(fh)
            self._check_header(name, (got_shape, got_dtype), shape, dtype)
            if info.file_size != hlen + nbytes:
                raise CaraFileError(self.path, f"the array {name} is damaged (its size does "
                                               "not match its header)")
            arr = np.empty(shape, dtype=dtype)
            flat = memoryview(arr.reshape(-1).view(np.uint8)) if arr.size else None
            done = 0
            while flat is not None and done < nbytes:
                n = fh.readinto(flat[done:done + (1 << 26)])
                if not n:
                    raise CaraFileError(self.path, f"the array {name} is truncated")
                done += n
            if fh.read(1):  # also makes zipfile check the CRC-32 at the end
                raise CaraFileError(self.path, f"the array {name} is longer than its header")
        return arr

    def verify(self) -> None:
        """Read the deferred arrays and check the CRC-32 of every member (preadv and zlib
        release the GIL: two threads, biggest members first)."""
        if not self._checks and not self._reads:
            return

        def crc(item: tuple[str, int, list[Any]]) -> tuple[str, bool]:
            name, expected, parts = item
            value = 0
            for part in parts:
                view = memoryview(part)
                for a in range(0, len(view), _CHUNK):
                    value = zlib.crc32(view[a : a + _CHUNK], value)
            return name, value == expected

        def read(item: tuple[str, int, bytes, memoryview, int]) -> tuple[str, bool]:
            name, expected, head, flat, pos = item
            # the CRC of the header, continued over the payload as it comes in
            return name, self._pread_into(name, flat, pos, zlib.crc32(head)) == expected

        tasks: list[tuple[int, Callable[[Any], tuple[str, bool]], Any]] = [
            (sum(len(memoryview(p)) for p in c[2]), crc, c) for c in self._checks]
        tasks += [(len(r[3]), read, r) for r in self._reads]
        tasks.sort(key=lambda t: -t[0])
        with ThreadPoolExecutor(max_workers=2) as pool:
            results = list(pool.map(lambda t: t[1](t[2]), tasks))
        self._checks.clear()
        self._reads.clear()
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


def load_project(path: str | Path, *, relocate: RelocateCallback | None = None,
                 private: bool | None = None) -> Project:
    """Open a ``.cara`` project.

    Parameters
    ----------
    path : str or Path
    relocate : callable, optional
        Asked for a camera video that is neither at its saved absolute path nor beside
        the project: ``relocate(camera_name, missing_path) -> new path or None``.
    private : bool, optional
        Read every array into memory of the project's own (True), or map the file
        copy-on-write (False). By default projects up to `PRIVATE_COPY_LIMIT` bytes are
        read (the open project then survives its file being truncated or overwritten);
        larger ones are mapped, which opens faster and shares the page cache.

    Returns
    -------
    Project

    Raises
    ------
    CaraFileError
        Missing, truncated, corrupt or foreign files, and projects of a newer format.
    """
    path = Path(path)
    check_input_file(path)
    clean_stale_parts(path)
    zf = open_zip(path)
    with zf:
        manifest = _read_manifest(zf, path)
        try:
            members = _Members(zf, path, private=private)
        except OSError as exc:
            raise CaraFileError(path, f"cannot be read: {exc.strerror or exc}") from None
        try:
            project = _build(members, manifest, path, relocate)
            members.verify()
            if members.mapped:
                # saves check that the file under the mapping did not change (see
                # check_mapped_source)
                st = os.stat(path)
                source = (str(path.absolute()), st.st_size, st.st_mtime_ns, st.st_ino)
                project.mapped_source = source
            return project
        except CaraFileError:
            raise
        except MemoryError:
            raise CaraFileError(path, "the project does not fit in memory") from None
        except RecursionError:
            raise CaraFileError(path, "the manifest is nested too deeply") from None
        except Exception as exc:
            raise CaraFileError(path, f"the manifest is inconsistent ({exc!r:.200})") from None
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
    if XCP_EXTRAS_MEMBER in members.zf.NameToInfo:
        raw = read_member(members.zf, path, XCP_EXTRAS_MEMBER, MANIFEST_LIMIT)
        cal.xcp_extras = load_json(path, raw, XCP_EXTRAS_MEMBER)
    project.labels = [str(x) for x in m.get("labels", [])]
    project.sticks = [Stick(int(a), int(b), tuple(col)) for a, b, col in m.get("sticks", [])]
    project.properties = Properties.from_dict(
        m.get("properties", {}), on_change=lambda keys: project.events.emit("properties")
    )
    project.current_frame = int(m.get("current_frame", 0))
    project.active_range = tuple(m.get("active_range", project.active_range))  # type: ignore[assignment]
    project.view_range = tuple(m.get("view_range", project.view_range))  # type: ignore[assignment]
    selected = tuple(dict.fromkeys(int(p) for p in m.get("selected_points", [])))
    project.selection = Selection(
        points=frozenset(selected),
        cameras=frozenset(int(c) for c in m.get("selected_cameras", [])),
        order=selected,
    )
    if m.get("rom"):
        project.rom = RomReference(path=str(m["rom"]))
    project.imported_blob_parameters = m.get("imported_blob_parameters")
    script = m.get("script")
    project.script = list(script) if isinstance(script, list) else None
    _build_stabilization(project, members, m, path)
    read_target_sizes(project, m.get("target_sizes"))
    project.path = str(path.absolute())
    project.modified = False
    return project


def _build_stabilization(project: Project, members: _Members, m: dict[str, Any],
                         path: Path) -> None:
    """Format 2: the stabilisation, alignment and Show Stabilized (absent in format 1)."""
    from carapost.model.stabilization import Alignment, Stabilization

    F = project.n_frames
    st = m.get("stabilization")
    if st is not None:
        key = "stabilization/transforms.npy"
        T = members.read(key, m["arrays"][key])
        if T.shape != (F, 4, 4):
            raise CaraFileError(path, f"{key} does not fit {F} frames")
        project.stabilization = Stabilization.from_manifest(st, T)
    if m.get("alignment") is not None:
        project.alignment = Alignment.from_manifest(m["alignment"])
    project.show_stabilized = bool(m.get("show_stabilized", False))

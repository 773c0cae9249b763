"""Import Camera Files: build a project from the per-camera files of one take.

A take is a set of files side by side in one folder::

    <take>_<channel>.mkv        one per camera; any of .mkv .mp4 .avi .mov
    <take>_<channel>/           ... or an image-sequence folder (.png .tif .jpg)
    <take>.json                 optional metadata (frame rate, start timecode, logger)
    <take>.xcp                  optional calibration (Vicon XCP)
    <take>_labels.txt           optional label list
    <take>_brim.csv             optional brim model: label,x,y,z in mm

The channel is the part after the last underscore, so take names may contain
underscores but channel names may not. Channels are ordered naturally (``cam2`` before
``cam10``).

``<take>.json`` is a JSON object; every key is optional and all are kept in
``take.metadata``. Keys carapost reads: ``fps`` (or ``frame_rate``), ``timecode_start``
(``"HH:MM:SS:FF"``, or ``start_timecode``), ``logger_name`` and ``logger_id`` (or
``logger: {"name", "id"}``), ``frames`` (checked against the videos),
``blob_parameters`` (object: the detector settings of the capture, used by Read Blob
Parameters From Pico Files) and ``cameras`` (object: channel -> ``{"frame_offset": int,
"rotation": 0|90|180|270}``).

Vicon's ``.pico`` files cannot be imported: the container is proprietary and
undocumented. Importing one raises `CaraFileError` saying how to supply the take instead.
"""

from __future__ import annotations

import csv
import logging
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from carapost.io.atomic import check_input_file
from carapost.io.errors import CaraFileError
from carapost.io.labels import merge_labels, read_label_file
from carapost.io.timecode import Timecode
from carapost.io.video import (
    IMAGE_EXTENSIONS,
    VIDEO_EXTENSIONS,
    VideoSource,
    image_sequence_files,
    natural_key,
)
from carapost.io.xcp import read_xcp
from carapost.io.ziplimits import load_json
from carapost.model.project import CameraChannel, Project, Take

log = logging.getLogger("carapost.io")

__all__ = [
    "DEFAULT_FPS",
    "IMAGE_EXTENSIONS",
    "PICO_MESSAGE",
    "VIDEO_EXTENSIONS",
    "TakeFiles",
    "find_take_files",
    "import_take",
    "read_brim_csv",
    "read_take_metadata",
]

#: Frame rate used when neither the metadata nor the videos give one.
DEFAULT_FPS = 60.0

#: Why a ``.pico`` file is refused and what to do instead.
PICO_MESSAGE = (
    "is a Vicon .pico file. The .pico container is Vicon's proprietary, undocumented "
    "format and carapost cannot read it. Export the take's camera videos from Vicon's "
    "software (or convert them) to one file per camera named <take>_<channel>.mkv "
    "(or .mp4/.avi/.mov, or image-sequence folders <take>_<channel>/ of .png/.tif/.jpg), "
    "optionally with <take>.json (frame rate, start timecode) and <take>.xcp "
    "(calibration) beside them, and import one of those files or their folder."
)

#: Called with (what, missing path) for a path that does not exist; returns a
#: replacement path or None.
RelocateCallback = Callable[[str, str], "str | None"]

#: Largest take metadata file read (bytes).
_TEXT_LIMIT = 64 << 20

_CHANNEL_FILE = re.compile(r"^(?P<take>.+)_(?P<channel>[^_]+)$")


@dataclass
class TakeFiles:
    """The files of one take found on disk.

    Attributes
    ----------
    name : str
        Take name (the ``<take>`` stem).
    folder : Path
        Folder holding the take.
    channels : list of str
        Channel names in natural order.
    videos : list of Path
        Video file or image-sequence folder of each channel.
    json : Path or None
        ``<take>.json`` when present.
    xcp : Path or None
        ``<take>.xcp`` when present.
    labels : Path or None
        ``<take>_labels.txt`` when present.
    brim_csv : Path or None
        ``<take>_brim.csv`` when present.
    """

    name: str
    folder: Path
    channels: list[str] = field(default_factory=list)
    videos: list[Path] = field(default_factory=list)
    json: Path | None = None
    xcp: Path | None = None
    labels: Path | None = None
    brim_csv: Path | None = None


def _is_sequence_dir(path: Path) -> bool:
    return path.is_dir() and bool(image_sequence_files(path))


def _channel_candidates(folder: Path) -> dict[str, dict[str, list[Path]]]:
    """take -> channel -> candidate files/folders, for everything in ``folder``."""
    found: dict[str, dict[str, list[Path]]] = {}
    try:
        entries = sorted(folder.iterdir(), key=lambda p: natural_key(p.name))
    except OSError as exc:
        raise CaraFileError(folder, f"cannot be listed ({exc.strerror or exc})") from None
    for entry in entries:
        if entry.name.startswith("."):  # hidden and partial files of a writer at work
            continue
        if entry.is_file() and entry.suffix.lower() in VIDEO_EXTENSIONS:
            stem = entry.stem
        elif entry.is_dir() and _is_sequence_dir(entry):
            stem = entry.name
        else:
            continue
        m = _CHANNEL_FILE.match(stem)
        if m is None:
            continue
        found.setdefault(m["take"], {}).setdefault(m["channel"], []).append(entry)
    return found


def _pick(channel: str, options: list[Path]) -> Path:
    if len(options) == 1:
        return options[0]
    # Prefer lossless containers, then folders of (lossless) images.
    order = {".mkv": 0, ".avi": 2, ".mov": 3, ".mp4": 4}

    def rank(p: Path) -> int:
        return 1 if p.is_dir() else order.get(p.suffix.lower(), 5)

    chosen = sorted(options, key=rank)[0]
    log.warning("Channel %s has several files (%s); using %s", channel,
                ", ".join(p.name for p in options), chosen.name)
    return chosen


def find_take_files(path: str | Path) -> TakeFiles:
    """Find every file of the take that ``path`` belongs to.

    Parameters
    ----------
    path : str or Path
        One camera file ``<take>_<channel>.<ext>``, an image-sequence folder
        ``<take>_<channel>/``, the take's ``.json`` or ``.xcp``, or the folder holding
        exactly one take.

    Returns
    -------
    TakeFiles

    Raises
    ------
    CaraFileError
        For a missing path, a ``.pico`` file, a file that is not part of a take, a folder
        without camera files or with several takes.
    """
    path = Path(path)
    if path.suffix.lower() == ".pico":
        raise CaraFileError(path, PICO_MESSAGE)
    if not path.exists():
        raise CaraFileError(path, "no such file or folder")
    path = path.absolute()
    take: str | None = None
    if path.is_dir() and not _is_sequence_dir(path):
        folder = path
    else:
        folder = path.parent
        stem = path.name if path.is_dir() else path.stem
        suffix = "" if path.is_dir() else path.suffix.lower()
        if suffix in (".json", ".xcp"):
            take = stem
        elif path.is_dir() or suffix in VIDEO_EXTENSIONS:
            m = _CHANNEL_FILE.match(stem)
            if m is None:
                raise CaraFileError(
                    path, "is not named like a camera file of a take, <take>_<channel>"
                    + (suffix or "/"))
            take = m["take"]
        else:
            raise CaraFileError(
                path, "is not a camera file: expected a video (" + ", ".join(VIDEO_EXTENSIONS)
                + "), an image-sequence folder, the take's .json/.xcp, or a folder")
    candidates = _channel_candidates(folder)
    if take is None:
        if not candidates:
            picos = sorted(folder.glob("*.pico")) + sorted(folder.glob("*.PICO"))
            if picos:
                raise CaraFileError(picos[0], PICO_MESSAGE)
            raise CaraFileError(
                folder, "holds no camera files named <take>_<channel> with extension "
                + ", ".join(VIDEO_EXTENSIONS) + " (or image-sequence folders)")
        if len(candidates) > 1:
            names = ", ".join(sorted(candidates, key=natural_key))
            raise CaraFileError(
                folder, f"holds several takes ({names}); import one of their files instead")
        take = next(iter(candidates))
    channels_found = candidates.get(take, {})
    if not channels_found:
        picos = sorted(folder.glob(f"{take}_*.pico"))
        if picos:
            raise CaraFileError(picos[0], PICO_MESSAGE)
        raise CaraFileError(path, f"no camera files {take}_<channel>.<ext> were found beside it")
    channels = sorted(channels_found, key=natural_key)
    files = TakeFiles(name=take, folder=folder, channels=channels,
                      videos=[_pick(c, channels_found[c]) for c in channels])
    for attr, name in (("json", f"{take}.json"), ("xcp", f"{take}.xcp"),
                       ("labels", f"{take}_labels.txt"), ("brim_csv", f"{take}_brim.csv")):
        p = folder / name
        if p.is_file():
            setattr(files, attr, p)
    return files


def read_take_metadata(path: str | Path) -> dict[str, Any]:
    """Read and check ``<take>.json``.

    Returns
    -------
    dict
        The JSON object, with ``fps`` (float) and ``timecode_start`` (str) normalised
        when present.

    Raises
    ------
    CaraFileError
        If the file is not a JSON object or a known key has a bad value.
    """
    path = Path(path)
    check_input_file(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise CaraFileError(path, f"cannot be read ({exc.strerror or exc})") from None
    if len(raw) > _TEXT_LIMIT:
        raise CaraFileError(path, f"is {len(raw):,} bytes, too large for take metadata")
    meta = load_json(path, raw, "")
    if not isinstance(meta, dict):
        raise CaraFileError(path, "must hold a JSON object of take metadata")
    for alias in ("frame_rate", "rate"):
        if "fps" not in meta and alias in meta:
            meta["fps"] = meta.pop(alias)
    if "fps" in meta:
        fps = meta["fps"]
        if isinstance(fps, bool) or not isinstance(fps, int | float) or not 0 < fps <= 10_000:
            raise CaraFileError(path, f"fps must be a positive number, got {fps!r}")
        meta["fps"] = float(fps)
    for alias in ("start_timecode", "timecode"):
        if "timecode_start" not in meta and alias in meta:
            meta["timecode_start"] = meta.pop(alias)
    if "timecode_start" in meta:
        try:
            meta["timecode_start"] = str(Timecode.parse(str(meta["timecode_start"])))
        except ValueError as exc:
            raise CaraFileError(path, f"timecode_start: {exc}") from None
    logger = meta.get("logger")
    if isinstance(logger, dict):  # {"logger": {"name": ..., "id": ...}}
        meta.setdefault("logger_name", logger.get("name"))
        meta.setdefault("logger_id", logger.get("id"))
    cams = meta.get("cameras", {})
    if not isinstance(cams, dict) or not all(isinstance(v, dict) for v in cams.values()):
        raise CaraFileError(path, "cameras must map channel names to objects")
    for name, spec in cams.items():
        off = spec.get("frame_offset", 0)
        rot = spec.get("rotation", 0)
        if isinstance(off, bool) or not isinstance(off, int):
            raise CaraFileError(path, f"cameras.{name}.frame_offset must be an integer")
        if isinstance(rot, bool) or rot not in (0, 90, 180, 270):
            raise CaraFileError(path, f"cameras.{name}.rotation must be 0, 90, 180 or 270")
    if "blob_parameters" in meta and not isinstance(meta["blob_parameters"], dict):
        raise CaraFileError(path, "blob_parameters must be a JSON object")
    return meta


def read_brim_csv(path: str | Path) -> tuple[list[str], NDArray[np.float64]]:
    """Read a brim model: one marker per line, ``label,x,y,z`` in millimetres.

    A first line whose coordinates are not numbers (e.g. ``label,x,y,z``) is taken as a
    header; blank lines and lines starting with ``#`` are skipped.

    Returns
    -------
    labels : list of str, length B
    xyz : ndarray, shape (B, 3) float64
        Marker positions (mm) in the brim's frame.

    Raises
    ------
    CaraFileError
        If the file cannot be read, a row is malformed (the message names the line),
        labels repeat, or it holds no marker.
    """
    path = Path(path)
    check_input_file(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except OSError as exc:
        raise CaraFileError(path, f"cannot be read ({exc.strerror or exc})") from None
    except UnicodeDecodeError:
        raise CaraFileError(path, "is not a text file") from None
    if "\0" in text:
        raise CaraFileError(path, "is not a text file (it contains binary data)")
    labels: list[str] = []
    seen: set[str] = set()  # a set: checking each label against a list was quadratic
    rows: list[list[float]] = []
    first = True
    reader = csv.reader(text.splitlines())
    while True:
        try:
            row = next(reader)
        except StopIteration:
            break
        except csv.Error as exc:
            raise CaraFileError(path, f"line {reader.line_num}: {exc}") from None
        lineno = reader.line_num
        cells = [c.strip() for c in row]
        if not cells or not any(cells) or cells[0].startswith("#"):
            continue
        if len(cells) != 4:
            raise CaraFileError(path, f"line {lineno}: expected label,x,y,z, got {len(cells)} "
                                "fields")
        try:
            xyz = [float(c) for c in cells[1:]]
        except ValueError:
            if first:  # header
                first = False
                continue
            raise CaraFileError(path, f"line {lineno}: x, y, z must be numbers, got "
                                f"{', '.join(cells[1:])}") from None
        first = False
        if not cells[0]:
            raise CaraFileError(path, f"line {lineno}: the label is empty")
        if not np.all(np.isfinite(xyz)):
            raise CaraFileError(path, f"line {lineno}: coordinates must be finite")
        if cells[0] in seen:
            raise CaraFileError(path, f"line {lineno}: label {cells[0]!r} appears twice")
        seen.add(cells[0])
        labels.append(cells[0])
        rows.append(xyz)
    if not rows:
        raise CaraFileError(path, "holds no brim markers (expected lines label,x,y,z)")
    return labels, np.asarray(rows, dtype=np.float64)


def _load_calibration(project: Project, xcp_path: Path) -> None:
    xcp = read_xcp(xcp_path)
    take = project.take
    names = [c.name for c in take.cameras]
    C = take.n_cameras
    if xcp.n_cameras != C:
        raise CaraFileError(
            xcp_path, f"holds {xcp.n_cameras} cameras but the take has {C} ({', '.join(names)})")
    xnames = list(xcp.intrinsics.names)
    if sorted(xnames) == sorted(names):
        order = np.array([xnames.index(n) for n in names], dtype=np.intp)
    else:
        order = np.arange(C)
        log.info("%s: camera names %s do not match the channels; matching by order",
                 xcp_path.name, ", ".join(xnames))
    intr = xcp.intrinsics.subset(order)
    intr.names = list(names)
    for c, cam in enumerate(take.cameras):
        if tuple(int(v) for v in intr.image_size[c]) != tuple(cam.image_size):
            log.warning("%s: camera %s is %dx%d in the calibration but %dx%d in the video",
                        xcp_path.name, cam.name, *intr.image_size[c], *cam.image_size)
    cal = project.calibration
    F = take.n_frames
    R, t = xcp.extrinsics_at(np.arange(F))
    cal.intrinsics = intr
    cal.R[:] = R[:, order]
    cal.t[:] = t[:, order]
    # A frame is covered once every camera's first KeyFrame is in force.
    first = max(int(xcp.keyframes[c][0]) for c in range(C))
    cal.solved[:] = np.arange(F) >= first
    cal.xcp_extras = xcp.extras
    for note in xcp.notes:
        log.info("%s: %s", xcp_path.name, note)


def _import_blob_parameters(project: Project, given: object) -> None:
    """Apply the take's blob parameters (if it has any) and remember the ones in force.

    Read Blob Parameters From Take Files goes back to exactly these values later.
    """
    from carapost.model.properties import BLOB, PropertyError

    keys = project.properties.section(BLOB)
    if isinstance(given, dict):
        values = {k: v for k, v in given.items() if k in keys}
        ignored = sorted(set(given) - set(values))
        if ignored:
            log.warning("Ignoring unknown blob parameters in the take metadata: %s",
                        ", ".join(map(str, ignored)))
        try:
            project.properties.update(values)
        except PropertyError as exc:
            log.warning("Blob parameters of the take ignored: %s", exc)
    project.imported_blob_parameters = project.properties.section(BLOB)



def _open_videos(videos: list[Path]) -> list[VideoSource]:
    """Open and check every camera video at once (closed again on return).

    Opening builds each video's keyframe index (a pass over the file that FFmpeg does
    without holding Python's GIL: ~3 s of CPU for 36,000 frames of 1280x720) and checks
    that its last frame decodes, so the cameras are done on parallel threads. The first
    camera in order that fails raises its `CaraFileError`.
    """
    from concurrent.futures import ThreadPoolExecutor

    def one(video: Path) -> VideoSource:
        src = VideoSource(video)
        try:
            src.verify_frame_count()
        finally:
            src.close()
        return src

    with ThreadPoolExecutor(max_workers=max(1, min(len(videos), 4)),
                            thread_name_prefix="carapost-import") as pool:
        futures = [pool.submit(one, v) for v in videos]
    return [f.result() for f in futures]

def import_take(path: str | Path, *, relocate: RelocateCallback | None = None) -> Project:
    """Import Camera Files: a new project from the camera files of one take.

    Parameters
    ----------
    path : str or Path
        One camera file of the take, its image-sequence folder, its ``.json``/``.xcp``
        or the folder holding the take (see `find_take_files`).
    relocate : callable, optional
        Asked when ``path`` does not exist: ``relocate("take", missing_path) -> new
        path or None`` (a GUI shows a file dialog).

    Returns
    -------
    Project
        A project with one camera per channel, ``n_frames`` = the frame range every
        camera covers, frame rate and start timecode from ``<take>.json`` (else the
        videos' frame rate, else 60 fps with a warning), calibration from ``<take>.xcp``
        and labels from ``<take>_labels.txt`` when present. ``take.metadata`` holds the
        JSON metadata plus ``take_folder`` and ``brim_file``.

    Raises
    ------
    CaraFileError
        For ``.pico`` files, missing or unreadable camera files (naming the file), and
        bad metadata, calibration or label files.
    """
    path = Path(path)
    if not path.exists() and path.suffix.lower() != ".pico" and relocate is not None:
        new = relocate("take", str(path))
        if new:
            path = Path(new)
    files = find_take_files(path)
    meta = read_take_metadata(files.json) if files.json else {}
    cam_meta: dict[str, dict[str, Any]] = meta.get("cameras", {})

    sources = _open_videos(files.videos)
    counts = [s.n_frames for s in sources]
    n_frames = min(counts)
    if isinstance(meta.get("frames"), int) and meta["frames"] != max(counts):
        log.warning("Take %s: %s.json says %d frames, the videos hold %s", files.name,
                    files.name, meta["frames"], "/".join(str(n) for n in counts))
    if len(set(counts)) > 1:
        detail = ", ".join(f"{c} {n}" for c, n in zip(files.channels, counts, strict=True))
        log.warning("Take %s: the cameras have different frame counts (%s); using the "
                    "common range of %d frames", files.name, detail, n_frames)

    fps = meta.get("fps")
    if fps is None:
        rates = sorted({round(s.fps, 6) for s in sources if s.fps > 0})
        if rates:
            fps = rates[0]
            if len(rates) > 1:
                log.warning("Take %s: the videos have different frame rates (%s); using %g",
                            files.name, ", ".join(f"{r:g}" for r in rates), fps)
        else:
            fps = DEFAULT_FPS
            log.warning("Take %s: no frame rate in the metadata or the videos; assuming %g "
                        "fps (add \"fps\" to %s.json)", files.name, fps, files.name)

    cameras = []
    for name, video, src in zip(files.channels, files.videos, sources, strict=True):
        spec = cam_meta.get(name, {})
        cameras.append(CameraChannel(
            name=name, video_path=str(video.resolve()), image_size=src.size,
            rotation=int(spec.get("rotation", 0)),
            frame_offset=int(spec.get("frame_offset", 0)),
        ))
    metadata = dict(meta)
    metadata.pop("fps", None)
    metadata.pop("timecode_start", None)
    metadata["take_folder"] = str(files.folder)
    if files.brim_csv is not None:
        read_brim_csv(files.brim_csv)  # refuse a bad brim model now, not mid-pipeline
        metadata["brim_file"] = str(files.brim_csv)
    take = Take(
        name=files.name,
        cameras=cameras,
        n_frames=n_frames,
        fps=float(fps),
        timecode_start=meta.get("timecode_start", "00:00:00:00"),
        metadata=metadata,
    )
    project = Project(take)
    if files.xcp is not None:
        _load_calibration(project, files.xcp)
    if files.labels is not None:
        project.labels = merge_labels([], read_label_file(files.labels))
    _import_blob_parameters(project, meta.get("blob_parameters"))
    project.modified = True
    log.info("Imported take %s: %d cameras (%s), %d frames at %g fps", files.name,
             len(cameras), ", ".join(files.channels), n_frames, take.fps)
    return project


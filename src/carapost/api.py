"""The scripting API: everything the File and Process menus do, without Qt.

Use it from a script or a notebook::

    from carapost import api

    project = api.import_take("takes/Speech01_cam0.mkv")
    api.save_project(project, "Speech01.cara")
    api.export_c3d(project, "Speech01.c3d", frame_range="active")
    print(api.evaluate("Speech01.cara", "takes/truth.npz"))

Errors the user can fix raise `CaraFileError` (a file is missing, unreadable or cannot
be written; the message names it) or `ValueError` (a bad option or a project that has
nothing to export). Exports are written atomically, so a failed export never leaves a
partial file behind.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from carapost.commands.stack import Command, CommandError, CommandStack, Journal
from carapost.io import cara
from carapost.io.atomic import check_output_path
from carapost.io.errors import CaraFileError
from carapost.io.take_import import import_take as _import_take
from carapost.io.take_import import read_brim_csv
from carapost.model.project import (
    KIND_BRIM,
    KIND_FACE,
    RECON_FILTERED,
    RECON_INTERPOLATED,
    Project,
)
from carapost.pipeline import process_take
from carapost.synth.scoring import MATCH_GATE_MM, score_tracks

log = logging.getLogger("carapost.api")

__all__ = [
    "RelocateFiles",
    "evaluate",
    "export_c3d",
    "export_fbx",
    "export_xcp",
    "import_take",
    "missing_files",
    "open_project",
    "process_take",
    "relocate_files",
    "save_project",
]

#: Called with (camera name, missing path); returns a replacement path or None.
RelocateCallback = Callable[[str, str], "str | None"]

# ----------------------------------------------------------------------------------------
# Projects
# ----------------------------------------------------------------------------------------


def open_project(path: str | Path, *, relocate: RelocateCallback | None = None) -> Project:
    """Open a ``.cara`` project.

    Camera videos that moved are looked for beside the project first, then
    ``relocate(camera_name, missing_path)`` is asked (see `relocate_files` to fix them
    afterwards).

    Raises
    ------
    CaraFileError
        Missing, damaged or foreign files and projects of a newer format.
    """
    return cara.load_project(path, relocate=relocate)


def save_project(project: Project, path: str | Path) -> Path:
    """Save a project atomically (``.cara`` is appended when missing); returns the path."""
    return cara.save_project(project, path)


def import_take(path: str | Path, *, relocate: RelocateCallback | None = None) -> Project:
    """Import Camera Files: a new project from one file (or the folder) of a take.

    See `carapost.io.take_import.import_take` for the files a take is made of. When the
    take carries its brim model (``<take>_brim.csv``), the project starts with those
    brim points, ready for Solve Calibration Brim.
    """
    project = _import_take(path, relocate=relocate)
    brim_file = project.take.metadata.get("brim_file")
    if brim_file:
        from carapost.commands.process import SetBrimModel

        labels, xyz = read_brim_csv(brim_file)
        SetBrimModel(labels, xyz, description="Calibration brim of the take").do(project)
        log.info("Brim model of the take: %d dots from %s", len(xyz), brim_file)
    return project


# ----------------------------------------------------------------------------------------
# Relocate Files
# ----------------------------------------------------------------------------------------


def missing_files(project: Project) -> dict[str, str]:
    """Cameras whose video file or folder does not exist: ``{camera name: path}``."""
    return {
        cam.name: cam.video_path
        for cam in project.take.cameras
        if not cam.video_path or not Path(cam.video_path).exists()
    }


class RelocateFiles(Command):
    """Point cameras at other video files (File > Relocate Files); undoable.

    Parameters
    ----------
    mapping : mapping
        Camera name or index -> new video file or image-sequence folder.

    Each new file must open as a video with the camera's image size; a different
    frame count is allowed (logged), since frames outside a video show blank.
    """

    description = "Relocate Files"

    def __init__(self, mapping: Mapping[str | int, str | Path]) -> None:
        super().__init__()
        self.mapping = dict(mapping)

    def apply(self, project: Project, journal: Journal) -> None:
        from carapost.io.video import VideoSource

        names = [c.name for c in project.take.cameras]
        resolved: list[tuple[int, str]] = []
        for key, new in self.mapping.items():
            if isinstance(key, int | np.integer):
                if not 0 <= int(key) < len(names):
                    raise CommandError(f"there is no camera {key} (cameras 0-{len(names) - 1})")
                c = int(key)
            elif key in names:
                c = names.index(key)
            else:
                raise CommandError(f"there is no camera named {key!r} ({', '.join(names)})")
            path = Path(new).absolute()
            cam = project.take.cameras[c]
            with VideoSource(path) as src:  # CaraFileError names a bad file
                if tuple(src.size) != tuple(cam.image_size):
                    raise CommandError(
                        f"{path} is {src.size[0]}x{src.size[1]} but camera {cam.name} is "
                        f"{cam.image_size[0]}x{cam.image_size[1]}")
                if src.n_frames < project.n_frames + cam.frame_offset:
                    log.warning("%s has %d frames; the take needs %d (the rest shows blank)",
                                path.name, src.n_frames, project.n_frames + cam.frame_offset)
            resolved.append((c, str(path)))
        for c, path_str in resolved:
            journal.setattr(project.take.cameras[c], "video_path", path_str, "cameras")


def relocate_files(
    project: Project,
    mapping: Mapping[str | int, str | Path] | str | Path,
    *,
    stack: CommandStack | None = None,
) -> RelocateFiles:
    """Change the video files of cameras (File > Relocate Files).

    Parameters
    ----------
    project : Project
    mapping : mapping or path
        Camera name (or index) -> new video file or image-sequence folder; or a folder
        in which every missing video is looked for by its file name.
    stack : CommandStack, optional
        Push the change on this undo stack (default: apply it directly).

    Returns
    -------
    RelocateFiles
        The applied command (``undo(project)`` reverts it when no stack is used).

    Raises
    ------
    CommandError
        Unknown cameras, a video of the wrong size, or no missing video found in a folder.
    CaraFileError
        A new file that does not exist or cannot be opened as a video.
    """
    if isinstance(mapping, str | Path):
        folder = Path(mapping)
        if not folder.is_dir():
            raise CaraFileError(folder, "is not a folder")
        found = {}
        for name, old in missing_files(project).items():
            cand = folder / Path(old).name if old else None
            if cand is not None and cand.exists():
                found[name] = cand
        if not found:
            raise CommandError(f"none of the missing videos was found in {folder}")
        mapping = found
    command = RelocateFiles(mapping)
    if stack is not None:
        stack.push(command)
    else:
        command.do(project)
    return command


# ----------------------------------------------------------------------------------------
# Exports
# ----------------------------------------------------------------------------------------


def _frame_range(project: Project, frame_range: str | Sequence[int]) -> tuple[int, int]:
    if project.n_frames < 1:
        raise ValueError("the project has no frames")
    if isinstance(frame_range, str):
        if frame_range == "all":
            return 0, project.n_frames - 1
        if frame_range == "active":
            a, b = project.active_range
            return int(a), int(b)
        raise ValueError(f"frame_range must be 'all', 'active' or (first, last), "
                         f"got {frame_range!r}")
    a, b = (int(v) for v in frame_range)
    if not 0 <= a <= b < project.n_frames:
        raise ValueError(f"frame_range {a}-{b} is outside the take (0-{project.n_frames - 1})")
    return a, b


def _export_columns(project: Project, include_brim: bool) -> NDArray[np.intp]:
    kinds = (KIND_FACE, KIND_BRIM) if include_brim else (KIND_FACE,)
    cols = np.flatnonzero(np.isin(project.points.kind, kinds))
    if cols.size == 0:
        what = "face or brim points" if include_brim else "face points"
        raise ValueError(f"nothing to export: the project has no {what}")
    return cols.astype(np.intp)


def _unique_labels(labels: list[str]) -> list[str]:
    seen: dict[str, int] = {}
    out = []
    for lab in labels:
        name = lab
        while name in seen:
            seen[lab] += 1
            name = f"{lab} ({seen[lab]})"
        seen[name] = 1
        if name != lab:
            log.warning("Two points are labelled %r; exporting one as %r", lab, name)
        out.append(name)
    return out


def _check_output(path: str | Path, suffixes: tuple[str, ...]) -> Path:
    path = check_output_path(path)
    if path.suffix.lower() not in suffixes:
        raise ValueError(f"{path}: the file name must end in {' or '.join(suffixes)}")
    return path


def _start_timecode(project: Project, first: int) -> str | None:
    from carapost.io.timecode import frame_index_to_timecode

    try:
        tc, _ = frame_index_to_timecode(first, project.take.timecode_start, project.take.fps)
    except ValueError:
        return project.take.timecode_start if first == 0 else None
    return str(tc)


def export_c3d(
    project: Project,
    path: str | Path,
    *,
    frame_range: str | Sequence[int] = "all",
    include_brim: bool = False,
    stabilized: bool = False,
) -> Path:
    """Export points as C3D (File > Export C3D).

    Parameters
    ----------
    project : Project
    path : str or Path
        Output ``.c3d`` file.
    frame_range : {"all", "active"} or (first, last)
        Frames to write (inclusive indices).
    include_brim : bool
        Also write the brim points.
    stabilized : bool
        Write stabilised coordinates (needs a stabilised project).

    Returns
    -------
    Path

    Notes
    -----
    Residuals are the points' residuals, the camera contribution mask comes from
    `carapost.model.queries.contribution_mask`, interpolated and filtered samples are
    written as modified, the first frame number is the burnt-in number (index + 1) and
    the start timecode is that of the first exported frame.
    """
    from carapost.io.c3d import write_c3d
    from carapost.model.queries import contribution_mask

    path = _check_output(path, (".c3d",))
    if stabilized:
        raise ValueError("stabilised export needs a stabilised project; this project has no "
                         "stabilisation (run Stabilize first, or export without it)")
    a, b = _frame_range(project, frame_range)
    cols = _export_columns(project, include_brim)
    pts = project.points
    sl = slice(a, b + 1)
    positions = pts.positions[sl][:, cols].astype(np.float64)
    recon = pts.recon[sl][:, cols]
    cams = project.take.cameras
    mask = None
    if 1 <= len(cams) <= 16:
        mask = contribution_mask(project, (a, b))[:, cols]
    write_c3d(
        path,
        positions,
        labels=_unique_labels([project.point_label(int(c)) for c in cols]),
        rate=project.take.fps,
        residuals=pts.residual[sl][:, cols].astype(np.float64),
        camera_mask=mask,
        modified=np.isin(recon, (RECON_INTERPOLATED, RECON_FILTERED)),
        first_frame=a + 1,
        timecode_start=_start_timecode(project, a),
        timecode_rate=project.take.fps,
        camera_names=[c.name for c in cams] if mask is not None else None,
    )
    log.info("Exported %d points x %d frames to %s", len(cols), b - a + 1, path)
    return path


def export_fbx(
    project: Project,
    path: str | Path,
    *,
    frame_range: str | Sequence[int] = "all",
    include_brim: bool = False,
    up_axis: str = "y",
    include_cameras: bool = False,
    include_sticks: bool = False,
) -> Path:
    """Export points (and optionally the solved cameras) as binary FBX (File > Export FBX).

    Parameters
    ----------
    project : Project
    path : str or Path
        Output ``.fbx`` file.
    frame_range : {"all", "active"} or (first, last)
        Frames to write; the FBX timeline starts at the first of them.
    include_brim : bool
        Also write the brim points (under ``<take>/brim``).
    up_axis : {"y", "z"}
        Up axis of the FBX scene.
    include_cameras : bool
        Write the cameras with their per-frame motion (needs a calibration).
    include_sticks : bool
        Write the project's sticks whose two points are both exported, as moving
        two-vertex line meshes.

    Returns
    -------
    Path
    """
    from carapost.io.fbx import write_fbx

    path = _check_output(path, (".fbx",))
    up = str(up_axis).lower()
    if up not in ("y", "z"):
        raise ValueError(f"up_axis must be 'y' or 'z', got {up_axis!r}")
    a, b = _frame_range(project, frame_range)
    cols = _export_columns(project, include_brim)
    sl = slice(a, b + 1)
    positions = project.points.positions[sl][:, cols].astype(np.float64)
    cameras = None
    if include_cameras:
        cal = project.calibration
        if cal.intrinsics is None or not cal.solved[sl].any():
            raise ValueError("cannot include cameras: they are not calibrated in these frames "
                             "(import an XCP or solve the cameras first)")
        R = cal.R[sl].copy()
        t = cal.t[sl].copy()
        R[~cal.solved[sl]] = np.nan
        t[~cal.solved[sl]] = np.nan
        cameras = {
            "R": R, "t": t, "focal_px": cal.intrinsics.focal,
            "image_size": cal.intrinsics.image_size,
            "names": [c.name for c in project.take.cameras],
        }
    write_fbx(
        path,
        positions,
        labels=_unique_labels([project.point_label(int(c)) for c in cols]),
        rate=project.take.fps,
        kinds=project.points.kind[cols].astype(np.int64),
        take_name=project.take.name or "take",
        up_axis=up,
        cameras=cameras,
        sticks=_export_sticks(project, cols) if include_sticks else None,
    )
    log.info("Exported %d points x %d frames to %s", len(cols), b - a + 1, path)
    return path


def _export_sticks(project: Project, cols: np.ndarray) -> list[tuple[int, int]] | None:
    """Sticks as pairs of indices into the exported columns (both ends exported)."""
    index = {int(project.points.ids[c]): k for k, c in enumerate(cols)}
    sticks = [(index[s.a], index[s.b]) for s in project.sticks if s.a in index and s.b in index]
    return sticks or None


def export_xcp(project: Project, path: str | Path, *, frame: int | None = None) -> Path:
    """Export the calibration as a Vicon ``.xcp`` file (File > Export XCP).

    Parameters
    ----------
    project : Project
    path : str or Path
        Output ``.xcp`` file.
    frame : int, optional
        Write only the cameras of this frame (a single static KeyFrame). By default the
        cameras of the project's current frame are written.

    Returns
    -------
    Path
    """
    from carapost.io.xcp import XcpCalibration, write_xcp

    path = _check_output(path, (".xcp",))
    cal = project.calibration
    if cal.intrinsics is None or project.n_frames < 1:
        raise ValueError("the project has no camera calibration to export (import an XCP or "
                         "solve the cameras first)")
    frame = project.current_frame if frame is None else int(frame)
    if not 0 <= frame < project.n_frames:
        raise ValueError(f"frame {frame} is outside the take (0-{project.n_frames - 1})")
    if not cal.solved[frame]:
        raise ValueError(f"the cameras are not solved at frame {frame}")
    calib = XcpCalibration.from_arrays(cal.intrinsics, cal.R[frame], cal.t[frame],
                                       extras=cal.xcp_extras)
    write_xcp(path, calib, frame=None)
    log.info("Exported the cameras of frame %d to %s", frame, path)
    return path


# ----------------------------------------------------------------------------------------
# Evaluation against ground truth
# ----------------------------------------------------------------------------------------

def _load_truth(path: Path) -> dict[str, Any]:
    if not path.is_file():
        raise CaraFileError(path, "no such file")
    try:
        with np.load(path, allow_pickle=False) as npz:
            data = {k: npz[k] for k in npz.files}
    except (OSError, ValueError, EOFError) as exc:
        raise CaraFileError(path, f"is not a readable .npz file ({exc})") from None
    for key in ("points3d", "labels"):
        if key not in data:
            raise CaraFileError(path, f"has no {key!r} array (not a carapost truth file?)")
    X = np.asarray(data["points3d"], dtype=np.float64)
    if X.ndim != 3 or X.shape[2] != 3:
        raise CaraFileError(path, f"points3d must be [F, M, 3], got {list(X.shape)}")
    data["points3d"] = X
    data["labels"] = [str(s) for s in np.asarray(data["labels"]).reshape(-1)]
    if len(data["labels"]) != X.shape[1]:
        raise CaraFileError(path, "labels and points3d disagree on the number of markers")
    return data


def evaluate(project_or_path: Project | str | Path, truth_path: str | Path) -> dict[str, Any]:
    """Compare a project's face points with a synthetic take's ground truth.

    Parameters
    ----------
    project_or_path : Project or str or Path
        The project (or its ``.cara`` file).
    truth_path : str or Path
        ``truth.npz`` of a synthetic take: ``points3d`` [F, M, 3] (mm), ``labels`` [M],
        optionally ``visible`` [F, M, C] and ``uv`` [F, M, C, 2] (px).

    Returns
    -------
    dict
        JSON-serialisable (``None`` where a metric has no data):

        - ``rmse_mm``: RMS 3D distance over every frame where a matched point and its
          marker both exist;
        - ``per_marker_rmse_mm``: the same per matched truth label;
        - ``coverage``: fraction of truth marker-frames seen by >= 2 cameras (all
          marker-frames without ``visible``) at which the matched point is within 2 mm;
        - ``swaps``: identity changes. For each face point, take the frames at which it
          is within 2 mm of some truth marker and the nearest such marker; every change
          of that marker from one such frame to the next counts once. A clean exchange
          of two points' identities therefore counts 2;
        - ``spurious_points``: face points with 3D data that match no marker (brim points
          are never counted);
        - ``reprojection_rms_px``: RMS distance between the matched points' 2D
          observations and the truth ``uv`` of their markers;
        - ``n_points`` (face points with 3D data), ``n_matched``, ``n_frames``,
          ``swapped_points`` (labels of points with a swap), ``match_gate_mm``.

    Notes
    -----
    Matching: a point whose label equals a truth label is matched to that marker when
    their mean distance is within `MATCH_GATE_MM`; the rest are matched one-to-one by
    the Hungarian method on the mean 3D distance over the frames where both exist,
    keeping pairs within the same gate (`carapost.synth.scoring.score_tracks`, which the
    tests and benchmarks also use). Frames beyond the shorter of the two are ignored.
    """
    if isinstance(project_or_path, Project):
        project = project_or_path
    else:
        project = open_project(project_or_path)
    truth = _load_truth(Path(truth_path))
    X = truth["points3d"]
    t_labels: list[str] = truth["labels"]
    F = min(project.n_frames, X.shape[0])
    if project.n_frames != X.shape[0]:
        log.warning("The project has %d frames and the truth %d; comparing the first %d",
                    project.n_frames, X.shape[0], F)
    X = X[:F]
    M = X.shape[1]
    face = np.flatnonzero(project.points.kind == KIND_FACE)
    Y = project.points.positions[:F][:, face].astype(np.float64)
    has_data = ~np.all(np.isnan(Y[..., 0]), axis=0)
    face, Y = face[has_data], Y[:, has_data]
    P = len(face)

    vis = truth.get("visible")
    if vis is not None:
        vis = np.asarray(vis).astype(bool)
        if vis.ndim != 3 or vis.shape[0] < F or vis.shape[1] != M:
            raise CaraFileError(Path(truth_path), f"visible must be [F, {M}, C], got "
                                f"{list(vis.shape)}")
        vis = vis[:F]
    label_index = {lab: m for m, lab in enumerate(t_labels)}
    preferred = np.array([label_index.get(project.points.labels[col], -1) for col in face],
                         dtype=np.int64)
    score = score_tracks(Y, X, vis, preferred)
    match = score.match
    matched = np.flatnonzero(match >= 0)
    swapped = [project.point_label(int(face[i])) for i in np.flatnonzero(score.swaps)]

    # 2D reprojection: observations of matched points vs the truth uv of their marker.
    reproj = None
    uv = truth.get("uv")
    if uv is not None and matched.size:
        uv = np.asarray(uv, dtype=np.float64)[:F]
        obs = project.points.obs[:F][:, face[matched]].astype(np.float64)
        C = min(obs.shape[2], uv.shape[2]) if uv.ndim == 4 else 0
        if C:
            diff = obs[:, :, :C] - uv[:, match[matched]][:, :, :C]
            d2 = np.sum(diff ** 2, axis=-1)
            ok = ~np.isnan(d2)
            if ok.any():
                reproj = float(np.sqrt(np.mean(d2[ok])))

    return {
        "rmse_mm": score.rmse,
        "per_marker_rmse_mm": {t_labels[m]: v for m, v in score.marker_rmse.items()},
        "coverage": score.coverage,
        "swaps": int(score.swaps.sum()),
        "spurious_points": int(P - matched.size),
        "reprojection_rms_px": reproj,
        "n_points": int(P),
        "n_matched": int(matched.size),
        "n_frames": int(F),
        "swapped_points": swapped,
        "match_gate_mm": MATCH_GATE_MM,
    }

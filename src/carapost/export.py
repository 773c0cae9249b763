"""Exports: C3D, FBX and XCP files from a project, with the Export properties as defaults.

`export_c3d`, `export_fbx` and `export_xcp` take every option as a keyword (their
defaults are the historical API defaults: all frames, no brim, Y up, no cameras, no
sticks). `ExportOptions.from_properties` reads the Export section of a project's
Properties (Export Range, Include Brim Points, FBX Up Axis, ...), which is what File >
Export and `carapost.Session` use, so the window and scripts write the same file.

Errors the user can fix raise `CaraFileError` (the output folder is missing or a file
cannot be written; the message names it) or `ValueError` (a bad option or nothing to
export). Files are written atomically: a failed export leaves no partial file.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from carapost.io.atomic import check_output_path
from carapost.io.errors import CaraFileError
from carapost.model.project import (
    KIND_BRIM,
    KIND_FACE,
    RECON_FILTERED,
    RECON_INTERPOLATED,
    Project,
)

log = logging.getLogger("carapost.export")

__all__ = [
    "ExportOptions",
    "OutputNameError",
    "check_output",
    "export_c3d",
    "export_fbx",
    "export_xcp",
    "resolve_frame_range",
]

#: ``frame_range`` of the exports: "all", "active" or inclusive (first, last).
FrameRange = str | Sequence[int]


@dataclass(frozen=True)
class ExportOptions:
    """What File > Export C3D / FBX writes (the Export section of the Properties).

    Attributes
    ----------
    frame_range : {"all", "active"} or (first, last)
        Frames written (Export Range).
    include_brim : bool
        Also write the brim points (Include Brim Points).
    stabilized : bool
        Stabilised (and aligned) coordinates (Export Stabilized Coordinates).
    up_axis : {"y", "z"}
        FBX scene up axis (FBX Up Axis).
    include_cameras : bool
        FBX: the solved cameras with their motion (FBX Include Cameras).
    include_sticks : bool
        FBX: sticks as line meshes (FBX Include Sticks).
    """

    frame_range: FrameRange = "all"
    include_brim: bool = False
    stabilized: bool = False
    up_axis: str = "y"
    include_cameras: bool = False
    include_sticks: bool = False

    @classmethod
    def from_properties(cls, properties: Mapping[str, Any]) -> ExportOptions:
        """The options the Export section of a project's properties asks for."""
        return cls(
            frame_range=str(properties["export_range"]),
            include_brim=bool(properties["export_include_brim_points"]),
            stabilized=bool(properties["export_stabilized"]),
            up_axis=str(properties["fbx_up_axis"]).lower(),
            include_cameras=bool(properties["fbx_include_cameras"]),
            include_sticks=bool(properties["fbx_include_sticks"]),
        )

    def with_overrides(self, **overrides: Any) -> ExportOptions:
        """A copy with some options replaced; an unknown name raises ``TypeError``."""
        names = {f.name for f in fields(self)}
        unknown = sorted(set(overrides) - names)
        if unknown:
            raise TypeError(f"unknown export option(s) {', '.join(unknown)} "
                            f"(options: {', '.join(sorted(names))})")
        return replace(self, **overrides)


class OutputNameError(CaraFileError, ValueError):
    """An output file name with the wrong extension (a `CaraFileError` and a `ValueError`,
    so callers catching either see it)."""


def check_output(path: str | Path, suffixes: str | tuple[str, ...]) -> Path:
    """Check an output file before any work is done for it.

    Parameters
    ----------
    path : str or Path
    suffixes : str or tuple of str
        Allowed extensions, lower case with the dot (``".c3d"``).

    Returns
    -------
    Path

    Raises
    ------
    OutputNameError
        The name does not end in one of ``suffixes``.
    CaraFileError
        ``path`` is a folder or its folder does not exist.
    """
    from carapost.io.atomic import checked_path

    if isinstance(suffixes, str):
        suffixes = (suffixes,)
    p = checked_path(path)  # empty names and NUL bytes first
    if p.suffix.lower() not in suffixes:
        allowed = " or ".join(suffixes)
        raise OutputNameError(p, f"the output must be a {allowed} file (the file name must "
                                 f"end in {allowed})")
    return check_output_path(p)


def resolve_frame_range(project: Project, frame_range: FrameRange) -> tuple[int, int]:
    """Inclusive (first, last) frames of ``"all"``, ``"active"`` or (first, last).

    Raises
    ------
    ValueError
        An unknown name, a range outside the take, or a project without frames.
    """
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


def _exported_points(project: Project, frame_range: FrameRange, include_brim: bool,
                     stabilized: bool = False
                     ) -> tuple[int, int, NDArray[np.intp], NDArray[np.float64], list[str]]:
    """What C3D and FBX both write: the inclusive frames, the point columns, their
    positions over those frames (float64; stabilised and aligned when ``stabilized``)
    and their labels made unique."""
    from carapost.model.stabilization import has_processing, processed_positions

    a, b = resolve_frame_range(project, frame_range)
    cols = _export_columns(project, include_brim)
    if stabilized:
        if not has_processing(project):
            raise ValueError("stabilised export needs a stabilised project; this project has "
                             "no stabilisation (run Stabilize Data first, or export without "
                             "it)")
        positions = processed_positions(project, a, b, cols)
        st = project.stabilization
        if st is not None:
            outside = ~np.isfinite(st.transforms[a:b + 1]).all((1, 2))
            if outside.any():
                log.warning("Exporting stabilised coordinates: %d of the %d frames are not "
                            "stabilised (stabilised frames %d-%d) and are written as gaps",
                            int(outside.sum()), b - a + 1, st.first, st.last)
    else:
        positions = project.points.positions[a:b + 1][:, cols].astype(np.float64)
    labels = _unique_labels([project.point_label(int(c)) for c in cols])
    return a, b, cols, positions, labels


def _unique_labels(labels: list[str]) -> list[str]:
    """The labels made unique for a format that keys points by label (logged)."""
    from carapost.io.labels import unique_names

    out = unique_names(labels)
    for lab, name in zip(labels, out, strict=True):
        if name != lab:
            log.warning("Two points are labelled %r; exporting one as %r", lab, name)
    return out


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
    frame_range: FrameRange = "all",
    include_brim: bool = False,
    stabilized: bool = False,
    residual: str = "sigma",
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
        Write stabilised (and aligned) coordinates: needs a stabilised or aligned
        project; frames outside the stabilised range are written as gaps.
    residual : {"sigma", "rays"}
        What the residual word (the spec's "average residual", mm) holds: ``"sigma"``
        the sample's estimated 3D error standard deviation where it has one, else its
        RMS distance to its rays; ``"rays"`` always the distance to the rays.

    Returns
    -------
    Path

    Notes
    -----
    Residuals are as ``residual`` says (docs/file-formats.md), the camera contribution
    mask comes from `carapost.model.queries.contribution_mask`, interpolated and filtered
    samples are written as modified (a stabilised sample is a measurement in other coordinates: a
    rigid change of frame does not clear its camera mask), the first frame number is
    the burnt-in number (index + 1) and the start timecode is that of the first exported
    frame.
    """
    from carapost.io.c3d import write_c3d
    from carapost.model.queries import contribution_mask

    path = check_output(path, ".c3d")
    if residual not in ("sigma", "rays"):
        raise ValueError(f"residual must be 'sigma' or 'rays', got {residual!r}")
    a, b, cols, positions, labels = _exported_points(project, frame_range, include_brim,
                                                     stabilized)
    pts = project.points
    sl = slice(a, b + 1)
    recon = pts.recon[sl][:, cols]
    cams = project.take.cameras
    mask = None
    if 1 <= len(cams) <= 16:
        mask = contribution_mask(project, (a, b))[:, cols]
    res = pts.residual[sl][:, cols].astype(np.float64)
    if residual == "sigma":
        sig = pts.arrays["sigma"][sl][:, cols].astype(np.float64)
        res = np.where(np.isfinite(sig), sig, res)
    write_c3d(
        path,
        positions,
        labels=labels,
        rate=project.take.fps,
        residuals=res,
        camera_mask=mask,
        modified=np.isin(recon, (RECON_INTERPOLATED, RECON_FILTERED)),
        first_frame=a + 1,
        timecode_start=_start_timecode(project, a),
        timecode_rate=project.take.fps,
        camera_names=[c.name for c in cams] if mask is not None else None,
    )
    log.info("Exported %d points x %d frames to %s", len(cols), b - a + 1, path)
    return path


def export_sigma_csv(project: Project, path: str | Path, *, frame_range: FrameRange = "all",
                     include_brim: bool = False, stabilized: bool = False) -> Path:
    """Write the per-sample uncertainty sidecar CSV of an export
    (`carapost.io.sigma_csv`): the same points, frames and coordinates as `export_c3d`
    (a rigid change of frame leaves the error's size as it was)."""
    from carapost.io.sigma_csv import write_sigma_csv

    path = check_output(path, ".csv")
    a, b, cols, positions, labels = _exported_points(project, frame_range, include_brim,
                                                     stabilized)
    sl = slice(a, b + 1)
    return write_sigma_csv(path, positions, project.points.arrays["sigma"][sl][:, cols],
                           project.points.recon[sl][:, cols], labels, first_frame=a + 1)


def export_fbx(
    project: Project,
    path: str | Path,
    *,
    frame_range: FrameRange = "all",
    include_brim: bool = False,
    up_axis: str = "y",
    include_cameras: bool = False,
    include_sticks: bool = False,
    stabilized: bool = False,
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
    stabilized : bool
        Stabilised (and aligned) coordinates; the cameras, when included, move with
        them (each camera's pose is expressed in the stabilised frame).

    Returns
    -------
    Path
    """
    from carapost.io.fbx import write_fbx

    path = check_output(path, ".fbx")
    up = str(up_axis).lower()
    if up not in ("y", "z"):
        raise ValueError(f"up_axis must be 'y' or 'z', got {up_axis!r}")
    a, b, cols, positions, labels = _exported_points(project, frame_range, include_brim,
                                                     stabilized)
    sl = slice(a, b + 1)
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
        if stabilized:
            from carapost.model.stabilization import processed_transforms

            # x_cam = R X + t with X = inv(T) X_s: R' = R Rs^T, t' = t - R' ts
            T = processed_transforms(project, a, b)
            R = np.einsum("fcij,fkj->fcik", R, T[:, :3, :3])
            t = t - np.einsum("fcij,fj->fci", R, T[:, :3, 3])
        cameras = {
            "R": R, "t": t, "focal_px": cal.intrinsics.focal,
            "image_size": cal.intrinsics.image_size,
            "names": [c.name for c in project.take.cameras],
        }
    write_fbx(
        path,
        positions,
        labels=labels,
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

    path = check_output(path, ".xcp")
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

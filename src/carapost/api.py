"""The scripting API in functions: File-menu actions on a `Project`, without Qt.

Use it from a script or a notebook::

    from carapost import api

    project = api.import_take("takes/Speech01_cam0.mkv")
    api.save_project(project, "Speech01.cara")
    api.export_c3d(project, "Speech01.c3d", frame_range="active")
    print(api.evaluate("Speech01.cara", "takes/truth.npz"))

These functions are thin wrappers: for undoable, menu-by-menu work (Detect Blobs,
Solve Calibration Brim, Initialize 3D, Track, ...) use `carapost.Session`, which holds a
project with its History and images; the exports live in `carapost.export`.

Errors the user can fix raise `CaraFileError` (a file is missing, unreadable or cannot
be written; the message names it) or `ValueError` (a bad option or a project that has
nothing to export). Exports are written atomically, so a failed export never leaves a
partial file behind.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from carapost.commands.file import RelocateFiles, missing_files
from carapost.commands.stack import CommandStack
from carapost.export import export_c3d, export_fbx, export_xcp
from carapost.model.project import Project
from carapost.pipeline import process_take
from carapost.session import RelocateCallback, Session, read_take

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


def open_project(path: str | Path, *, relocate: RelocateCallback | None = None,
                 recover: bool | None = None) -> Project:
    """Open a ``.cara`` project (`Session.open` without the session).

    Camera videos that moved are looked for beside the project first, then
    ``relocate(camera_name, missing_path)`` is asked (see `relocate_files` to fix them
    afterwards). ``recover``: when an autosave copy newer than the file exists, True
    opens the copy, False the file; None (default) opens the file, warns
    (`NewerAutosaveWarning`) and sets ``project.newer_autosave`` to the copy's path.

    Raises
    ------
    CaraFileError
        Missing, damaged or foreign files and projects of a newer format.
    """
    session = Session.open(path, relocate=relocate, recover=recover)
    project = session.project
    project.newer_autosave = session.newer_autosave
    return project


def save_project(project: Project, path: str | Path) -> Path:
    """Save a project atomically (``.cara`` is appended when missing); returns the path."""
    from carapost.io import cara

    return cara.save_project(project, path)


def import_take(path: str | Path, *, relocate: RelocateCallback | None = None) -> Project:
    """Import Camera Files: a new project from one file (or the folder) of a take.

    The same project as File > Import and `Session.import_take` (`read_take`): when the
    take carries its brim model (``<take>_brim.csv``), the project starts with those
    brim points, ready for Solve Calibration Brim.
    """
    return read_take(path, relocate=relocate)


def relocate_files(
    project: Project,
    mapping: Mapping[str | int, str | Path] | str | Path,
    *,
    stack: CommandStack | None = None,
) -> RelocateFiles:
    """Change the video files of cameras (Edit > Relocate Files).

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
    command = RelocateFiles.of(project, mapping)
    if stack is not None:
        stack.push(command)
    else:
        command.do(project)
    return command


def evaluate(project_or_path: Project | str | Path, truth_path: str | Path) -> dict[str, Any]:
    """Compare a project's face points with a synthetic take's ground truth.

    See `carapost.synth.evaluation.evaluate` (imported on first use, so ``import
    carapost.api`` does not load the synthetic-take renderer).
    """
    from carapost.synth.evaluation import evaluate as _evaluate

    return _evaluate(project_or_path, truth_path)

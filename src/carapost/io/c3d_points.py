"""File > Import C3D: the 3D points and labels of any vendor's C3D file as a project.

The project has no cameras: the clean-up tools (Interpolate Gaps, Filter Trajectories,
Find Problems) and the exports work on it like on a tracked take. Valid samples become
"triangulated" with the file's residual; samples the file marks as processed (word 4 =
0: interpolated or filtered by the system that wrote it) become "interpolated", so
Overwrite Existing Filled Gaps and Remove Interpolated 3D Points treat them as fills —
unless more than half of the valid samples carry that mark (writers that store no
residuals write 0 everywhere), in which case every valid sample is taken as measured.
Points with no valid sample are kept (with their label), so the file's marker list is
complete.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from carapost.algorithms.codes import RECON_INTERPOLATED, RECON_NONE, RECON_TRIANGULATED
from carapost.io.errors import CaraFileError
from carapost.model.project import Project, new_project

__all__ = ["project_from_c3d"]


def project_from_c3d(path: str | Path) -> Project:
    """A new project holding the points of a C3D file.

    Raises
    ------
    CaraFileError
        The file is missing, unreadable, or holds no 3D points.
    """
    from carapost.io.c3d import read_c3d

    path = Path(path)
    if not path.exists():
        raise CaraFileError(path, "no such file")
    try:
        data = read_c3d(path)
    except CaraFileError:
        raise
    except (OSError, ValueError, IndexError, KeyError) as exc:  # reader guards the rest
        raise CaraFileError(path, f"not a readable C3D file ({exc})") from None
    X = np.asarray(data.positions)
    if X.ndim != 3 or X.shape[1] == 0 or X.shape[0] == 0:
        raise CaraFileError(path, "the file holds no 3D points (POINT:USED is 0 or no "
                                  "frames): nothing to import")
    F, P, _ = X.shape
    rate = float(data.rate) if data.rate and np.isfinite(data.rate) and data.rate > 0 else 60.0
    project = new_project(F, 0, fps=rate, name=path.stem)
    labels = [(lab or f"M{i + 1}").strip().replace(" ", "_") for i, lab in
              enumerate(list(data.labels) + [""] * (P - len(data.labels)))][:P]
    pts = project.points
    pts.append(P, labels=labels)
    valid = np.isfinite(X).all(-1)
    pts.positions[:] = np.where(valid[..., None], X, np.nan).astype(np.float32)
    processed = np.asarray(data.processed, bool) & valid
    # many writers put word 4 = 0 on every sample (no residuals at all): then the flag
    # says nothing about which samples were filled, and all are taken as measured
    if processed.sum() > 0.5 * max(valid.sum(), 1):
        processed[:] = False
    pts.recon[:] = np.where(valid, np.where(processed, RECON_INTERPOLATED, RECON_TRIANGULATED),
                            RECON_NONE).astype(np.int8)
    res = np.asarray(data.residuals, np.float64)
    pts.residual[:] = np.where(valid & ~processed, res, np.nan).astype(np.float32)
    project.take.metadata["source_c3d"] = str(path.absolute())
    project.take.metadata["c3d_first_frame"] = int(data.first_frame)
    project.labels = [lab for lab in labels if lab]
    project.active_range = (0, F - 1)
    project.view_range = (0, F - 1)
    project.modified = False
    return project

"""Evaluation of a project against a synthetic take's ground truth (``carapost evaluate``).

It lives beside `carapost.synth.scoring` (the array-level scores the tests and
benchmarks use) and adds the project side: label matching, file checks and the 2D
reprojection error. `carapost.api.evaluate` imports it lazily, so ``import
carapost.api`` never loads the renderer.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np

from carapost.io.cara import load_project
from carapost.io.errors import CaraFileError
from carapost.model.project import KIND_FACE, Project
from carapost.synth.scoring import MATCH_GATE_MM, score_tracks

log = logging.getLogger("carapost.evaluate")

__all__ = ["evaluate", "load_truth", "truth_labels"]


def load_truth(path: Path) -> dict[str, Any]:
    """Read and check a synthetic take's ``truth.npz``.

    Returns
    -------
    dict
        Every array of the file; ``points3d`` as float64 [F, M, 3] (mm) and ``labels``
        as a list of M strings.

    Raises
    ------
    CaraFileError
        Missing or unreadable file, or arrays missing or of the wrong shape.
    """
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
        project = load_project(project_or_path)
    truth = load_truth(Path(truth_path))
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


def truth_labels(project: Project, truth_path: str | Path) -> dict[int, str]:
    """The truth label of each face point of a project, as an artist would name them.

    Points are matched to the truth markers as `evaluate` matches them (geometry only:
    the points' own labels are ignored); unmatched points are left out.

    Returns
    -------
    dict
        ``{point id: truth label}``.
    """
    truth = load_truth(Path(truth_path))
    X = truth["points3d"]
    F = min(project.n_frames, X.shape[0])
    face = np.flatnonzero(project.points.kind == KIND_FACE)
    Y = project.points.positions[:F][:, face].astype(np.float64)
    has = ~np.all(np.isnan(Y[..., 0]), axis=0)
    face, Y = face[has], Y[:, has]
    vis = truth.get("visible")
    vis = None if vis is None else np.asarray(vis).astype(bool)[:F]
    match = score_tracks(Y, X[:F], vis).match
    labels: list[str] = truth["labels"]
    return {int(project.points.ids[c]): labels[m]
            for c, m in zip(face, match, strict=True) if m >= 0}

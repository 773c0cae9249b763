"""Stabilize Data [Manual]/[Assisted]/[Automatic], Align Data, Remove Stabilization.

Stabilisation follows the processing recipe (:mod:`carapost.commands.recipe`):
:func:`prepare_stabilize` validates the selection and snapshots the active range's
positions, the job computes the per-frame transforms
(:mod:`carapost.algorithms.stabilise`) and the result sets
``project.stabilization`` as one History entry. Raw positions are never written.

Align Data and Remove Stabilization are small edit commands. Stabilising again after
aligning keeps the alignment: the result re-derives it from the same three points at
the same frame in the new stabilised coordinates, so they land where the convention
says again.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from carapost.algorithms import stabilise as algo
from carapost.algorithms.params import from_mapping, to_mapping
from carapost.algorithms.stabilise_auto import stabilise_auto
from carapost.commands.recipe import Job, Progress, Result
from carapost.commands.stack import Command, CommandError, Journal
from carapost.model.project import KIND_BRIM, KIND_FACE, Project
from carapost.model.stabilization import (
    Alignment,
    Stabilization,
    processed_positions,
)

log = logging.getLogger("carapost.commands")

__all__ = ["MODES", "AlignData", "RemoveStabilization",
           "StabiliseJob", "StabiliseResult", "prepare_stabilize", "stabilisation_message"]

#: The stabilisation modes and their menu names.
MODES = {"manual": "Stabilize Data [Manual]", "assisted": "Stabilize Data [Assisted]",
         "auto": "Stabilize Data [Automatic]"}


def _name(project: Project, column: int) -> str:
    label = project.points.labels[column]
    pid = int(project.points.ids[column])
    return f"{label} (point {pid})" if label else f"point {pid}"


def _runs(missing: NDArray[np.bool_], first: int) -> str:
    """'12-40, 88' for the missing frames (absolute indices)."""
    idx = np.flatnonzero(missing)
    if not idx.size:
        return ""
    cut = np.flatnonzero(np.diff(idx) > 1)
    starts = np.r_[idx[0], idx[cut + 1]] + first
    ends = np.r_[idx[cut], idx[-1]] + first
    parts = [f"{a}" if a == b else f"{a}-{b}" for a, b in zip(starts, ends, strict=True)]
    more = f" and {len(parts) - 4} more runs" if len(parts) > 4 else ""
    return ", ".join(parts[:4]) + more


def _selected_columns(project: Project, points: Iterable[int] | None) -> NDArray[np.intp]:
    if points is None:
        return project.selected_columns()
    ids = np.asarray(list(points), dtype=np.int64)
    try:
        return project.points.index_of(ids)
    except (KeyError, ValueError) as exc:
        raise CommandError(f"unknown point id(s): {exc}") from None


def check_stable_selection(project: Project, cols: NDArray[np.intp], first: int, last: int,
                           what: str) -> None:
    """Refuse fewer than 3 points, or a point with a gap over ``first..last``."""
    cols = np.unique(cols)
    if len(cols) < 3:
        raise CommandError(f"{what}: select at least 3 points that stay still relative to "
                           f"the head (got {len(cols)})")
    X = project.points.positions[first:last + 1][:, cols, 0]
    for k, c in enumerate(cols):
        missing = ~np.isfinite(X[:, k])
        if missing.any():
            raise CommandError(
                f"{what}: {_name(project, int(c))} has no 3D position in frames "
                f"{_runs(missing, first)} of the active range {first}-{last}; select "
                f"gap-free points (or fill the gap first)")


@dataclass
class StabiliseResult(Result):
    """Computed stabilisation, applied as ``project.stabilization``."""

    stabilization: Stabilization
    description: str
    message: str = ""
    cancelled: bool = False

    def write(self, project: Project, journal: Journal) -> None:
        st = self.stabilization
        journal.setattr(project, "stabilization", st, "stabilization")
        al = project.alignment
        if al is not None:
            journal.setattr(project, "alignment", _realign(project, al), "stabilization")
        if not project.show_stabilized:
            journal.setattr(project, "show_stabilized", True, "stabilization")
        log.info("%s", self.message)


def _realign(project: Project, al: Alignment) -> Alignment:
    """The alignment re-derived in the current stabilised coordinates (or kept as is
    when its points no longer exist there)."""
    try:
        cols = project.points.index_of(np.asarray(al.point_ids, np.int64))
        P = processed_positions(project, al.frame, al.frame, cols, align=False)[0]
        M = algo.alignment_transform(P[0], P[1], P[2], al.axes)
    except (KeyError, ValueError) as exc:
        log.warning("Align Data kept as it was: its points cannot define it again (%s)", exc)
        return al
    return Alignment(M, al.point_ids, al.frame, al.axes)


def stabilisation_message(st: Stabilization, what: str) -> str:
    """The Log line of a stabilisation: errors, base frame, points."""
    T = st.transforms[st.first:st.last + 1]
    n_bad = int((~np.isfinite(T).all((1, 2))).sum())
    extra = f"; {n_bad} frames had too few points and are not stabilised" if n_bad else ""
    return (f"{what}: frames {st.first}-{st.last}, base frame {st.base_frame}, "
            f"{len(st.point_ids)} points; base frame error {st.base_frame_error:.4f} mm, "
            f"inter frame error {st.inter_frame_error:.4f} mm, stabilization error "
            f"{st.error:.4f}{extra}")


@dataclass
class StabiliseJob(Job):
    """Snapshot of a stabilisation: the active range's positions and the choices."""

    mode: str
    positions: NDArray[np.float32]  # (n, P, 3), the active range
    ids: NDArray[np.int64]
    seed: NDArray[np.intp]  # columns (manual / assisted)
    candidates: NDArray[np.bool_]
    first: int
    n_frames: int
    base_frame: int | None  # absolute (manual / assisted)
    params: algo.StabilizationParameters
    description: str
    parameters: dict = field(default_factory=dict)

    def compute(self, progress: Progress = None) -> StabiliseResult:
        X = self.positions
        try:
            if self.mode == "manual":
                r = algo.stabilise_manual(X, self.seed, base_frame=self.base_frame - self.first)
            elif self.mode == "assisted":
                r = algo.stabilise_assisted(X, self.seed,
                                            base_frame=self.base_frame - self.first,
                                            params=self.params, candidates=self.candidates,
                                            progress=progress)
            else:
                r = stabilise_auto(X, params=self.params, candidates=self.candidates,
                                   progress=progress)
        except ValueError as exc:
            raise CommandError(f"{self.description}: {exc}") from None
        T = np.full((self.n_frames, 4, 4), np.nan)
        T[self.first:self.first + len(X)] = r.transforms
        st = Stabilization(T, self.first + r.base_frame, self.ids[r.points].copy(),
                           self.mode, self.first, self.first + len(X) - 1,
                           r.base_frame_error, r.inter_frame_error, r.error,
                           self.parameters)
        msg = stabilisation_message(st, self.description)
        return StabiliseResult(st, self.description, msg, r.cancelled)


def prepare_stabilize(project: Project, mode: str = "manual",
                      points: Iterable[int] | None = None,
                      base_frame: int | None = None) -> StabiliseJob:
    """Validate and snapshot a stabilisation of the active range.

    Parameters
    ----------
    project : Project
    mode : {"manual", "assisted", "auto"}
    points : iterable of int, optional
        Point ids (default: the selection); ignored by "auto".
    base_frame : int, optional
        Default: the current frame ("auto" chooses its own).

    Raises
    ------
    CommandError
        Unknown mode, fewer than 3 points, a selected point with a gap in the active
        range (named with its frames), a base frame outside the active range.
    """
    mode = str(mode).strip().lower()
    if mode in ("automatic",):
        mode = "auto"
    if mode not in MODES:
        raise CommandError(f"stabilize: mode must be one of {', '.join(MODES)}, got {mode!r}")
    what = MODES[mode]
    a, b = (int(v) for v in project.active_range)
    if project.n_frames < 1 or project.n_points < 3:
        raise CommandError(f"{what}: the project needs at least 3 points")
    params = from_mapping(algo.StabilizationParameters, project.properties)
    kinds = project.points.kind
    use_brim = params.stabilization_use_brim_points
    candidates = (kinds == KIND_FACE) | ((kinds == KIND_BRIM) & use_brim)
    seed = np.zeros(0, np.intp)
    if mode != "auto":
        seed = np.unique(_selected_columns(project, points))
        check_stable_selection(project, seed, a, b, what)
        base = project.current_frame if base_frame is None else int(base_frame)
        if not a <= base <= b:
            raise CommandError(f"{what}: the base frame {base} is outside the active range "
                               f"{a}-{b}")
    else:
        base = None
        if int(candidates.sum()) < 3:
            raise CommandError(f"{what}: the project has fewer than 3 face points")
    parameters = {} if mode == "manual" else to_mapping(params)
    return StabiliseJob(mode, project.points.positions[a:b + 1].copy(),
                        project.points.ids.copy(), seed, candidates, a, project.n_frames,
                        base, params, f"{what} [frames {a}-{b}]", parameters)


class AlignData(Command):
    """Align Data: three points define the coordinate frame of the processed data.

    Parameters
    ----------
    project : Project
    points : sequence of 3 int, optional
        Point ids in order: origin, the x direction, the x-y plane (default: the three
        selected points, in id order).
    axes : str
        Which axes the first direction and the plane use (default "xy"; "zx": z
        towards the second point, the third in the z-x plane; a "-" flips an axis). See
        `carapost.algorithms.stabilise.parse_axes`.
    frame : int, optional
        The frame whose (stabilised) positions define the frame (default current).
    """

    description = "Align Data"

    def __init__(self, project: Project, points: Sequence[int] | None = None,
                 axes: str = "xy", frame: int | None = None) -> None:
        super().__init__(project)
        if points is None:
            cols = project.selected_columns()
        else:
            cols = _selected_columns(project, points)
        if len(cols) != 3 or len(np.unique(cols)) != 3:
            raise CommandError(f"Align Data: select exactly 3 different points (got "
                               f"{len(np.unique(cols))})")
        f = project.current_frame if frame is None else int(frame)
        if not 0 <= f < project.n_frames:
            raise CommandError(f"Align Data: frame {f} is outside the take")
        P = processed_positions(project, f, f, cols, align=False)[0]
        for k in range(3):
            if not np.isfinite(P[k]).all():
                raise CommandError(f"Align Data: {_name(project, int(cols[k]))} has no "
                                   f"{'stabilised ' if project.stabilization else ''}3D "
                                   f"position at frame {f}")
        try:
            M = algo.alignment_transform(P[0], P[1], P[2], axes)
        except ValueError as exc:
            raise CommandError(f"Align Data: {exc}") from None
        ids = tuple(int(i) for i in project.points.ids[cols])
        self.alignment = Alignment(M, (ids[0], ids[1], ids[2]), f, str(axes))
        names = ", ".join(_name(project, int(c)) for c in cols)
        self.description = f"Align Data [{names}]"

    def apply(self, project: Project, journal: Journal) -> None:
        journal.setattr(project, "alignment", self.alignment, "stabilization")
        if not project.show_stabilized:
            journal.setattr(project, "show_stabilized", True, "stabilization")


class RemoveStabilization(Command):
    """Remove Stabilization: back to raw positions (the stabilisation and alignment go)."""

    description = "Remove Stabilization"

    def __init__(self, project: Project) -> None:
        super().__init__(project)
        if project.stabilization is None and project.alignment is None:
            raise CommandError("Remove Stabilization: the project is not stabilised or "
                               "aligned")

    def apply(self, project: Project, journal: Journal) -> None:
        journal.setattr(project, "stabilization", None, "stabilization")
        journal.setattr(project, "alignment", None, "stabilization")
        if project.show_stabilized:
            journal.setattr(project, "show_stabilized", False, "stabilization")

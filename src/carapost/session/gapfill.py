"""The clean-up actions of a `carapost.Session`: Interpolate Gaps, Filter Trajectories,
Find Problems and its repairs (mixed into the Session, on the processing recipe).

Each action is one History entry; undo restores the project bit for bit::

    s.interpolate_gaps()                         # all points, active range, guide method
    s.interpolate_gaps(method="auto")            # per gap, the best method by self-test
    s.gap_report()["gaps"][0]                    # method, estimated error (mm), status
    s.filter_trajectories(8.0, order=4)
    for problem in s.find_problems():
        s.repair(problem)                        # one History entry each
"""

from __future__ import annotations

import json
import logging
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from carapost.commands.recipe import ApplyResult, Job
from carapost.commands.stack import Command, CommandError, CommandStack
from carapost.model.project import Project

log = logging.getLogger("carapost.session")

__all__ = ["GapFillActions"]


class GapFillActions:
    """Interpolate Gaps, Filter Trajectories, Find Problems (mixed into the Session)."""

    project: Project
    stack: CommandStack
    _gap_report: dict[str, Any] | None = None

    @classmethod
    def import_c3d(cls, path: str | Path, **kwargs: Any) -> Any:
        """File > Import C3D: a session on a new project holding the 3D points and labels
        of a C3D file of any vendor (no cameras; see `carapost.io.c3d_points`).

        Raises
        ------
        CaraFileError
            Missing or unreadable file, or a file with no 3D points.
        """
        from carapost.io.c3d_points import project_from_c3d

        return cls(project_from_c3d(path), **kwargs)  # type: ignore[call-arg]

    def prepare_interpolate_gaps(self, points: Iterable[int] | None = None,
                                 method: str | None = None, *, max_gap: int | None = None,
                                 frames: tuple[int, int] | None = None, **options: Any) -> Job:
        """Prepare :meth:`interpolate_gaps` (see ``Session.prepare``)."""
        from carapost.commands.gapfill import prepare_interpolate_gaps

        return prepare_interpolate_gaps(self.project, points, frames=frames, method=method,
                                        max_gap=max_gap, **options)

    def interpolate_gaps(self, points: Iterable[int] | None = None,
                         method: str | None = "guide",
                         *, max_gap: int | None = None, frames: tuple[int, int] | None = None,
                         progress: Any = None, report: str | Path | None = None,
                         **options: Any) -> ApplyResult | None:
        """Process > Interpolate Gaps with the Gap-Filling and Clean-up Parameters.

        Parameters
        ----------
        points : iterable of int, optional
            Point ids (default: the selected points, or all).
        method : {"guide", "auto", "lowrank", "spline"} or None
            Default "guide", the reference workflow's neighbour prediction; "auto"
            (recommended for faces) picks per gap the method with the lowest hold-out
            error. None: the project's Gap-Filling Method property (what Process >
            Interpolate Gaps uses; "guide" unless changed).
        max_gap : int, optional
            Longest gap filled (frames; 0 = all). Default: Max Gap Length.
        frames : (int, int), optional
            Default: the active range.
        progress : callable, optional
        report : path, optional
            Also write the gap table as JSON (see :meth:`gap_report`).
        **options
            Other ``GapFillParameters`` fields (``use_forwards_prediction=False``, ...).

        Returns
        -------
        ApplyResult or None
            None when nothing was filled (the messages are logged).
        """
        job = self.prepare_interpolate_gaps(points, method, max_gap=max_gap, frames=frames,
                                            **options)
        result = job.compute(progress)
        self._gap_report = result.report()
        if report is not None:
            self.write_gap_report(report)
        if result.changes_nothing():
            log.warning(result.message)
            return None
        return self.apply(result)  # type: ignore[attr-defined]

    def gap_report(self) -> dict[str, Any] | None:
        """The last Interpolate Gaps run's gaps: ``{"filled_samples", "gaps": [{point_id,
        label, first, last, length, method, estimated_rmse_mm, holdouts, status}],
        "messages"}`` (None before the first run). The per-sample estimate is the
        project's ``points.sigma`` (mm)."""
        if self._gap_report is not None:
            return self._gap_report
        from carapost.commands.gapfill import GapFillResult

        for cmd in reversed(self.stack.applied()):   # a run from the window's worker
            result = getattr(cmd, "result", None)
            if isinstance(result, GapFillResult):
                return result.report()
        return None

    def write_gap_report(self, path: str | Path) -> Path:
        """Write :meth:`gap_report` as JSON (atomically)."""
        from carapost.io.atomic import atomic_output

        rep = self.gap_report()
        if rep is None:
            raise CommandError("no Interpolate Gaps run to report")
        path = Path(path)
        with atomic_output(path) as fh:
            fh.write(json.dumps(rep, indent=1).encode("utf-8"))
        return path

    def prepare_filter_trajectories(self, cutoff_hz: float | None = None,
                                    order: int | None = None,
                                    points: Iterable[int] | None = None, *,
                                    frames: tuple[int, int] | None = None) -> Job:
        """Prepare :meth:`filter_trajectories`."""
        from carapost.commands.gapfill import prepare_filter_trajectories

        return prepare_filter_trajectories(self.project, cutoff_hz, order, points,
                                           frames=frames)

    def filter_trajectories(self, cutoff_hz: float | None = None, order: int | None = None,
                            points: Iterable[int] | None = None, *,
                            frames: tuple[int, int] | None = None,
                            progress: Any = None) -> ApplyResult | None:
        """Process > Filter Trajectories: zero-phase Butterworth low-pass (cut-off in Hz,
        order; default the Clean-up Parameters) of the selected (or all) points over the
        active range, never across a gap. Filtered samples become "filtered"; undo
        restores the raw data."""
        job = self.prepare_filter_trajectories(cutoff_hz, order, points, frames=frames)
        return self.run(job, progress)  # type: ignore[attr-defined]

    def prepare_remove_filtering(self, points: Iterable[int] | None = None, *,
                                 frames: tuple[int, int] | None = None) -> Job:
        """Prepare :meth:`remove_filtering`."""
        from carapost.commands.gapfill import prepare_remove_filtering

        return prepare_remove_filtering(self.project, points, frames=frames)

    def remove_filtering(self, points: Iterable[int] | None = None, *,
                         frames: tuple[int, int] | None = None) -> ApplyResult | None:
        """Process > Remove Filtering: the filtered samples of the selected (or all)
        points over the active range get back their raw values from before Filter
        Trajectories (positions, reconstruction kind, sigma), as one History entry. The
        raw values are kept in the project (and its file), so this works after undo
        history is gone; samples tracked, edited or filled since keep their newer values.

        Returns None (a warning logged) when there is no filtered sample to restore.
        """
        job = self.prepare_remove_filtering(points, frames=frames)
        result = job.compute(None)
        if result.changes_nothing():
            log.warning(result.message)
            return None
        return self.apply(result)  # type: ignore[attr-defined]

    def find_problems(self, points: Iterable[int] | None = None,
                      frames: tuple[int, int] | None = None) -> list:
        """Find Problems: gaps, spikes and suspected identity swaps (see
        :func:`carapost.commands.gapfill.find_problems`); changes nothing."""
        from carapost.commands.gapfill import find_problems

        return find_problems(self.project, points, frames)

    def swap_identities(self, point_a: int, point_b: int, frame: int,
                        last: int | None = None) -> Command:
        """Exchange two points' data from ``frame`` to the end of the active range."""
        from carapost.commands.gapfill import SwapIdentities

        return self.stack.push(SwapIdentities(self.project, (point_a, point_b), frame, last))

    def repair(self, problem: Any) -> Command | None:
        """The one-click repair of a Find Problems entry, as one History entry: a gap is
        filled, a spike is cut and filled, a swap exchanges the two identities from its
        frame on."""
        if problem.kind == "swap":
            a, b = problem.point_ids
            return self.swap_identities(a, b, problem.first)
        (pid,) = problem.point_ids
        extra = None
        if problem.kind == "spike":
            col = int(self.project.points.index_of([pid])[0])
            extra = np.zeros((self.project.n_frames, self.project.points.count), bool)
            extra[problem.first:problem.last + 1, col] = True
        job = self.prepare_interpolate_gaps(
            [pid], frames=(problem.first, problem.last), extra_fill=extra,
            description=f"Repair {problem.kind}: {problem.text}")
        result = job.compute(None)
        if result.changes_nothing():
            why = ("; ".join(result.messages)
                   or "nothing left to fill there (run Find Problems again)")
            raise CommandError(f"Repair: {problem.text}: {why}")
        return self.apply(result)  # type: ignore[attr-defined]


def fill_gaps_file(source: str | Path, output: str | Path, *, method: str | None = "guide",
                   max_gap: int | None = None, report: str | Path | None = None,
                   progress: Any = None) -> dict[str, Any]:
    """``carapost fill-gaps``: fill every gap of a ``.c3d`` or ``.cara`` file and write
    a ``.c3d`` or ``.cara`` file (all frames, all points).

    Returns the gap report (see ``Session.gap_report``), also written to ``report``.

    Raises
    ------
    CaraFileError
        Unreadable input, a C3D without points, an unwritable output.
    CommandError
        Bad options.
    """
    from carapost.io.errors import CaraFileError
    from carapost.session import Session

    src, out = Path(source), Path(output)
    kinds = (".c3d", ".cara")
    for p, what in ((src, "input"), (out, "output")):
        if p.suffix.lower() not in kinds:
            raise CaraFileError(p, f"the {what} must be a .c3d or .cara file")
    session = Session.import_c3d(src) if src.suffix.lower() == ".c3d" else Session.open(src)
    with session:
        p = session.project
        p.active_range = (0, max(p.n_frames - 1, 0))
        p.selection = type(p.selection)()
        session.interpolate_gaps(method=method, max_gap=max_gap, progress=progress)
        rep = session.gap_report() or {"filled_samples": 0, "gaps": [], "messages": []}
        if out.suffix.lower() == ".c3d":
            session.export_c3d(out, frame_range="all", include_brim=True)
        else:
            session.save(out)
        rep = {"input": str(src), "output": str(out), **rep}
        session._gap_report = rep
        if report is not None:
            session.write_gap_report(report)
    return rep

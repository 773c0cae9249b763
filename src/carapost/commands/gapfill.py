"""Interpolate Gaps, Filter Trajectories and the Find Problems repairs, on the recipe.

``prepare_interpolate_gaps`` and ``prepare_filter_trajectories`` snapshot the point
arrays (every point serves as a neighbour; the whole take gives the self-test its
stretches) and return jobs of :mod:`carapost.commands.recipe`. Their results write only
the samples they change (:meth:`Journal.point_mask`), so undo costs what the edit
changed and restores the model bit for bit.

What a run may read and what it fills:

- samples to fill: in the active range (or the given frames), of the selected points
  (all when none is selected), with no 3D position or 3D from a single camera only
  (reconstruction "single sensor"); earlier fills ("interpolated") too when Overwrite
  Existing Filled Gaps is on;
- samples read: every other sample with a 3D position, any point, any frame.

Filled samples get reconstruction "interpolated", residual NaN (the C3D writer writes
word 4 = 0 for them: residual 0, camera mask cleared) and ``sigma`` = the estimated
error from the self-test (mm). Filtered samples get "filtered" (interpolated ones stay
"interpolated", so Remove Interpolated 3D Points still finds them) and keep no sigma.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from carapost.algorithms.cleanup import FilterParameters, lowpass
from carapost.algorithms.codes import (
    RAW_POINT_ARRAYS,
    RECON_FILTERED,
    RECON_INTERPOLATED,
    RECON_NONE,
    RECON_SINGLE_SENSOR,
)
from carapost.algorithms.gapfill import GapFillParameters, GapTable, fill_gaps
from carapost.algorithms.params import from_mapping
from carapost.commands.recipe import Job, Progress, Result
from carapost.commands.stack import Command, CommandError, Journal
from carapost.model.project import Project

log = logging.getLogger("carapost.gapfill")

__all__ = ["FilterJob", "FilterResult", "GapFillJob", "GapFillResult", "RemoveFilteringJob",
           "RemoveFilteringResult", "SwapIdentities", "prepare_filter_trajectories",
           "prepare_interpolate_gaps", "prepare_remove_filtering"]

_FILL_ARRAYS = ("positions", "recon", "residual", "sigma")


def _columns(project: Project, point_ids: Any) -> NDArray[np.intp]:
    pts = project.points
    ids = project.selection.points if point_ids is None else point_ids
    ids = sorted({int(p) for p in ids}) if ids else []
    if not ids:
        return np.arange(pts.count, dtype=np.intp)
    try:
        return np.sort(pts.index_of(ids))
    except KeyError as exc:
        raise CommandError(str(exc.args[0])) from None


def _range(project: Project, frames: tuple[int, int] | None, what: str) -> tuple[int, int]:
    a, b = project.active_range if frames is None else (int(frames[0]), int(frames[1]))
    if not (0 <= a <= b < project.n_frames):
        raise CommandError(f"{what}: frames {a}-{b} are outside the take "
                           f"(0-{project.n_frames - 1})")
    return a, b


@dataclass
class SparseSamples:
    """Samples of a frames x points block: the mask and the values under it."""

    first: int
    ids: NDArray[np.int64]
    mask: NDArray[np.bool_]                 # (n_frames, n_ids)
    values: dict[str, NDArray] = field(default_factory=dict)   # name -> values[mask]

    def write(self, project: Project, journal: Journal) -> None:
        pts = project.points
        cols = pts.index_of(self.ids)
        fr = slice(self.first, self.first + self.mask.shape[0])
        journal.point_mask(fr, cols, self.mask, list(self.values))
        for name, v in self.values.items():
            arr = pts.arrays[name]
            block = arr[fr][:, cols]
            block[self.mask] = v
            arr[fr, cols] = block


@dataclass
class SamplesResult(Result):
    """A result that writes some samples of the point arrays (`SparseSamples`): the
    shared part of Interpolate Gaps, Filter Trajectories and Remove Filtering."""

    samples: SparseSamples

    def write(self, project: Project, journal: Journal) -> None:
        self.samples.write(project, journal)

    def changes_nothing(self) -> bool:
        return not self.samples.mask.any()


@dataclass
class GapFillResult(SamplesResult):
    """Filled samples of Interpolate Gaps, and the gap table with its estimates."""

    gaps: GapTable
    messages: list[str]
    labels: list[str]
    point_ids: NDArray[np.int64]
    first: int
    description: str = "Interpolate Gaps"
    message: str = ""
    cancelled: bool = False

    def report(self) -> dict[str, Any]:
        """The gaps as plain data (for the sidecar report and the Find Problems pane):
        one dict per gap with the point's id and label, take frames, method, estimated
        RMS error (mm) and status."""
        g = self.gaps
        rows = []
        for i in range(len(g)):
            col = int(g.point[i])
            est = float(g.estimate_mm[i])
            rows.append({"point_id": int(self.point_ids[col]), "label": self.labels[col],
                         "first": int(g.start[i]) + self.first,
                         "last": int(g.end[i]) + self.first,
                         "length": int(g.end[i] - g.start[i] + 1),
                         "method": str(g.method[i]) or None,
                         "estimated_rmse_mm": None if not np.isfinite(est) else round(est, 4),
                         "holdouts": int(g.holdouts[i]),
                         "status": g.status[i]})
        filled = int(self.samples.mask.sum())
        return {"filled_samples": filled, "gaps": rows, "messages": list(self.messages)}


@dataclass
class GapFillJob(Job):
    positions: NDArray[np.float32]          # (F, P, 3), the whole take
    fill: NDArray[np.bool_]                 # (F, P)
    known: NDArray[np.bool_]
    point_ids: NDArray[np.int64]
    labels: list[str]
    params: GapFillParameters
    rays: tuple[NDArray, NDArray] | None
    description: str

    def compute(self, progress: Progress = None) -> GapFillResult:
        out = fill_gaps(self.positions, self.fill, self.known, params=self.params,
                        rays=self.rays, labels=self.labels, progress=progress)
        rows = np.flatnonzero(out.filled.any(1))
        cols = np.flatnonzero(out.filled.any(0))
        first = int(rows[0]) if len(rows) else 0
        last = int(rows[-1]) if len(rows) else -1
        mask = out.filled[first:last + 1][:, cols]
        pos = out.positions[first:last + 1][:, cols][mask].astype(np.float32)
        sig = out.sigma[first:last + 1][:, cols][mask]
        values = {"positions": pos,
                  "recon": np.full(len(pos), RECON_INTERPOLATED, np.int8),
                  "residual": np.full(len(pos), np.nan, np.float32),
                  "sigma": sig.astype(np.float32),
                  # a filled sample is new data: no raw value of an earlier filtering
                  "raw_positions": np.full((len(pos), 3), np.nan, np.float32),
                  "raw_recon": np.full(len(pos), RECON_NONE, np.int8),
                  "raw_sigma": np.full(len(pos), np.nan, np.float32)}
        samples = SparseSamples(first, self.point_ids[cols].copy(), mask, values)
        n = int(mask.sum())
        gaps = out.gaps
        done = int((gaps.method != "").sum())
        msg = f"{self.description}: {done} of {len(gaps)} gap(s) filled ({n} samples)"
        if out.messages:
            msg += "; " + "; ".join(out.messages)
        log.info(msg)
        return GapFillResult(samples, out.gaps, list(out.messages), self.labels,
                             self.point_ids, 0,
                             self.description, msg, out.cancelled)


def _single_rays(project: Project, fill: NDArray[np.bool_]) -> tuple[NDArray, NDArray] | None:
    """The ray of every sample to fill that has exactly one attached detection."""
    cal = project.calibration
    if cal.intrinsics is None or project.n_cameras == 0:
        return None
    pts = project.points
    attached = pts.detection >= 0
    one = fill & (attached.sum(-1) == 1) & cal.solved[:, None]
    if not one.any():
        return None
    from carapost.algorithms.camera import pixel_rays

    f, p = np.nonzero(one)
    c = np.argmax(attached[f, p], axis=-1)
    uvc = np.full((len(f), project.n_cameras, 2), np.nan)
    uvc[np.arange(len(f)), c] = pts.obs[f, p, c]
    with np.errstate(invalid="ignore"):
        o, d = pixel_rays(uvc, cal.R[f], cal.t[f], cal.intrinsics)
    origins = np.full(pts.positions.shape, np.nan)
    dirs = np.full(pts.positions.shape, np.nan)
    origins[f, p] = o[np.arange(len(f)), c]
    dirs[f, p] = d[np.arange(len(f)), c]
    ok = np.isfinite(dirs).all(-1)
    return (origins, dirs) if ok.any() else None


def prepare_interpolate_gaps(project: Project, point_ids: Any = None, *,
                             frames: tuple[int, int] | None = None, method: str | None = None,
                             max_gap: int | None = None, extra_fill: NDArray | None = None,
                             description: str | None = None, **overrides: Any) -> GapFillJob:
    """Process > Interpolate Gaps (see the module).

    Parameters
    ----------
    project : Project
    point_ids : iterable of int, optional
        Points to fill (default: the selected points, or all).
    frames : (int, int), optional
        Inclusive frame range (default: the active range).
    method : {"auto", "guide", "lowrank", "spline"}, optional
        Default: the Gap-Filling Method property.
    max_gap : int, optional
        Longest gap filled, frames (0: all). Default: the Max Gap Length property.
    extra_fill : ndarray (F, P) bool, optional
        Further samples to cut and fill (a spike repair).
    **overrides
        Other :class:`GapFillParameters` fields.
    """
    pts = project.points
    if pts.count == 0 or project.n_frames == 0:
        raise CommandError("Interpolate Gaps: the project has no points")
    a, b = _range(project, frames, "Interpolate Gaps")
    cols = _columns(project, point_ids)
    if method is not None:
        overrides["method"] = str(method).strip().lower()
    if max_gap is not None:
        overrides["max_gap_frames"] = int(max_gap)
    try:
        params = from_mapping(GapFillParameters, project.properties, **overrides)
    except (ValueError, TypeError) as exc:
        raise CommandError(f"Interpolate Gaps: {exc}") from None
    X = pts.positions
    finite = np.isfinite(X).all(-1)
    recon = pts.recon
    target = ~finite | (recon == RECON_SINGLE_SENSOR)
    if params.overwrite_existing_filled_gaps:
        target |= recon == RECON_INTERPOLATED
    if extra_fill is not None:
        target |= np.asarray(extra_fill, bool)
    fill = np.zeros_like(target)
    sel = np.zeros(pts.count, bool)
    sel[cols] = True
    fill[a:b + 1] = target[a:b + 1] & sel[None]
    known = finite & ~fill
    if params.overwrite_existing_filled_gaps:
        known &= recon != RECON_INTERPOLATED
    rays = (_single_rays(project, fill) if params.allow_single_sensor_gap_filling
            else None)
    labels = [project.point_label(i) for i in range(pts.count)]
    desc = description or (f"Interpolate Gaps [{params.method}, frames {a}-{b}]")
    return GapFillJob(X.copy(), fill, known, pts.ids.copy(), labels, params, rays, desc)


@dataclass
class FilterResult(SamplesResult):
    """The filtered samples (and their raw values) of Filter Trajectories."""

    description: str = "Filter Trajectories"
    message: str = ""
    cancelled: bool = False


@dataclass
class FilterJob(Job):
    positions: NDArray[np.float32]          # (n, P, 3) block of the range
    recon: NDArray[np.int8]
    point_ids: NDArray[np.int64]
    first: int
    fps: float
    params: FilterParameters
    description: str
    #: the range's sigma and raw arrays (kept so that Remove Filtering can restore)
    raw: dict[str, NDArray] | None = None

    def compute(self, progress: Progress = None) -> FilterResult:
        out, changed = lowpass(self.positions, self.fps, self.params)
        values = {"positions": out[changed].astype(np.float32),
                  "recon": np.where(self.recon[changed] == RECON_INTERPOLATED,
                                    RECON_INTERPOLATED, RECON_FILTERED).astype(np.int8),
                  "sigma": np.full(int(changed.sum()), np.nan, np.float32)}
        if self.raw is not None:
            # the raw values: a sample filtered again keeps those from before its first
            # filtering
            had = np.isfinite(self.raw["raw_positions"][..., 0])[changed]
            now = {"raw_positions": self.positions[changed], "raw_recon": self.recon[changed],
                   "raw_sigma": self.raw["sigma"][changed]}
            for name, v in now.items():
                old = self.raw[name][changed]
                values[name] = np.where(had.reshape((-1,) + (1,) * (v.ndim - 1)), old,
                                        v).astype(old.dtype)
        s = SparseSamples(self.first, self.point_ids, changed, values)
        msg = (f"{self.description}: {int(changed.sum())} samples of "
               f"{int(changed.any(0).sum())} point(s) filtered")
        log.info(msg)
        return FilterResult(s, self.description, msg)


def prepare_filter_trajectories(project: Project, cutoff_hz: float | None = None,
                                order: int | None = None, point_ids: Any = None, *,
                                frames: tuple[int, int] | None = None) -> FilterJob:
    """Process > Filter Trajectories: zero-phase Butterworth low-pass per point over the
    active range, each run of present samples on its own (never across a gap)."""
    pts = project.points
    if pts.count == 0 or project.n_frames == 0:
        raise CommandError("Filter Trajectories: the project has no points")
    a, b = _range(project, frames, "Filter Trajectories")
    cols = _columns(project, point_ids)
    over: dict[str, Any] = {}
    if cutoff_hz is not None:
        over["filter_cutoff_hz"] = float(cutoff_hz)
    if order is not None:
        over["filter_order"] = int(order)
    try:
        params = from_mapping(FilterParameters, project.properties, **over)
    except (ValueError, TypeError) as exc:
        raise CommandError(f"Filter Trajectories: {exc}") from None
    fps = float(project.take.fps)
    if not params.filter_cutoff_hz < fps / 2:
        raise CommandError(f"Filter Trajectories: the cut-off ({params.filter_cutoff_hz:g} Hz) "
                           f"must be below half the frame rate ({fps / 2:g} Hz)")
    block = pts.positions[a:b + 1][:, cols]
    raw = {name: pts.arrays[name][a:b + 1][:, cols] for name in ("sigma",) + RAW_POINT_ARRAYS}
    return FilterJob(block, pts.recon[a:b + 1][:, cols], pts.ids[cols].copy(), a, fps, params,
                     f"Filter Trajectories [{params.filter_cutoff_hz:g} Hz, order "
                     f"{params.filter_order}, frames {a}-{b}]", raw)


@dataclass
class RemoveFilteringResult(SamplesResult):
    """The raw samples Remove Filtering puts back."""

    description: str = "Remove Filtering"
    message: str = ""
    cancelled: bool = False


@dataclass
class RemoveFilteringJob(Job):
    """Restores the raw values kept by Filter Trajectories (a quick job: masks only)."""

    arrays: dict[str, NDArray]              # recon, raw_* of the (n, p) block
    point_ids: NDArray[np.int64]
    first: int
    description: str

    def compute(self, progress: Progress = None) -> RemoveFilteringResult:
        a = self.arrays
        raw = np.isfinite(a["raw_positions"][..., 0])
        # only samples still holding the filter's output: a sample tracked, edited or
        # filled since (its reconstruction kind changed) keeps its newer value
        still = (a["recon"] == RECON_FILTERED) | ((a["recon"] == RECON_INTERPOLATED)
                                                  & (a["raw_recon"] == RECON_INTERPOLATED))
        mask = raw & still
        n = int(mask.sum())
        values = {"positions": a["raw_positions"][mask], "recon": a["raw_recon"][mask],
                  "sigma": a["raw_sigma"][mask],
                  "raw_positions": np.full((n, 3), np.nan, np.float32),
                  "raw_recon": np.full(n, RECON_NONE, np.int8),
                  "raw_sigma": np.full(n, np.nan, np.float32)}
        s = SparseSamples(self.first, self.point_ids, mask, values)
        msg = (f"{self.description}: {n} raw samples of {int(mask.any(0).sum())} point(s) "
               "restored" if n else f"{self.description}: no filtered samples there")
        log.info(msg)
        return RemoveFilteringResult(s, self.description, msg)


def prepare_remove_filtering(project: Project, point_ids: Any = None, *,
                             frames: tuple[int, int] | None = None) -> RemoveFilteringJob:
    """Process > Remove Filtering: the raw values of the filtered samples of the selected
    (or all) points over the active range, as before Filter Trajectories (positions,
    reconstruction kind, sigma)."""
    pts = project.points
    if pts.count == 0 or project.n_frames == 0:
        raise CommandError("Remove Filtering: the project has no points")
    a, b = _range(project, frames, "Remove Filtering")
    cols = _columns(project, point_ids)
    arrays = {name: pts.arrays[name][a:b + 1][:, cols] for name in ("recon",) + RAW_POINT_ARRAYS}
    return RemoveFilteringJob(arrays, pts.ids[cols].copy(), a,
                              f"Remove Filtering [frames {a}-{b}]")


class SwapIdentities(Command):
    """Exchange two points' data from a frame to the end of the active range (the repair
    of a suspected identity swap)."""

    def __init__(self, project: Project, point_ids: tuple[int, int], frame: int,
                 last: int | None = None) -> None:
        super().__init__()
        i, j = (int(p) for p in point_ids)
        if i == j:
            raise CommandError("Swap Identities: two different points are needed")
        try:
            project.points.index_of([i, j])
        except KeyError as exc:
            raise CommandError(str(exc.args[0])) from None
        end = project.active_range[1] if last is None else int(last)
        f = int(frame)
        if not 0 <= f <= end < project.n_frames:
            raise CommandError(f"Swap Identities: frames {f}-{end} are outside the take")
        self.ids, self.frames = (i, j), (f, end)
        ci, cj = project.points.index_of([i, j])
        self.description = (f"Swap Identities {project.point_label(int(ci))} / "
                            f"{project.point_label(int(cj))} [frames {f}-{end}]")

    def apply(self, project: Project, journal: Journal) -> None:
        pts = project.points
        cols = pts.index_of(list(self.ids))
        fr = slice(self.frames[0], self.frames[1] + 1)
        journal.point_block(fr, cols)
        for arr in pts.arrays.values():
            a = arr[fr, cols[0]].copy()
            arr[fr, cols[0]] = arr[fr, cols[1]]
            arr[fr, cols[1]] = a


@dataclass(frozen=True)
class Problem:
    """One entry of Find Problems.

    Attributes
    ----------
    kind : {"gap", "spike", "swap"}
    point_ids : tuple of int
        One point (gap, spike) or two (swap).
    first, last : int
        Take frames concerned (a swap: the frame it happens at, twice).
    size_mm : float
        Spike: distance from the local motion; swap: the jump; gap: NaN.
    text : str
        One line for the pane and the log.
    """

    kind: str
    point_ids: tuple[int, ...]
    first: int
    last: int
    size_mm: float
    text: str


def find_problems(project: Project, point_ids: Any = None,
                  frames: tuple[int, int] | None = None) -> list[Problem]:
    """Gaps, spikes and suspected identity swaps of the selected (or all) points in the
    active range, ordered by frame. Swaps are looked for among all points (a point can
    swap with one that is not selected) and reported when one of the two is selected."""
    from carapost.algorithms.cleanup import ProblemParameters, find_spikes, find_swaps
    from carapost.algorithms.gapfill import runs
    from carapost.algorithms.gapfill_methods import head_frame, to_head

    pts = project.points
    if pts.count == 0 or project.n_frames == 0:
        return []
    a, b = _range(project, frames, "Find Problems")
    cols = _columns(project, point_ids)
    prm = from_mapping(ProblemParameters, project.properties)
    X = pts.positions[a:b + 1].astype(np.float64)
    known = np.isfinite(X).all(-1)
    R, t, _ = head_frame(np.where(known[..., None], X, 0.0), known, zeroed=True)
    Y = to_head(np.where(known[..., None], X, 0.0), R, t)
    Y[~known] = np.nan
    sel = np.zeros(pts.count, bool)
    sel[cols] = True
    name = project.point_label
    out: list[Problem] = []
    # interior gaps (runs with data on both sides)
    p, s, e = runs(~known)
    inner = (s > 0) & (e < len(X) - 1) & sel[p]
    for c, f0, f1 in zip(p[inner], s[inner], e[inner], strict=True):
        out.append(Problem("gap", (int(pts.ids[c]),), int(f0) + a, int(f1) + a, float("nan"),
                           f"Gap: {name(int(c))}, frames {f0 + a}-{f1 + a} "
                           f"({f1 - f0 + 1} frames)"))
    for sp in find_spikes(X, prm, Y=Y):
        if sel[sp.point]:
            out.append(Problem("spike", (int(pts.ids[sp.point]),), sp.start + a, sp.end + a,
                               sp.size_mm, f"Spike: {name(sp.point)}, frame {sp.start + a}"
                               + (f"-{sp.end + a}" if sp.end > sp.start else "")
                               + f" ({sp.size_mm:.1f} mm)"))
    for sw in find_swaps(X, prm, Y=Y):
        i, j = sw.points
        if sel[i] or sel[j]:
            out.append(Problem("swap", (int(pts.ids[i]), int(pts.ids[j])), sw.frame + a,
                               sw.frame + a, sw.jump_mm,
                               f"Suspected swap: {name(i)} / {name(j)} at frame "
                               f"{sw.frame + a} ({sw.jump_mm:.1f} mm jump)"))
    out.sort(key=lambda q: (q.first, q.kind, q.point_ids))
    return out

"""Initialize from ROM, following the processing recipe; Load ROM.

``prepare_rom_initialisation(project, ...)`` snapshots the loaded ROM's frame and this
frame's detections; ``job.compute()`` matches them with no project
(:func:`carapost.algorithms.rom.initialize_from_rom`); ``ApplyResult(result)`` writes the
matched points, cameras, sticks and labels. ``InitializeFromRom(project, ...)`` does all
three.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from carapost.algorithms.camera import CameraIntrinsics
from carapost.algorithms.params import from_mapping
from carapost.algorithms.rom import RomParameters, initialize_from_rom
from carapost.algorithms.tracking import RaggedDetections, TrackingParameters
from carapost.commands.process import check_frame, refuse, set_cameras
from carapost.commands.recipe import Job, Progress, Result, ResultCommand
from carapost.commands.stack import Command, Journal
from carapost.commands.tracking import tracked_arrays, tracking_parameters
from carapost.model.project import KIND_BRIM, KIND_FACE, Project, RomReference, Stick

log = logging.getLogger("carapost.process")

__all__ = ["InitializeFromRom", "LoadRom", "RomComputation", "RomJob", "RomResultCommand",
           "prepare_rom_initialisation"]


class LoadRom(Command):
    """Load ROM: keep a ``.cara`` project to initialise this take from."""

    def __init__(self, project: Project, path: str | Path):
        from carapost.io.cara import load_project
        from carapost.io.errors import CaraFileError

        super().__init__()
        p = Path(path)
        try:
            rom = load_project(p)
        except CaraFileError as exc:
            raise refuse(f"Load ROM: {exc}") from exc  # the window shows the file error
        if rom.points.count == 0:
            raise refuse(f"Load ROM: {p} has no points to initialise from")
        if rom.calibration.intrinsics is None:
            raise refuse(f"Load ROM: {p} has no camera calibration")
        self.reference = RomReference(path=str(p.absolute()), project=rom)
        self.description = f"Load ROM {p.name}"
        log.info("Loaded ROM %s: %d points, %d frames", p, rom.points.count, rom.n_frames)

    def apply(self, project: Project, journal: Journal) -> None:
        old = project.rom

        def undo() -> None:
            project.rom = old

        journal.call(undo, "rom")
        project.rom = self.reference


@dataclass
class RomComputation(Result):
    """What a :class:`RomJob` found: the ROM's points matched at one frame of this take."""

    frame: int
    rom_frame: int
    labels: list[str]
    kind: NDArray[np.int8]
    rom_ids: NDArray[np.int64]
    existing_ids: NDArray[np.int64]  # id of the existing point reused per row, -1 = new
    result: Any
    intrinsics: Any
    sticks: list[tuple[int, int, tuple[int, int, int]]]  # rows into the result, colour
    rom_label_list: list[str]
    brim_only: bool
    description: str

    def write(self, project: Project, journal: Journal) -> None:
        res = self.result
        f = self.frame
        pts = project.points
        cal = project.calibration
        if cal.intrinsics is None:
            journal.setattr(cal, "intrinsics", self.intrinsics.copy(), "cameras")
        # brim points of the ROM replace the take's brim (the structure comes with them)
        new_rows = np.flatnonzero(self.existing_ids < 0)
        if (self.kind[new_rows] == KIND_BRIM).any():
            old_brim = np.flatnonzero(pts.kind == KIND_BRIM)
            reused = set(int(i) for i in self.existing_ids[self.existing_ids >= 0])
            drop = [c for c in old_brim if int(pts.ids[c]) not in reused]
            if drop:
                journal.remove_points(np.asarray(drop, dtype=np.intp))
        cols = np.empty(len(self.labels), dtype=np.intp)
        old = self.existing_ids >= 0
        if old.any():
            cols[old] = pts.index_of(self.existing_ids[old])
        if new_rows.size:
            cols[new_rows] = journal.append_points(
                new_rows.size, labels=[self.labels[j] for j in new_rows],
                kind=self.kind[new_rows])
        brim_rows = np.flatnonzero(self.kind == KIND_BRIM)
        if brim_rows.size:
            # the brim structure holds in every frame
            journal.write_points(slice(None), cols[brim_rows], {
                "positions": res.structure[brim_rows].astype(np.float32)[None]})
        journal.write_points(f, cols, tracked_arrays(lambda name: getattr(res, name)))
        set_cameras(journal, project, f, res.R, res.t)
        if not self.brim_only:
            ids = pts.ids[cols]
            new_sticks = [Stick(int(ids[a]), int(ids[b]), tuple(col))
                          for a, b, col in self.sticks]
            have = {(s.a, s.b) for s in project.sticks}
            new_sticks = [s for s in new_sticks if (s.a, s.b) not in have]
            if new_sticks:
                journal.setattr(project, "sticks", project.sticks + new_sticks, "sticks")
            missing = [lab for lab in self.rom_label_list if lab not in project.labels]
            if missing:
                journal.setattr(project, "labels", project.labels + missing, "labels")


@dataclass
class RomJob(Job):
    """Snapshot for :func:`carapost.algorithms.rom.initialize_from_rom` (see
    :func:`prepare_rom_initialisation`): the ROM frame's points and cameras, this
    frame's detections, and how the matched rows map onto this take's points."""

    detections: list[tuple[NDArray, NDArray | None]]
    rom_points: NDArray
    rom_kind: NDArray
    rom_R: NDArray
    rom_t: NDArray
    intrinsics: CameraIntrinsics
    rom_params: RomParameters
    tracking_params: TrackingParameters
    template: RomComputation  # everything but the result (filled in by compute)
    what: str

    @property
    def description(self) -> str:  # type: ignore[override]
        """The History entry of the result."""
        return self.template.description

    def compute(self, progress: Progress = None) -> RomComputation:
        res = initialize_from_rom(self.detections, self.rom_points, self.rom_kind,
                                  self.rom_R, self.rom_t, self.intrinsics, self.rom_params,
                                  self.tracking_params)
        n_found = int(np.isfinite(res.positions).all(-1).sum())
        f = self.template.frame
        if n_found == 0:
            raise refuse(f"{self.what}: no ROM point could be matched at frame {f} (try a "
                          "ROM Frame Index closer to this frame's pose, or larger ROM "
                          "tracking distances)")
        log.info("%s: matched %d of %d points", self.template.description, n_found,
                 len(self.rom_points))
        return replace(self.template, result=res)


def prepare_rom_initialisation(project: Project, *, brim_only: bool = False,
                               frame: int | None = None) -> RomJob:
    """Match the loaded ROM's frame to a frame of this take: validate and snapshot.

    Raises
    ------
    CommandError
        No ROM loaded, camera counts differ, bad parameters, or no detections.
    """
    what = "Initialize from ROM" + (" [Brim Only]" if brim_only else "")
    if project.rom is None or project.rom.project is None:
        raise refuse(f"{what}: no ROM is loaded (Process > Load ROM first)")
    rom: Project = project.rom.project
    f = check_frame(project, frame, what)
    if rom.n_cameras != project.n_cameras:
        raise refuse(f"{what}: the ROM has {rom.n_cameras} cameras, this take "
                      f"{project.n_cameras}")
    try:
        rp = from_mapping(RomParameters, project.properties)
    except (TypeError, ValueError) as exc:
        raise refuse(f"{what}: {exc}") from None
    rf = rp.rom_frame_index
    if not 0 <= rf < rom.n_frames:
        raise refuse(f"{what}: ROM Frame Index {rf} is outside the ROM take (0-"
                      f"{rom.n_frames - 1})")
    if not rom.calibration.solved[rf]:
        raise refuse(f"{what}: the ROM's cameras are not solved at frame {rf}")
    tparams = tracking_parameters(project, what)
    rpts = rom.points
    X = rpts.positions[rf].astype(np.float64)
    keep = np.isfinite(X).all(-1)
    if brim_only:
        keep &= rpts.kind == KIND_BRIM
    rows = np.flatnonzero(keep)
    if rows.size == 0:
        raise refuse(f"{what}: the ROM has no {'brim ' if brim_only else ''}points with a "
                      f"3D position at frame {rf}")
    intr = project.calibration.intrinsics
    if intr is None or intr.n_cameras != project.n_cameras:
        intr = rom.calibration.intrinsics
    dets = RaggedDetections(project.detections.offsets, project.detections.arrays["centre"],
                            project.detections.arrays["axes"], project.n_cameras)(f)
    if not any(len(d[0]) for d in dets):
        raise refuse(f"{what}: frame {f} has no detections (run Detect Blobs)")
    labels = [rpts.labels[i] for i in rows]
    kind = rpts.kind[rows].copy()
    # reuse this take's points of the same label and kind instead of duplicating them
    existing = np.full(rows.size, -1, dtype=np.int64)
    by_label = {(lab, int(k)): int(i) for lab, k, i in zip(
        project.points.labels, project.points.kind, project.points.ids, strict=True) if lab}
    for j, (lab, k) in enumerate(zip(labels, kind, strict=True)):
        if lab:
            existing[j] = by_label.get((lab, int(k)), -1)
    if (existing >= 0).any():
        log.warning("%s: this take already has %d of the ROM's points; updating them at "
                    "frame %d instead of adding duplicates", what, int((existing >= 0).sum()),
                    f)
    elif (project.points.kind == KIND_FACE).any() and not brim_only:
        log.warning("%s: this take already has face points; the ROM's points are added "
                    "beside them", what)
    row_of = {int(rpts.ids[r]): j for j, r in enumerate(rows)}
    sticks = [(row_of[s.a], row_of[s.b], s.colour) for s in rom.sticks
              if s.a in row_of and s.b in row_of]
    desc = f"{what} [frame {f}, ROM frame {rf}]"
    intr = intr.copy()
    template = RomComputation(f, rf, labels, kind, rpts.ids[rows].copy(), existing, None,
                              intr, sticks, list(rom.labels), brim_only, desc)
    return RomJob(dets, X[rows], rpts.kind[rows].copy(), rom.calibration.R[rf].copy(),
                  rom.calibration.t[rf].copy(), intr, rp, tparams, template, what)


class RomResultCommand(ResultCommand):
    """Apply a :class:`RomComputation` as one undoable step (``ResultCommand``)."""


class InitializeFromRom(RomResultCommand):
    """Initialize from ROM / Initialize from ROM [Brim Only] at the current frame."""

    def __init__(self, project: Project, brim_only: bool = False, frame: int | None = None):
        super().__init__(prepare_rom_initialisation(project, brim_only=brim_only,
                                                    frame=frame).compute())

"""Label From Template, following the processing recipe; Set Point Labels.

``prepare_label_from_template(project, template)`` reduces both takes' face points to
their reference clouds (`carapost.algorithms.labelling.reference_cloud`, a few frames
only, so a long take costs little to snapshot); ``job.compute()`` registers them and
assigns the labels (`carapost.algorithms.labelling.label_from_template`); applying the
result renames the points as one History entry. :class:`SetPointLabels` gives many points
their labels in one step (scripts, and the demo's ROM labelled from its truth).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from carapost.algorithms.labelling import (
    LabelAssignment,
    LabellingParameters,
    label_from_template,
    reference_cloud,
    well_tracked_frames,
)
from carapost.algorithms.params import from_mapping
from carapost.commands.recipe import Job, Progress, Result
from carapost.commands.stack import Command, CommandError, Journal
from carapost.model.project import KIND_FACE, Project

log = logging.getLogger("carapost.process")

__all__ = ["LabelJob", "LabelResult", "SetPointLabels", "prepare_label_from_template",
           "write_labels"]


def write_labels(journal: Journal, project: Project, mapping: Mapping[int, str]) -> None:
    """Give points (by id) their labels in one journal step.

    A label names one point: another point holding it loses it. Labels new to the
    project's label list are appended to it.
    """
    pts = project.points
    wanted = {lab for lab in mapping.values() if lab}
    cols = pts.index_of(np.fromiter(mapping.keys(), dtype=np.int64, count=len(mapping)))
    target = {int(c): lab for c, lab in zip(cols, mapping.values(), strict=True)}
    new = ["" if lab in wanted and i not in target else lab
           for i, lab in enumerate(pts.labels)]
    for col, lab in target.items():
        new[col] = lab
    journal.setattr(pts, "labels", new, "labels")
    missing = [lab for lab in dict.fromkeys(mapping.values()) if lab and
               lab not in project.labels]
    if missing:
        journal.setattr(project, "labels", list(project.labels) + missing, "labels")


class SetPointLabels(Command):
    """Give many points their labels as one History entry (``{point id: label}``)."""

    def __init__(self, project: Project, mapping: Mapping[int, str],
                 description: str = "Set Point Labels") -> None:
        super().__init__()
        ids = set(int(i) for i in project.points.ids)
        bad = [i for i in mapping if int(i) not in ids]
        if bad:
            raise CommandError(f"{description}: no point with id {bad[0]}")
        labels = [str(v).strip() for v in mapping.values()]
        spaced = [lab for lab in labels if " " in lab]
        if spaced:
            raise CommandError(f"{description}: a label cannot contain a space "
                               f"({spaced[0]!r})")
        named = [lab for lab in labels if lab]
        if len(set(named)) != len(named):
            raise CommandError(f"{description}: a label is given to two points")
        self.mapping = {int(k): lab for k, lab in zip(mapping, labels, strict=True)}
        self.description = description

    def apply(self, project: Project, journal: Journal) -> None:
        write_labels(journal, project, self.mapping)


@dataclass
class LabelResult(Result):
    """Labels found by a :class:`LabelJob`: point id -> label, and what was left out."""

    mapping: dict[int, str] = field(default_factory=dict)
    assignment: LabelAssignment | None = None
    unassigned: list[str] = field(default_factory=list)  # template labels not given
    low_confidence: list[str] = field(default_factory=list)
    confidence: dict[str, float] = field(default_factory=dict)
    template_labels: list[str] = field(default_factory=list)

    def write(self, project: Project, journal: Journal) -> None:
        if self.mapping:
            write_labels(journal, project, self.mapping)
        missing = [lab for lab in self.template_labels if lab not in project.labels]
        if missing:  # the label list holds the whole marker set, assigned or not
            journal.setattr(project, "labels", list(project.labels) + missing, "labels")

    def changes_nothing(self) -> bool:
        return not self.mapping


@dataclass
class LabelJob(Job):
    """Snapshot of :func:`prepare_label_from_template`: two reference clouds."""

    template_cloud: NDArray[np.float64]   # (M, 3) mm
    template_frames: NDArray[np.float32]  # (K, M, 3) mm: single expressions to try
    template_labels: list[str]
    target_cloud: NDArray[np.float64]     # (P, 3) mm
    target_ids: NDArray[np.int64]
    params: LabellingParameters
    all_template_labels: list[str]
    description: str = "Label From Template"

    def compute(self, progress: Progress = None) -> LabelResult:
        stopped = [False]

        def tick(done: int, total: int) -> bool:
            if progress is not None and progress(done, total) is False:
                stopped[0] = True
                return False
            return True

        out = label_from_template(self.template_cloud, self.target_cloud, self.params,
                                  tick, template_frames=self.template_frames)
        cancelled = stopped[0]
        mapping = {int(self.target_ids[j]): self.template_labels[int(i)]
                   for j, i in enumerate(out.template_index) if i >= 0}
        given = set(mapping.values())
        unassigned = [lab for lab in self.template_labels if lab not in given]
        low = [self.template_labels[int(i)] for i in out.rejected]
        conf = {self.template_labels[int(i)]: round(float(out.confidence[j]), 3)
                for j, i in enumerate(out.candidate) if i >= 0}
        n_pts = len(self.target_ids)
        msg = (f"{self.description}: labelled {len(mapping)} of {n_pts} points from "
               f"{len(self.template_labels)} template labels")
        if unassigned:
            msg += (f"; left unassigned: {', '.join(unassigned)}"
                    + (f" (low confidence: {', '.join(low)})" if low else ""))
        result = LabelResult(mapping=mapping, assignment=out, unassigned=unassigned,
                             low_confidence=low, confidence=conf,
                             template_labels=list(self.all_template_labels))
        result.description = f"{self.description} [{len(mapping)} labelled]"
        result.message = msg
        result.cancelled = cancelled
        return result


def _face_columns(project: Project) -> NDArray[np.intp]:
    pts = project.points
    face = np.flatnonzero(pts.kind == KIND_FACE)
    has = np.isfinite(pts.positions[:, face, 0]).any(0) if len(face) else np.zeros(0, bool)
    return face[has]


def prepare_label_from_template(project: Project, template: Project | str | Path, *,
                                relabel: bool = False) -> LabelJob:
    """Label From Template: validate and snapshot (see the module docstring).

    Parameters
    ----------
    project : Project
        The tracked take to label.
    template : Project or str or Path
        A labelled take of the same marker set (a ``.cara`` file or a project).
    relabel : bool
        Also relabel points that already have a label (default: only unlabelled points
        get labels, and the labels already used in the take are not given again).

    Raises
    ------
    CommandError
        The template cannot be read or has no labelled face points with 3D, the take
        has no face points to label, or the parameters are bad.
    """
    what = "Label From Template"
    name = "template"
    if not isinstance(template, Project):
        from carapost.io.cara import load_project
        from carapost.io.errors import CaraFileError

        name = Path(template).name
        try:
            template = load_project(Path(template))
        except CaraFileError as exc:
            raise CommandError(f"{what}: {exc}") from None
    try:
        params = from_mapping(LabellingParameters, project.properties)
    except (TypeError, ValueError) as exc:
        raise CommandError(f"{what}: {exc}") from None
    tcols = [int(c) for c in _face_columns(template) if template.points.labels[c]]
    if len(tcols) < 3:
        raise CommandError(f"{what}: {name} has {len(tcols)} labelled face points with 3D "
                           "(label the template first)")
    pts = project.points
    cols = _face_columns(project)
    # a label held by a point without any 3D (a ROM marker never found in this take) is
    # free: the point that tracks that marker takes it
    empty = set(np.flatnonzero(pts.kind == KIND_FACE).tolist()) - set(cols.tolist())
    used = {lab for i, lab in enumerate(pts.labels) if lab and i not in empty}
    if not relabel:
        cols = np.asarray([c for c in cols if not pts.labels[c]], dtype=np.intp)
        tcols = [c for c in tcols if template.points.labels[c] not in used]
    if len(cols) == 0:
        raise CommandError(f"{what}: the take has no unlabelled face points with 3D "
                           "(track the take first)")
    if len(tcols) < 3:
        raise CommandError(f"{what}: every label of {name} is already used in this take")
    tpos = template.points.positions[:, tcols]
    tcloud = reference_cloud(tpos, params.reference_frames)
    tframes = tpos[well_tracked_frames(np.isfinite(tpos[..., 0]), 24)].copy()
    cloud = reference_cloud(pts.positions[:, cols], params.reference_frames)
    all_labels = [lab for lab in template.labels if lab] or [
        template.points.labels[c] for c in tcols]
    return LabelJob(tcloud, tframes, [template.points.labels[c] for c in tcols], cloud,
                    pts.ids[cols].copy(), params, all_labels,
                    f"{what} {name}")

"""Labelling actions of a `carapost.Session`: Label From Template, Set Point Labels."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from carapost.commands.recipe import ApplyResult, Job
from carapost.commands.stack import Command, CommandStack
from carapost.model.project import Project
from carapost.session.process import ProgressFn

__all__ = ["LabellingActions"]


class LabellingActions:
    """Mixin of `carapost.Session`: label a tracked take from a labelled one."""

    project: Project
    stack: CommandStack

    def prepare_label_from_template(self, template: Project | str | Path, *,
                                    relabel: bool = False) -> Job:
        """Prepare :meth:`label_from_template` (see :meth:`prepare`)."""
        from carapost.commands.labelling import prepare_label_from_template

        return prepare_label_from_template(self.project, template, relabel=relabel)

    def label_from_template(self, template: Project | str | Path, *, relabel: bool = False,
                            progress: ProgressFn | None = None) -> ApplyResult | None:
        """Process > Label From Template: give the take's unlabelled face points the
        labels of a labelled take of the same marker set (a ROM, or another take).

        Labels whose confidence is below the Label Confidence Threshold are left
        unassigned; the result's ``message`` lists them (and the command's
        ``result.unassigned``). ``relabel`` also relabels labelled points.

        Raises
        ------
        CommandError
            Unreadable template, nothing to label, bad parameters.
        """
        job = self.prepare_label_from_template(template, relabel=relabel)
        return self.run(job, progress)  # type: ignore[attr-defined]

    def set_point_labels(self, mapping: Mapping[int, str],
                         description: str = "Set Point Labels") -> Command:
        """Give many points (by id) their labels as one History entry."""
        from carapost.commands.labelling import SetPointLabels

        return self.stack.push(SetPointLabels(self.project, mapping, description))

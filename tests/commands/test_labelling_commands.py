"""Label From Template and Set Point Labels on the Session: labels, undo, refusals."""

from __future__ import annotations

import numpy as np
import pytest

from carapost.commands.stack import CommandError
from carapost.model.project import KIND_BRIM, KIND_FACE, Project, new_project
from carapost.session import Session
from carapost.synth.scene import SynthConfig, build_scene
from tests.commands.test_edit_commands import snapshot


def _project(X: np.ndarray, labels: list[str]) -> Project:
    F, M, _ = X.shape
    project = new_project(F, 4)
    project.points.append(M, labels=labels)
    project.points.positions[:] = X.astype(np.float32)
    return project


@pytest.fixture(scope="module")
def takes():
    tpl = build_scene(SynthConfig(preset="rom", frames=30, seed=2))
    tgt = build_scene(SynthConfig(preset="speech", frames=30, seed=9))
    rng = np.random.default_rng(3)
    order = rng.permutation(len(tgt.labels))
    template = _project(tpl.points3d, list(tpl.labels))
    return template, tgt.points3d[:, order], [tgt.labels[i] for i in order]


def test_label_from_template_labels_every_point_and_undoes_bit_identically(takes, tmp_path):
    template, X, truth = takes
    take = _project(X, [""] * X.shape[1])
    take.points.append(1, kind=KIND_BRIM)          # brim points are never labelled
    take.points.positions[:, -1] = 5.0
    session = Session(take)
    before = snapshot(take)
    cmd = session.label_from_template(template)
    face = take.points.kind == KIND_FACE
    assert [lab for lab, f in zip(take.points.labels, face, strict=True) if f] == truth
    assert take.points.labels[-1] == ""
    assert "labelled 89 of 89" in cmd.message
    assert session.history()[-1].description.startswith("Label From Template")
    after = snapshot(take)
    session.undo()
    assert snapshot(take) == before
    session.redo()
    assert snapshot(take) == after
    # from a file too, and only unlabelled points are labelled by default
    path = Session(template).save(tmp_path / "rom.cara")
    session.undo()
    session.rename_point(int(take.points.ids[0]), truth[0])
    cmd = session.label_from_template(path)
    assert take.points.labels[: X.shape[1]] == truth and "of 88 points" in cmd.message


def test_label_from_template_refuses_what_it_cannot_do(takes, tmp_path):
    template, X, truth = takes
    unlabelled = _project(X, [""] * X.shape[1])
    with pytest.raises(CommandError, match="labelled face points"):
        Session(unlabelled).label_from_template(unlabelled)
    with pytest.raises(CommandError, match="no unlabelled face points"):
        Session(_project(X, truth)).label_from_template(template)
    with pytest.raises(CommandError, match="Label From Template"):
        Session(unlabelled).label_from_template(tmp_path / "missing.cara")


def test_set_point_labels_is_one_step_and_moves_a_taken_label():
    project = _project(np.zeros((2, 3, 3)), ["A", "", ""])
    session = Session(project)
    before = snapshot(project)
    ids = [int(i) for i in project.points.ids]
    session.set_point_labels({ids[1]: "A", ids[2]: "B"})
    assert project.points.labels == ["", "A", "B"] and "B" in project.labels
    session.undo()
    assert snapshot(project) == before
    with pytest.raises(CommandError, match="two points"):
        session.set_point_labels({ids[0]: "X", ids[1]: "X"})
    with pytest.raises(CommandError, match="space"):
        session.set_point_labels({ids[0]: "X Y"})

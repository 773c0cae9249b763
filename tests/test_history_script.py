"""History as a script: ``carapost history --python`` and ``carapost replay`` reproduce a
project bit for bit on its own take; undone steps, groups, the window's prepare/apply
and projects saved and reopened are recorded as the History has them."""

from __future__ import annotations

import numpy as np
import pytest

from carapost import Session
from carapost.cli import main
from carapost.io.cara import load_project
from carapost.session.script import replay, to_python
from tests.small_takes import render_take


@pytest.fixture(scope="module")
def take(tmp_path_factory):
    return render_take(tmp_path_factory.mktemp("hist") / "Take00", frames=6, seed=7)


def same_project(a, b) -> list[str]:
    """The names of everything that differs between two projects (empty: identical)."""
    diff = []

    def eq(x, y):
        return (x.shape == y.shape and x.dtype == y.dtype
                and np.array_equal(x, y, equal_nan=x.dtype.kind == "f"))

    for k in a.points.arrays:
        if not eq(a.points.arrays[k], b.points.arrays[k]):
            diff.append(f"points/{k}")
    if not eq(a.detections.offsets, b.detections.offsets):
        diff.append("detections/offsets")
    for k in a.detections.arrays:
        if not eq(a.detections.arrays[k], b.detections.arrays[k]):
            diff.append(f"detections/{k}")
    for k in ("R", "t", "solved"):
        if not eq(getattr(a.calibration, k), getattr(b.calibration, k)):
            diff.append(f"calibration/{k}")
    for k in ("labels", "active_range", "view_range", "current_frame", "script"):
        if getattr(a, k) != getattr(b, k):
            diff.append(k)
    if a.points.ids.tolist() != b.points.ids.tolist() or a.points.labels != b.points.labels:
        diff.append("points/ids,labels")
    if a.properties.to_dict() != b.properties.to_dict():
        diff.append("properties")
    if [(s.a, s.b) for s in a.sticks] != [(s.a, s.b) for s in b.sticks]:
        diff.append("sticks")
    return diff


def test_replaying_a_projects_history_on_its_take_is_bit_identical(take, tmp_path, capsys):
    first = tmp_path / "first.cara"
    with Session.import_take(take) as s:
        s.detect_blobs("all", cameras=range(4), workers=1)
        s.set_property("Blob Parameters", "black_threshold", 0.45)
        s.solve_brim(frame=0, method="automatic")
        # the window's two-step form: prepare on the GUI thread, compute, apply
        job = s.prepare("initialize_3d", frame=0)
        s.apply(job.compute(None))
        s.set_active_range(0, 5)
        s.track_take(frame=0)
        s.current_frame = 2
        ids = s.project.points.ids[-4:].tolist()
        s.select(points=ids[:1])
        with s.group("Clean Up"):
            s.delete_selected()  # the selection made above
            s.rename_point(ids[1], "Lip_X")
        s.clear_selected("current", point_ids=[ids[2]])
        s.undo()  # undone: not part of the History any more
        s.create_stick([ids[1], ids[3]])
    s.save(first)
    # a second session on the saved project continues its record
    with Session.open(first) as s2:
        s2.set_active_range(1, 4)
        s2.save()
    assert [st.get("call") or st.get("group") for st in load_project(first).script] == [
        None, "detect_blobs", "set_property", "solve_brim", "initialize_3d",
        "set_active_range", "track_take", "Clean Up", "create_stick", "set_active_range"]

    assert main(["history", str(first), "--python"]) == 0
    script = tmp_path / "history.py"
    script.write_text(capsys.readouterr().out)
    text = script.read_text()
    assert "s.clear_selected" not in text and "with s.group('Clean Up'):" in text
    assert "s.current_frame = 2" in text and f"s.select(points=[{ids[0]}]" in text
    assert "s.initialize_3d(frame=0)" in text
    assert main(["replay", str(script), str(take), "-o", str(tmp_path / "again.cara")]) == 0
    assert same_project(load_project(first), load_project(tmp_path / "again.cara")) == []


def test_replay_on_another_take_and_bad_scripts(take, tmp_path):
    from tests.small_takes import copy_take

    steps = [{"import": {"take_brim": True}},
             {"call": "detect_blobs", "args": [], "kwargs": {"frames": "all"},
              "state": {"frame": 0, "points": [], "detections": [], "cameras": []}},
             {"call": "set_active_range", "args": [1, 3], "kwargs": {}}]
    script = tmp_path / "s.py"
    script.write_text(to_python(steps, name="demo"))
    other = copy_take(take, tmp_path / "Other", "Other")
    out = replay(script, other, tmp_path / "other.cara")
    p = load_project(out)
    assert p.detections.total > 0 and p.active_range == (1, 3)
    assert p.script == steps[:1] + [
        {**steps[1], "kwargs": {"frames": "all"}},
        {"call": "set_active_range", "args": [],
         "kwargs": {"first": 1, "last": 3},
         "state": {"frame": 0, "points": [], "detections": [], "cameras": []}}]
    (tmp_path / "bad.py").write_text("x = 1\n")
    with pytest.raises(ValueError, match="defines no replay"):
        replay(tmp_path / "bad.py", other, tmp_path / "x.cara")
    assert main(["replay", str(tmp_path / "bad.py"), str(other), "-o",
                 str(tmp_path / "x.cara")]) == 2
    assert not (tmp_path / "x.cara").exists()


def test_a_project_without_a_record_says_so(tmp_path, capsys):
    from carapost.model.project import new_project

    Session(new_project(3, 2)).save(tmp_path / "bare.cara")
    assert load_project(tmp_path / "bare.cara").script is None
    assert main(["history", str(tmp_path / "bare.cara"), "--python"]) == 2
    assert "holds no record" in capsys.readouterr().err


def test_module_examples():
    import doctest

    import carapost.session.script

    assert doctest.testmod(carapost.session.script).failed == 0


def test_hand_built_commands_and_undone_steps_in_the_record():
    from carapost.commands import edit
    from carapost.model.project import new_project

    project = new_project(6, 2)
    project.script = [{"import": {"take_brim": False}}]
    s = Session(project)
    s.set_active_range(1, 4)
    s.push(edit.SetRange(project, "view_range", (0, 3), "Set View Range By Hand"))
    s.set_active_range(2, 3)
    s.undo()
    steps = s.script_steps()
    assert [st.get("call") for st in steps] == [None, "set_active_range", "push"]
    text = to_python(steps, name="demo")
    assert "s.set_active_range(first=1, last=4)" in text
    assert "# not replayable: push('Set View Range By Hand')" in text
    assert "last=3" not in text  # undone
    assert "IMPORT = {'take_brim': False}" in text
    compile(text, "history.py", "exec")
    s.clear_history()  # the effect stays in the project, so does the record
    assert s.script_steps() == steps

"""The continuity chart recomputes only the point-frames a command's change names."""

from __future__ import annotations

import numpy as np

from carapost.commands import edit
from carapost.commands.stack import CommandStack
from carapost.model.project import RECON_INTERPOLATED
from carapost.ui.context import ViewContext
from carapost.ui.frames import FrameSource
from carapost.ui.views import continuity as cont
from tests.commands.test_edit_commands import make_project


def test_partial_redraw_of_the_changed_frames_and_points(qtbot, rng, monkeypatch):
    p = make_project(rng)
    ctx = ViewContext()
    ctx.set_project(p, FrameSource())
    view = cont.ContinuityView(ctx)
    qtbot.addWidget(view)
    p.events.subscribe(view.refresh)
    calls: list[tuple] = []
    real = cont.point_codes

    def spy(project, frames=None, columns=None):
        calls.append((frames, None if columns is None else list(columns)))
        return real(project, frames, columns)

    monkeypatch.setattr(cont, "point_codes", spy)
    stack = CommandStack(p)
    # point 2 has interpolated frames 20-22 (make_project); point 4 gets some at 7-8
    p.points.recon[7:9, 4] = RECON_INTERPOLATED
    view.refresh(None)
    calls.clear()
    stack.push(edit.RemoveInterpolated3DPoints(p))
    assert calls == [((7, 22), [2, 4])]  # the masked diff's box and its points only
    assert view.partial_updates == 1
    np.testing.assert_array_equal(view._codes, real(p))
    stack.undo()
    assert calls[-1] == ((7, 22), [2, 4]) and view.partial_updates == 2
    np.testing.assert_array_equal(view._codes, real(p))
    # a change of the point list still recomputes everything
    stack.push(edit.AddLabels(p, ["Lip_U"]))
    p.events.emit("point_list")
    assert calls[-1] == (None, None)
    np.testing.assert_array_equal(view._codes, real(p))

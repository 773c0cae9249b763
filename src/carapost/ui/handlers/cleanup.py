"""Clean-up items: File > Import C3D, Process > Remove Filtering and Process > Find
Problems (the pane)."""

from __future__ import annotations

import logging

from carapost.ui.context import ActionContext

log = logging.getLogger("carapost.ui")

#: File dialog filter of C3D files.
C3D_FILTER = "C3D files (*.c3d);;All files (*)"


def import_c3d(ctx: ActionContext, path: str | None = None) -> bool:
    """File > Import C3D: a new project holding the 3D points and labels of any vendor's
    C3D file (read on the worker), ready for Interpolate Gaps and the exports."""
    from carapost.io.c3d_points import project_from_c3d
    from carapost.session import Session
    from carapost.ui.handlers.file import maybe_save

    if path is None:
        if not maybe_save(ctx):
            return False
        path = ctx.dialogs.open_file("Import C3D", C3D_FILTER)
    if not path:
        return False
    src = path
    return ctx.run_job("Import C3D", lambda progress: project_from_c3d(src),
                       lambda project, cancelled: project is not None
                       and ctx.set_session(Session(project)))


def remove_filtering(ctx: ActionContext) -> bool:
    """Process > Remove Filtering: the raw data of the filtered samples of the selected
    (or all) points over the active range (one History entry)."""
    scope = ctx.selection.points
    done = ctx.act("Remove Filtering", ctx.session.remove_filtering,
                   sorted(scope) if scope else None)
    if done is None:
        ctx.status("Remove Filtering: no filtered samples there")
    return done is not None


def find_problems(ctx: ActionContext) -> None:
    """Process > Find Problems: list gaps, spikes and suspected swaps in the Find
    Problems pane (shown and raised)."""
    pane = getattr(ctx, "problems_pane", None)
    scope = ctx.selection.points
    problems = ctx.act("Find Problems", ctx.session.find_problems,
                       sorted(scope) if scope else
                       [int(i) for i in ctx.project.points.ids])
    if problems is None:
        return
    if pane is not None:
        pane.show_problems(problems, scope)
    counts = {k: sum(1 for p in problems if p.kind == k) for k in ("gap", "spike", "swap")}
    ctx.status(f"Find Problems: {counts['gap']} gaps, {counts['spike']} spikes, "
               f"{counts['swap']} suspected swaps", 6000)

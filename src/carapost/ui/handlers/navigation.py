"""View menu navigation: frames, keyframes, playback, ranges, point selection tools."""

from __future__ import annotations

import logging

import numpy as np

from carapost.model import queries
from carapost.ui.context import ActionContext

log = logging.getLogger("carapost.ui")


def go_to_frame(ctx: ActionContext) -> None:
    """Go To Frame (Ctrl+G)."""
    p = ctx.project
    f = ctx.dialogs.get_int("Go To Frame", "Frame:", p.current_frame, 0, max(p.n_frames - 1, 0))
    if f is not None:
        ctx.set_frame(f)


def go_start(ctx: ActionContext) -> None:
    """Go to Start Frame (Home)."""
    ctx.set_frame(0)


def go_end(ctx: ActionContext) -> None:
    """Go to End Frame (End)."""
    ctx.set_frame(ctx.project.n_frames - 1)


def step(ctx: ActionContext, delta: int) -> None:
    """Next / Prev Frame (arrows; auto-repeat while held acts like play)."""
    ctx.set_frame(ctx.project.current_frame + int(delta))


def step_key(ctx: ActionContext, delta: int) -> None:
    """Next / Prev Key Frame of the selected points (wrapping), else one frame."""
    p = ctx.project
    cols = p.selected_columns()
    keys = (np.flatnonzero(p.points.keyframe[:, cols, :].any(axis=(1, 2))) if len(cols)
            else np.zeros(0, np.intp))
    if len(keys) == 0:
        step(ctx, delta)
        return
    f = p.current_frame
    later, earlier = keys[keys > f], keys[keys < f]
    if delta > 0:
        ctx.set_frame(int(later[0]) if len(later) else int(keys[0]))
    else:
        ctx.set_frame(int(earlier[-1]) if len(earlier) else int(keys[-1]))


def toggle_play(ctx: ActionContext, on: bool) -> None:
    """Play / Stop (Space): plays the view range at the take's frame rate (from the
    playback proxies when there are some), dropping frames that cannot be decoded in
    time and saying so in the status bar."""
    ctx.playback.toggle(on)


def build_proxies(ctx: ActionContext) -> None:
    """View > Build Playback Proxies: write the missing proxies in the background."""
    if not ctx.frames.has_images or not hasattr(ctx.frames, "attach_proxies"):
        ctx.status("Build Playback Proxies: the take has no camera videos")
    elif not ctx.proxies.start(ctx.frames):
        ctx.status("Build Playback Proxies: every camera has its proxy")


def toggle_lock(ctx: ActionContext, on: bool) -> None:
    """Lock To Point: the 3D view follows the selection."""
    ctx.view.lock_to_point = on
    ctx.view.notify_options()


def set_active_range(ctx: ActionContext, a: int, b: int) -> None:
    """Ctrl+drag on the timebar, continuity chart or graph: set the active range."""
    ctx.act("Active range", ctx.session.set_active_range, a, b)


def select_point(ctx: ActionContext) -> None:
    """Select Point (Ctrl+P): by id."""
    p = ctx.project
    if p.n_points == 0:
        return
    pid = ctx.dialogs.get_int("Select Point", "Point id:", int(p.points.ids[0]),
                              int(p.points.ids.min()), int(p.points.ids.max()))
    if pid is None:
        return
    if pid not in set(p.points.ids.tolist()):
        ctx.report_error("Select Point", f"Select Point: there is no point {pid}", show=False)
        return
    p.set_selection(points=[pid])


def select_fewest_gaps(ctx: ActionContext) -> None:
    """Select Point With Fewest Gaps (Ctrl+A) within the active range."""
    p = ctx.project
    col = queries.point_with_fewest_gaps(p, frames=p.active_range) if p.n_points else None
    if col is None:
        ctx.status("No point has a gap", 4000)
        log.info("Select Point With Fewest Gaps: no point has a gap")
        return
    p.set_selection(points=[int(p.points.ids[col])])
    log.info("Selected %s (fewest gaps)", p.point_label(col))


def go_next_gap(ctx: ActionContext) -> None:
    """Go To Next Gap of Selected Point: the frame before the gap (wrapping)."""
    p = ctx.project
    cols = p.selected_columns()
    if len(cols) != 1:
        ctx.report_error("Go To Next Gap", "Go To Next Gap: select one point", show=False)
        return
    gap = queries.next_gap(p, int(cols[0]), p.current_frame)
    if gap is None:
        gs = queries.gaps(p, int(cols[0]))
        if len(gs) == 0:
            ctx.status("The selected point has no gap", 4000)
            return
        gap = (int(gs[0, 0]), int(gs[0, 1]))
    ctx.set_frame(max(gap[0] - 1, 0))

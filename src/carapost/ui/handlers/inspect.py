"""View menu inspection tools: Get Point Information, Distance Between Two Points."""

from __future__ import annotations

import logging
import math

from carapost.model import queries
from carapost.ui.context import ActionContext

log = logging.getLogger("carapost.ui")


def point_information(ctx: ActionContext) -> str:
    """Get Point Information of the one selected point at the current frame (dialog + log)."""
    p = ctx.project
    cols = p.selected_columns()
    if len(cols) != 1:
        ctx.report_error("Get Point Information", "Get Point Information: select one point",
                         show=False)
        return ""
    text = queries.point_information(p, int(cols[0]), p.current_frame).text()
    log.info("Point information:\n%s", text)
    ctx.dialogs.info("Get Point Information", text)
    return text


def distance_two_points(ctx: ActionContext) -> float | None:
    """Distance Between Two Points, written to the log."""
    p = ctx.project
    cols = p.selected_columns()
    if len(cols) != 2:
        ctx.report_error("Distance Between Two Points", "Distance Between Two Points: "
                         "select exactly two points", show=False)
        return None
    a, b = int(cols[0]), int(cols[1])
    d = queries.distance_between(p, a, b, p.current_frame)
    if math.isnan(d):
        log.warning("Distance Between Two Points: a point has no 3D position at frame %d",
                    p.current_frame)
        return None
    log.info("Distance between %s and %s: %.2f mm", p.point_label(a), p.point_label(b), d)
    return d

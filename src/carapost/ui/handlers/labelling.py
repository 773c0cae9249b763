"""Process > Label From Template: choose a labelled take, label this one on the worker."""

from __future__ import annotations

from carapost.ui.context import ActionContext
from carapost.ui.handlers import process as process_menu
from carapost.ui.handlers.file import CARA_FILTER

TITLE = "Label From Template"


def label_from_template(ctx: ActionContext) -> bool:
    """Ask for a labelled ``.cara`` take of the same marker set and label this take's
    unlabelled face points from it (one History entry; the Log lists what was left
    unassigned)."""
    path = ctx.dialogs.open_file(f"{TITLE}: choose a labelled take (a ROM or another take)",
                                 CARA_FILTER)
    if not path:
        return False
    return process_menu.run(ctx, "label_from_template", TITLE, template=path)

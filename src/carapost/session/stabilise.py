"""Stabilize Data, Align Data, Toggle Show Stabilized and Remove Stabilization of a
`carapost.Session`.

Stabilisation follows the processing recipe (``prepare_stabilize`` / ``stabilize``), so
the window computes it on its worker with progress and Cancel; Align Data and Remove
Stabilization are edit commands. Each is one History entry; raw positions are never
changed. Toggle Show Stabilized is a display setting, not a History entry.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Sequence
from typing import Any

from carapost.commands.recipe import ApplyResult, Job
from carapost.commands.stabilise import AlignData, RemoveStabilization, prepare_stabilize
from carapost.commands.stack import Command, CommandStack
from carapost.model.project import Project

log = logging.getLogger("carapost.session")

__all__ = ["StabiliseActions"]


class StabiliseActions:
    """Stabilisation actions of a `carapost.Session` (mixed into it)."""

    project: Project
    stack: CommandStack

    # it uses the Session's push and ProcessActions' run

    def prepare_stabilize(self, mode: str = "manual", points: Iterable[int] | None = None,
                          base_frame: int | None = None) -> Job:
        """Step 1 of Stabilize Data (see `stabilize`): validate and snapshot."""
        return prepare_stabilize(self.project, mode, points, base_frame)

    def stabilize(self, mode: str = "manual", points: Iterable[int] | None = None,
                  base_frame: int | None = None, *, progress: Any = None
                  ) -> ApplyResult | None:
        """Process > Stabilize Data [Manual] / [Assisted] / [Automatic] over the active
        range.

        Parameters
        ----------
        mode : {"manual", "assisted", "auto"}
            "manual": each frame is mapped by the rigid transform that takes ``points``
            onto their base-frame positions. "assisted": starts from ``points``, adds
            stable points itself and minimises the weighted stabilisation error
            (Stabilization Parameters). "auto": no selection; chooses the base frame
            and the stable set.
        points : iterable of int, optional
            Point ids (default: the selection); at least 3, gap-free over the active
            range (manual, assisted).
        base_frame : int, optional
            Default: the current frame (manual, assisted).
        progress : callable, optional
            ``progress(iteration, max_iterations) -> bool``; False stops the assisted
            optimisation (the last iterate is kept, marked cancelled).

        Returns
        -------
        ApplyResult
            ``.message`` holds the errors (also logged); ``.result.stabilization`` the
            transforms.

        Raises
        ------
        CommandError
            Fewer than 3 points, a point with a gap (named, with its frames), ...
        """
        return self.run(self.prepare_stabilize(mode, points, base_frame),  # type: ignore[attr-defined]
                        progress)

    def align(self, points: Sequence[int] | None = None, axes: str = "xy",
              frame: int | None = None) -> Command:
        """Process > Align Data: the three points (ids; default the selection) define
        the coordinate frame: origin at the first, the first axis of ``axes`` (x)
        towards the second, the third in the plane of both axes (x-y) on the positive
        side of the second. Applied after the stabilisation; re-applied when the take
        is stabilised again."""
        return self.push(AlignData(  # type: ignore[attr-defined]
            self.project, points, axes, frame))

    def remove_stabilization(self) -> Command:
        """Remove Stabilization (and the alignment): the views and exports show raw data
        again. Undo brings them back."""
        return self.push(RemoveStabilization(self.project))  # type: ignore[attr-defined]

    def show_stabilized(self, on: bool | None = None) -> bool:
        """View > Toggle Show Stabilized: the views show stabilised (and aligned)
        positions when on. ``on=None`` toggles. A display setting: no History entry.
        Returns the new state."""
        p = self.project
        new = (not p.show_stabilized) if on is None else bool(on)
        if new != p.show_stabilized:
            p.show_stabilized = new
            p.events.emit("stabilization")
        return new

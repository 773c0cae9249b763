"""The Target Tracker actions of a `carapost.Session` (Edit menu and Tracker pane).

::

    s.add_target_track(camera=0, frame=120, xy=(512.3, 301.8))   # a new point, keyed
    s.edit_target_track(point, camera=1, frame=120, xy=(498.0, 310.2))
    s.target_track(+1)                   # Track forward to end (one History entry)
    s.target_track(-1, single_frame=True)
    s.add_keyframe()                     # the selected points, current frame
    s.gaps_to_keys(point)
    s.clear_tracked_points(point)

A tracking run follows the processing recipe: ``s.prepare_target_track(direction)``
snapshots on the calling thread, ``job.compute(progress)`` tracks anywhere (the window:
its worker, where Pause is the progress callback returning False), ``s.apply(result)``
pushes one History entry keeping what was tracked.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable
from typing import Any

from carapost.commands.recipe import ApplyResult, Job
from carapost.commands.stack import Command, CommandError
from carapost.session.process import ImageFn, ProgressFn

__all__ = ["TargetActions"]

log = logging.getLogger("carapost.commands")


class TargetActions:
    """Target Tracker methods mixed into `carapost.Session`."""

    def _point_ids(self, point: int | Iterable[int] | None) -> list[int] | None:
        if point is None:
            return None
        if isinstance(point, Iterable):
            return [int(p) for p in point]
        return [int(point)]

    def add_target_track(self, camera: int, frame: int | None, xy: Any) -> Command:
        """Edit > Add Target Track (Shift+A), then a click at ``xy`` (raw px) in camera
        ``camera``: a new point with a target-track keyframe there (it is selected)."""
        from carapost.commands.target_track import AddTargetTrack

        f = self.project.current_frame if frame is None else frame
        return self.push(AddTargetTrack(self.project, camera, f, xy))

    def edit_target_track(self, point: int | None, camera: int, frame: int | None,
                          xy: Any) -> Command:
        """Edit > Edit Target Track (Shift+E), then a click: the point's keyframe in
        ``camera`` at ``xy`` (replacing a connected detection); 3D re-solved."""
        from carapost.commands.target_track import EditTargetTrack

        if point is None:
            sel = sorted(self.project.selection.points)
            if len(sel) != 1:
                raise CommandError("Edit Target Track: select one point")
            point = sel[0]
        f = self.project.current_frame if frame is None else frame
        return self.push(EditTargetTrack(self.project, point, camera, f, xy))

    def add_keyframe(self, points: Iterable[int] | None = None,
                     frame: int | None = None) -> Command:
        """Tracker pane > Add Keyframe To Current Frame (default: the selected points)."""
        from carapost.commands.target_track import AddKeyframe

        return self.push(AddKeyframe(self.project, self._point_ids(points), frame))

    def gaps_to_keys(self, point: int | Iterable[int] | None = None) -> Command:
        """Edit > Gaps To Keys: keyframes either side of every gap (default: the
        selected points)."""
        from carapost.commands.target_track import GapsToKeys

        return self.push(GapsToKeys(self.project, self._point_ids(point)))

    def clear_tracked_points(self, point: int | Iterable[int] | None = None) -> Command:
        """Tracker pane > Clear Tracked Points: the target-track 2D data (keyframes
        included) of the point(s) (default: the selected points)."""
        from carapost.commands.target_track import ClearTrackedPoints

        return self.push(ClearTrackedPoints(self.project, self._point_ids(point)))

    def prepare_target_track(self, direction: int | str, single_frame: bool = False,
                             to: int | None = None, *, points: Iterable[int] | None = None,
                             get_image: ImageFn | None = None, **overrides: Any) -> Job:
        """Prepare :meth:`target_track` (snapshot; see the module)."""
        from carapost.commands.target_track import prepare_target_track

        d = {"forward": 1, "forwards": 1, "back": -1, "backward": -1,
             "backwards": -1}.get(direction, direction) if isinstance(direction, str) \
            else direction
        if d not in (1, -1):
            raise CommandError(f"Target Track: direction must be +1/-1 or 'forwards'/"
                               f"'backwards', got {direction!r}")
        images = get_image if get_image is not None else self.image_source("Target Track")
        return prepare_target_track(self.project, images, int(d), single_frame=single_frame,
                                    to=to, points=points, **overrides)

    def target_track(self, direction: int | str, single_frame: bool = False,
                     to: int | None = None, *, points: Iterable[int] | None = None,
                     progress: ProgressFn | None = None,
                     **overrides: Any) -> ApplyResult | None:
        """Tracker pane: Track forward / back to the end (or to ``to``), or one frame.

        Tracks the selected points (or ``points``) from the current frame in every
        camera where they have a 2D position there, with the Target Tracker settings of
        the properties; ``overrides`` set parameter fields for this run
        (``pattern_size=25``). One History entry; ``progress`` returning False pauses
        (what was tracked is kept). None when nothing was tracked (the marker was lost
        on the first frame: the log says where, with its match score).
        """
        job = self.prepare_target_track(direction, single_frame, to, points=points,
                                        **overrides)
        result = job.compute(progress)
        if result.changes_nothing() and not result.cancelled:
            # the marker was lost on the first frame: no History entry that changes nothing
            log.warning("%s; nothing changed", result.message)
            return None
        return self.apply(result)  # type: ignore[attr-defined]

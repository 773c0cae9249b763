"""Per-track Target Tracker sizes as a `carapost.Session` action (the handles' drag).

::

    s.set_target_track_size(point, camera=0, pattern=31)   # the blue box, px
    s.set_target_track_size(point, camera=0, search=121)   # the green cross, px
    s.target_track_size(point, 0)                          # (31, 121)
"""

from __future__ import annotations

from carapost.commands.stack import Command

__all__ = ["TargetSizeActions"]


class TargetSizeActions:
    """The per-track pattern and search sizes, mixed into `carapost.Session`."""

    def set_target_track_size(self, point: int, camera: int, *,
                              pattern: float | None = None,
                              search: float | None = None) -> Command:
        """Dragging a handle of a selected keyframe's pattern box (blue) or search cross
        (green): that point's target track in ``camera`` uses these sizes (px, rounded
        to odd) from the next run on. One History entry."""
        from carapost.commands.target_sizes import SetTargetTrackSize

        return self.push(SetTargetTrackSize(self.project, point, camera, pattern=pattern,
                                            search=search))

    def target_track_size(self, point: int, camera: int) -> tuple[int, int]:
        """(pattern, search) sizes (px) the point's target track in ``camera`` uses."""
        from carapost.commands.target_sizes import track_sizes

        return track_sizes(self.project, point, camera)

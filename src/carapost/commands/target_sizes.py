"""Per-track Target Tracker sizes: the pattern box and search cross of one target track.

The artist drags the white handles of a selected keyframe's blue pattern box or green
search cross; the new size belongs to that point in that camera
(``Project.target_sizes``), is drawn there from then on, is used by the next tracking
run of that track, and is saved in the project file. One History entry per drag.

>>> from carapost.model.project import new_project
>>> p = new_project(10, 2)
>>> cols = p.points.append(1)
>>> pid = int(p.points.ids[0])
>>> track_parameters(p, pid, 1, TargetTrackerParameters()).pattern_size
21
>>> SetTargetTrackSize(p, pid, 1, pattern=31).do(p)
>>> p.target_sizes[(pid, 1)]
(31, 81)
>>> track_parameters(p, pid, 1, TargetTrackerParameters()).pattern_size
31
"""

from __future__ import annotations

from dataclasses import replace

from carapost.algorithms.params import param_info
from carapost.algorithms.target_track import TargetTrackerParameters
from carapost.commands.stack import Command, CommandError, Journal
from carapost.model.project import Project

__all__ = ["SetTargetTrackSize", "track_parameters", "track_sizes"]


def _limits(name: str) -> tuple[int, int]:
    info = param_info(TargetTrackerParameters.__dataclass_fields__[name])
    assert info is not None and info.minimum is not None and info.maximum is not None
    return int(info.minimum), int(info.maximum)


_PATTERN, _SEARCH = _limits("pattern_size"), _limits("search_size")


def track_sizes(project: Project, point: int, camera: int,
                default: TargetTrackerParameters | None = None) -> tuple[int, int]:
    """(pattern, search) sizes (px) of one point's target track in one camera."""
    d = default if default is not None else TargetTrackerParameters()
    return project.target_sizes.get((int(point), int(camera)),
                                    (d.pattern_size, d.search_size))


def track_parameters(project: Project, point: int, camera: int,
                     params: TargetTrackerParameters, *, keep: frozenset[str] = frozenset()
                     ) -> TargetTrackerParameters:
    """``params`` with the track's own pattern and search sizes, if the artist set them.

    ``keep`` names fields the caller set explicitly for this run (a script's
    ``pattern_size=25``): those win over the track's sizes.
    """
    sizes = project.target_sizes.get((int(point), int(camera)))
    if sizes is None:
        return params
    pattern, search = sizes
    changes = {}
    if "pattern_size" not in keep:
        changes["pattern_size"] = int(pattern)
    if "search_size" not in keep:
        changes["search_size"] = int(search)
    if not changes:
        return params
    try:
        return replace(params, **changes)
    except ValueError:
        # an explicit size of the run and the track's other size do not fit together:
        # the run's settings win
        return params


class SetTargetTrackSize(Command):
    """Set the pattern and/or search size of one point's target track in one camera."""

    def __init__(self, project: Project, point: int, camera: int, *,
                 pattern: float | None = None, search: float | None = None) -> None:
        super().__init__(project)
        what = "Target Track Size"
        pid, cam = int(point), int(camera)
        try:
            project.points.index_of([pid])
        except KeyError:
            raise CommandError(f"{what}: there is no point {pid}") from None
        if not 0 <= cam < project.n_cameras:
            raise CommandError(f"{what}: there is no camera {cam}")
        if pattern is None and search is None:
            raise CommandError(f"{what}: give a pattern or a search size")
        old_p, old_s = track_sizes(project, pid, cam)
        # sizes are odd, so the box is centred on the marker's pixel grid the same way
        # whichever way it was dragged
        def odd(v: float) -> int:
            n = int(round(float(v)))
            return n if n % 2 else n + 1

        new_p = old_p if pattern is None else odd(pattern)
        new_s = old_s if search is None else odd(search)
        if pattern is not None and search is None:
            new_s = max(new_s, new_p)          # the box grows the cross with it
        if search is not None and pattern is None:
            new_p = min(new_p, new_s)          # the cross shrinks the box with it
        for name, v, lo, hi in (("pattern box (Pattern Size)", new_p, *_PATTERN),
                                ("search cross (Search Size)", new_s, *_SEARCH)):
            if not lo <= v <= hi:
                raise CommandError(f"{what}: the {name} must be {lo}-{hi} px, got {v} px")
        for c in project.take.cameras[cam:cam + 1]:
            w, h = c.image_size
            if w and h and new_p + 4 > min(w, h):
                raise CommandError(f"{what}: the pattern box ({new_p} px) is larger than "
                                   f"the {w} x {h} image of camera {cam}")
        self.key = (pid, cam)
        self.sizes = (new_p, new_s)
        self.description = (f"Target Track Size [point {pid}, camera {cam}: pattern "
                            f"{new_p} px, search {new_s} px]")

    def apply(self, project: Project, journal: Journal) -> None:
        sizes = dict(project.target_sizes)
        sizes[self.key] = self.sizes
        journal.setattr(project, "target_sizes", sizes, "points")

"""The optional ``target_sizes`` member of a ``.cara`` manifest.

Per-track Target Tracker sizes (``Project.target_sizes``) as a list of
``[point id, camera, pattern px, search px]``; written only when there are some, so a
project without them saves as before, and an older file without the member opens with
the defaults.
"""

from __future__ import annotations

from typing import Any

from carapost.model.project import Project

__all__ = ["read_target_sizes", "target_sizes_manifest"]


def target_sizes_manifest(project: Project) -> list[list[int]]:
    """The per-track Target Tracker sizes of existing points, for the manifest."""
    ids = set(project.points.ids.tolist())
    return [[int(pid), int(cam), int(pat), int(sea)]
            for (pid, cam), (pat, sea) in sorted(project.target_sizes.items()) if pid in ids]


def read_target_sizes(project: Project, raw: Any) -> None:
    """Per-track sizes from the manifest; entries that do not fit the project (or are
    not four integers) are left out: they only change the default of a later run."""
    if not isinstance(raw, list):
        return
    ids = set(project.points.ids.tolist())
    for row in raw:
        if (isinstance(row, list) and len(row) == 4
                and all(isinstance(v, int) and not isinstance(v, bool) for v in row)):
            pid, cam, pat, sea = row
            if pid in ids and 0 <= cam < project.n_cameras and 0 < pat <= sea:
                project.target_sizes[(pid, cam)] = (pat, sea)

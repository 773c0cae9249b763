"""The head rig's layout: which cameras share a caddy.

A head-mounted rig carries its cameras on caddies (usually one each side of the face).
Initialize 3D pairs the cameras of one caddy (they see the same markers from close
viewpoints); Get Point Information reports the distance to each caddy's centroid. Both
ask this module, so they agree for every rig size.

The grouping comes from the take's metadata when it says so (``<take>.json``:
``"rig": {"caddies": [[0, 1, 2], [3, 4, 5]]}`` or a top-level ``"caddies"``; the
synthetic takes write it), else cameras are paired in channel order: (0, 1), (2, 3), ...,
the order in which the rig's channels are wired. The XCP format has no caddy field.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import Any

log = logging.getLogger("carapost.model")

__all__ = ["caddies", "caddy_groups"]


def _groups_from_metadata(metadata: Mapping[str, Any] | None,
                          n_cameras: int) -> tuple[tuple[int, ...], ...] | None:
    if not metadata:
        return None
    rig = metadata.get("rig")
    given = rig.get("caddies") if isinstance(rig, Mapping) else None
    if given is None:
        given = metadata.get("caddies")
    if given is None:
        return None
    try:
        if isinstance(given, str) or any(isinstance(g, str) for g in given):
            raise TypeError("a string is not a list of camera indices")
        groups = tuple(tuple(int(c) for c in g) for g in given)
    except (TypeError, ValueError):
        log.warning("Ignoring the take's caddies %r: not lists of camera indices", given)
        return None
    flat = [c for g in groups for c in g]
    if (not groups or any(len(g) == 0 for g in groups) or len(set(flat)) != len(flat)
            or any(not 0 <= c < n_cameras for c in flat)):
        log.warning("Ignoring the take's caddies %r: not disjoint groups of cameras 0-%d",
                    given, n_cameras - 1)
        return None
    return groups


def caddy_groups(n_cameras: int, metadata: Mapping[str, Any] | None = None,
                 ) -> tuple[tuple[int, ...], ...]:
    """The cameras of each caddy.

    Parameters
    ----------
    n_cameras : int
        Cameras of the take.
    metadata : mapping, optional
        ``take.metadata`` (the take's JSON); its ``rig.caddies`` (or ``caddies``) wins
        when it is a valid set of disjoint camera groups.

    Returns
    -------
    tuple of tuple of int
        One tuple of camera indices per caddy. Without metadata: (0, 1), (2, 3), ...;
        an odd last camera is a caddy of its own.

    Examples
    --------
    >>> caddy_groups(6)
    ((0, 1), (2, 3), (4, 5))
    >>> caddy_groups(6, {"rig": {"caddies": [[0, 1, 2], [3, 4, 5]]}})
    ((0, 1, 2), (3, 4, 5))
    """
    n = int(n_cameras)
    groups = _groups_from_metadata(metadata, n)
    if groups is not None:
        return groups
    return tuple(tuple(range(i, min(i + 2, n))) for i in range(0, n, 2))


def caddies(n_cameras: int, metadata: Mapping[str, Any] | None = None,
            ) -> tuple[tuple[int, int], ...]:
    """Camera pairs that share a caddy (what `initialize_3d` calls ``caddies``).

    Neighbouring cameras of each caddy group (`caddy_groups`) are paired: a two-camera
    caddy gives one pair, a three-camera caddy (0, 1, 2) gives (0, 1) and (1, 2). A
    caddy of one camera gives none.

    Examples
    --------
    >>> caddies(4)
    ((0, 1), (2, 3))
    >>> caddies(5)
    ((0, 1), (2, 3))
    """
    pairs: list[tuple[int, int]] = []
    for group in caddy_groups(n_cameras, metadata):
        pairs.extend((a, b) for a, b in zip(group[:-1], group[1:], strict=True))
    return tuple(pairs)


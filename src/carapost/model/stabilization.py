"""Stabilisation and alignment of a project: non-destructive transforms over raw points.

Raw positions (``project.points.positions``) are never changed by Stabilize Data or
Align Data. A project holds at most one :class:`Stabilization` (a rigid transform per
frame, raw -> stabilised, with its base frame, point set and errors) and one
:class:`Alignment` (one rigid transform applied after the stabilisation). The
*processed* position of a sample is ``A @ T_f @ x`` (the identity stands in for a
missing part); frames outside the stabilised range have no processed position (NaN).

Toggle Show Stabilized (``project.show_stabilized``) makes the views show processed
positions (:func:`display_positions`); the exports write them when asked
(Export Stabilized Coordinates, ``--stabilized``).

Examples
--------
>>> from carapost.model.project import new_project
>>> p = new_project(3, 1)
>>> has_processing(p)
False
>>> T = np.broadcast_to(np.eye(4), (3, 4, 4)).copy(); T[:, 0, 3] = 5.0
>>> p.stabilization = Stabilization(T, 0, np.array([1, 2, 3]), "manual")
>>> processed_transforms(p, 0, 2)[:, 0, 3].tolist()
[5.0, 5.0, 5.0]
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    from carapost.model.project import Project

__all__ = [
    "Alignment",
    "Stabilization",
    "display_positions",
    "has_processing",
    "processed_positions",
    "processed_transforms",
]


@dataclass
class Stabilization:
    """The stabilisation of a take.

    Attributes
    ----------
    transforms : ndarray, shape (F, 4, 4), float64
        Raw -> stabilised per frame (row-vector use: ``x @ T[:3, :3].T + T[:3, 3]``);
        all-NaN for frames not stabilised (outside the range, or too few points).
    base_frame : int
        The frame mapped onto itself.
    point_ids : ndarray of int64
        The selected (manual, assisted) or chosen (automatic) stable points.
    mode : str
        "manual", "assisted" or "auto".
    first, last : int
        The frames stabilised (the active range when it ran), inclusive.
    base_frame_error, inter_frame_error, error : float
        The stabilisation errors (mm; ``error`` is the weighted sum).
    parameters : dict
        The Stabilization Parameters used (assisted, automatic).
    """

    transforms: NDArray[np.float64]
    base_frame: int
    point_ids: NDArray[np.int64]
    mode: str
    first: int = 0
    last: int = -1
    base_frame_error: float = float("nan")
    inter_frame_error: float = float("nan")
    error: float = float("nan")
    parameters: dict[str, Any] = field(default_factory=dict)

    def to_manifest(self) -> dict[str, Any]:
        """JSON-ready fields (the transforms are stored as an array member)."""
        return {"base_frame": int(self.base_frame),
                "point_ids": [int(i) for i in self.point_ids], "mode": self.mode,
                "first": int(self.first), "last": int(self.last),
                "base_frame_error": _num(self.base_frame_error),
                "inter_frame_error": _num(self.inter_frame_error),
                "error": _num(self.error), "parameters": dict(self.parameters)}

    @classmethod
    def from_manifest(cls, m: dict[str, Any], transforms: NDArray) -> Stabilization:
        """The inverse of :meth:`to_manifest`."""
        def f(v: Any) -> float:
            return float("nan") if v is None else float(v)
        return cls(np.asarray(transforms, np.float64), int(m["base_frame"]),
                   np.asarray(m.get("point_ids", []), np.int64), str(m.get("mode", "manual")),
                   int(m.get("first", 0)), int(m.get("last", len(transforms) - 1)),
                   f(m.get("base_frame_error")), f(m.get("inter_frame_error")),
                   f(m.get("error")), dict(m.get("parameters", {})))


@dataclass
class Alignment:
    """Align Data: one rigid transform applied after the stabilisation.

    Attributes
    ----------
    matrix : ndarray, shape (4, 4), float64
        Stabilised (or raw, without a stabilisation) -> aligned.
    point_ids : tuple of 3 int
        The points that define the frame (origin, x direction, x-y plane by default).
    frame : int
        The frame whose positions defined it.
    axes : str
        The axes convention (see `carapost.algorithms.stabilise.parse_axes`).
    """

    matrix: NDArray[np.float64]
    point_ids: tuple[int, int, int]
    frame: int
    axes: str = "xy"

    def to_manifest(self) -> dict[str, Any]:
        """JSON-ready fields (the 4 x 4 matrix as nested lists, exact in JSON)."""
        return {"matrix": np.asarray(self.matrix, np.float64).tolist(),
                "point_ids": [int(i) for i in self.point_ids], "frame": int(self.frame),
                "axes": self.axes}

    @classmethod
    def from_manifest(cls, m: dict[str, Any]) -> Alignment:
        """The inverse of :meth:`to_manifest`."""
        M = np.asarray(m["matrix"], np.float64).reshape(4, 4)
        ids = tuple(int(i) for i in m["point_ids"])
        return cls(M, (ids[0], ids[1], ids[2]), int(m["frame"]), str(m.get("axes", "xy")))


def _num(v: float) -> float | None:
    return None if not np.isfinite(v) else float(v)


def has_processing(project: Project) -> bool:
    """Whether the project has a stabilisation or an alignment."""
    return (getattr(project, "stabilization", None) is not None
            or getattr(project, "alignment", None) is not None)


def processed_transforms(project: Project, first: int, last: int, *,
                         align: bool = True) -> NDArray[np.float64]:
    """Raw -> processed transforms of frames ``first..last`` (inclusive): (n, 4, 4).

    The stabilisation (NaN where a frame is not stabilised), then the alignment
    (``align``); the identity where the project has neither.
    """
    n = last - first + 1
    st = getattr(project, "stabilization", None)
    if st is not None:
        T = np.array(st.transforms[first:last + 1], dtype=np.float64)
    else:
        T = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
    al = getattr(project, "alignment", None)
    if align and al is not None:
        T = np.asarray(al.matrix, np.float64) @ T
    return T


def processed_positions(project: Project, first: int = 0, last: int | None = None,
                        columns: Any = None, *, align: bool = True) -> NDArray[np.float64]:
    """Stabilised (and aligned) positions of frames ``first..last``: (n, P', 3) mm.

    Parameters
    ----------
    project : Project
    first, last : int
        Inclusive frames (``last`` default: the last frame).
    columns : index, optional
        Point columns (default all).
    align : bool
        Apply the alignment after the stabilisation.
    """
    last = project.n_frames - 1 if last is None else int(last)
    X = project.points.positions[first:last + 1]
    if columns is not None:
        X = X[:, columns]
    T = processed_transforms(project, first, last, align=align)
    return np.einsum("fij,fpj->fpi", T[:, :3, :3], X.astype(np.float64)) \
        + T[:, None, :3, 3]


def display_positions(project: Project, frames: slice | int, columns: Any = None
                      ) -> NDArray:
    """What the views show: raw positions, or processed ones when Show Stabilized is
    on and the project has a stabilisation or alignment.

    ``frames`` is a frame index (result (P', 3)) or a slice with step 1 (result
    (n, P', 3)).
    """
    pos = project.points.positions
    single = isinstance(frames, int | np.integer)
    if not (getattr(project, "show_stabilized", False) and has_processing(project)):
        out = pos[frames]
        return out if columns is None else out[..., columns, :]
    if single:
        f = int(frames)
        return processed_positions(project, f, f, columns)[0].astype(pos.dtype)
    a, b, _ = frames.indices(project.n_frames)
    if b <= a:
        shape = (0, pos.shape[1] if columns is None else len(np.atleast_1d(
            np.arange(pos.shape[1])[columns])), 3)
        return np.zeros(shape, pos.dtype)
    return processed_positions(project, a, b - 1, columns).astype(pos.dtype)

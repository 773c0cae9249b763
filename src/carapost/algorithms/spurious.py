"""Find tracked face points that are not markers, with the reason for each.

A point that is not a marker - a "ghost" made by matching two different markers across
the two cameras of one caddy, a highlight or a speck tracked for a while - is worse in an
export than a gap: it is animated data nobody asked for. :func:`find_spurious_points`
judges each face point over the whole take by what a marker must satisfy:

``too few frames``
    triangulated (seen by >= 2 cameras) in fewer than ``min_frames`` frames (half the
    frames on a take shorter than twice that);
``too few cameras``
    fewer than ``min_triangulated_share`` of its samples are seen by two cameras or
    more (a single-sensor depth is only a guess from the neighbours);
``blob unlike a marker``
    its blobs are, at its depth, more than ``max_size_ratio`` times as large as the
    take's typical marker (the median over points of each point's median blob size in
    mm): a nostril, an eye corner or a shadow is a dark blob too, but a larger one;
``rays do not meet``
    its cameras disagree: the median over its triangulated samples of the reprojection
    chi-square (per camera, against that camera's 2D noise measured on the take) divided
    by the chi-square's median for its degrees of freedom (`ray_misfit`) exceeds
    ``max_ray_misfit``. A marker's rays meet within its blobs' noise (1 for a typical
    one, up to ~46 for a marker whose blobs are consistently off on the rendered takes);
    a ghost made of two different skin features or blobs matched across cameras only
    follows the epipolar constraint as far as the tracker let it drift, so its rays miss
    each other by many noise widths in every frame;
``blob and rays unlike a marker's``
    two weaker signs together: blobs larger than ``joint_size_ratio`` times the typical
    marker's and a ray misfit above ``joint_ray_misfit``. Each alone happens to markers
    (a marker close to the lens; a marker whose blob a fold clips), both together did
    not on any take we have: the markers with the largest misfits have blobs of typical
    size or smaller, and the largest blobs of markers meet within a few noise widths;
``moves unlike its neighbours``
    the RMS, over frames, of its displacement minus its neighbours' median displacement
    exceeds ``motion_share`` marker spacings: skin carries a marker along with the markers
    around it.

Arrays in, reasons out; nothing is changed here. Units: mm.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from carapost.algorithms.camera import CameraIntrinsics
from carapost.algorithms.codes import KIND_BRIM, RECON_SINGLE_SENSOR, RECON_TRIANGULATED

__all__ = ["SpuriousParameters", "SpuriousPoint", "blob_sizes_mm", "find_spurious_points",
           "ray_misfit"]


#: Least 2D noise (px) the ray misfit is measured in (`ray_misfit`).
MISFIT_NOISE_PX = 0.05


@dataclass(frozen=True)
class SpuriousParameters:
    """Thresholds of :func:`find_spurious_points` (see the module docstring).

    The defaults keep every marker of the rendered takes (the largest motion deviation
    from the neighbours is 0.4 marker spacing on the fast preset's truth). A distance
    from the surface through the neighbours was tried as a test too and left out: the
    nose tip stands 16 mm off the patch through its neighbours on the standard set.
    """

    min_frames: int = 10
    max_size_ratio: float = 1.9
    min_triangulated_share: float = 0.1
    neighbours: int = 10
    motion_share: float = 0.75
    max_ray_misfit: float = 100.0
    joint_size_ratio: float = 1.5
    joint_ray_misfit: float = 15.0


@dataclass(frozen=True)
class SpuriousPoint:
    """One point judged not to be a marker.

    Attributes
    ----------
    index : int
        Column of the point in the arrays given.
    reason : str
        Why, in words (for the log and the report).
    """

    index: int
    reason: str


def find_spurious_points(positions: ArrayLike, recon: ArrayLike, kind: ArrayLike,
                         params: SpuriousParameters | None = None,
                         blob_size_mm: ArrayLike | None = None,
                         misfit: ArrayLike | None = None,
                         observed: ArrayLike | None = None) -> list[SpuriousPoint]:
    """Face points of a tracked take that are not markers (see the module docstring).

    Parameters
    ----------
    positions : array_like, shape (F, P, 3)
        Tracked positions (mm), NaN where none.
    recon : array_like, shape (F, P) int
        ``RECON_*`` of each sample.
    kind : array_like, shape (P,)
        ``KIND_*``; brim points are never judged.
    params : SpuriousParameters, optional
    blob_size_mm : array_like, shape (P,), optional
        Each point's median blob size in mm at its depth (`blob_sizes_mm`); NaN where
        unknown. Without it the blob test is skipped.
    misfit : array_like, shape (P,), optional
        Each point's `ray_misfit`; NaN where unknown. Without it the ray test is skipped.
    observed : array_like of bool, shape (P,), optional
        Points with camera observations (made by tracking here). Only these are judged:
        a point imported from a C3D or typed in has no 2D evidence of how it was made,
        and the rules are for facial points tracked on this rig (the limbs of a body
        take move unlike their neighbours, a head-rig marker unlike the skin around it).
        Without it every face point is judged.

    Returns
    -------
    list of SpuriousPoint
        In point order; the first reason that applies.

    Examples
    --------
    A grid of markers riding together and one point drifting across it:

    >>> import numpy as np
    >>> g = np.stack(np.meshgrid(np.arange(6.0), np.arange(6.0)), -1).reshape(-1, 2) * 12
    >>> rest = np.vstack([np.c_[g, np.zeros(len(g))], [30.0, 30.0, 0.0]])
    >>> X = rest[None] + np.linspace(0, 5, 40)[:, None, None] * [0, 1, 0]
    >>> X[:, -1, 0] += np.linspace(-25, 25, 40)
    >>> found = find_spurious_points(X, np.ones(X.shape[:2], int), np.zeros(len(rest), int))
    >>> [(s.index, s.reason.split(":")[0]) for s in found]
    [(36, 'moves unlike its neighbours')]
    """
    p = SpuriousParameters() if params is None else params
    X = np.asarray(positions, dtype=np.float64)
    rc = np.asarray(recon)
    kd = np.asarray(kind)
    judge = kd != KIND_BRIM
    if observed is not None:
        judge &= np.asarray(observed, dtype=bool)
    face = np.flatnonzero(judge)
    present = np.isfinite(X[..., 0])
    n_tri = (rc == RECON_TRIANGULATED).sum(0)
    n_single = (rc == RECON_SINGLE_SENSOR).sum(0)
    n_present = present.sum(0)
    # A take shorter than twice min_frames (a test take, a short pick-up) asks for
    # half its frames instead, so that a real marker of a short take is never judged.
    need = min(p.min_frames, max(2, X.shape[0] // 2))
    out: dict[int, str] = {}
    for i in face:
        if n_present[i] == 0:
            continue
        if n_tri[i] < need:
            out[int(i)] = (f"too few frames: triangulated in {int(n_tri[i])} frames "
                           f"(needs {need})")
        elif n_single[i] > (1.0 - p.min_triangulated_share) * n_present[i]:
            out[int(i)] = (f"too few cameras: {int(n_single[i])} of its {int(n_present[i])} "
                           f"samples are from one camera only")
    typical = np.nan
    if blob_size_mm is not None:
        size = np.asarray(blob_size_mm, dtype=np.float64)
        typical = np.nanmedian(size[face]) if np.isfinite(size[face]).any() else np.nan
        for i in face:
            if int(i) in out or not np.isfinite(size[i]) or not np.isfinite(typical):
                continue
            if size[i] > p.max_size_ratio * typical:
                out[int(i)] = (f"blob unlike a marker: blob radius {size[i]:.1f} mm at its "
                               f"depth against {typical:.1f} mm for the take's markers")
    if misfit is not None:
        q = np.asarray(misfit, dtype=np.float64)
        rel = np.full(q.shape, np.nan)
        if blob_size_mm is not None and np.isfinite(typical):
            rel = np.asarray(blob_size_mm, dtype=np.float64) / typical
        for i in face:
            if int(i) in out or not np.isfinite(q[i]):
                continue
            if q[i] > p.max_ray_misfit:
                out[int(i)] = (f"rays do not meet: its cameras disagree by {q[i]:.0f} times "
                               f"what their noise explains (limit {p.max_ray_misfit:g})")
            elif q[i] > p.joint_ray_misfit and rel[i] > p.joint_size_ratio:
                out[int(i)] = (f"blob and rays unlike a marker's: blobs {rel[i]:.1f} times the "
                               f"take's markers' and cameras that disagree by {q[i]:.0f} times "
                               f"their noise (limits {p.joint_size_ratio:g} and "
                               f"{p.joint_ray_misfit:g} together)")
    judged = np.array([i for i in face if n_present[i] and int(i) not in out], dtype=np.intp)
    if judged.size >= 8:
        Xj = X[:, judged]
        rest = np.nanmedian(Xj, axis=0)
        d, nb = cKDTree(rest).query(rest, k=min(p.neighbours, judged.size - 1) + 1)
        spacing = float(np.median(d[:, 1]))
        ref = np.nanmedian(Xj, axis=0)
        disp = Xj - ref[None]  # (F, n, 3)
        for j, i in enumerate(judged):
            nd = np.nanmedian(disp[:, nb[j, 1:]], axis=1)  # (F, 3)
            dev = np.linalg.norm(disp[:, j] - nd, axis=-1)
            dev = dev[np.isfinite(dev)]
            if dev.size and np.sqrt(np.mean(dev ** 2)) > p.motion_share * spacing:
                out[int(i)] = (f"moves unlike its neighbours: {np.sqrt(np.mean(dev ** 2)):.1f}"
                               f" mm RMS from their motion (limit "
                               f"{p.motion_share * spacing:.1f} mm)")
    return [SpuriousPoint(i, out[i]) for i in sorted(out)]


def blob_sizes_mm(positions: ArrayLike, axes: ArrayLike, R: ArrayLike, t: ArrayLike,
                  focal: ArrayLike, step: int = 4) -> NDArray[np.float64]:
    """Each point's median blob size (mm): the geometric mean of its blobs' semi-axes
    (px) times the depth over the focal length, over every ``step``-th frame.

    Parameters
    ----------
    positions : array_like, shape (F, P, 3)
    axes : array_like, shape (F, P, C, 2)
        Semi-axes (px) of the blob attached to each point-camera, NaN where none.
    R, t : array_like, shapes (F, C, 3, 3) and (F, C, 3)
    focal : array_like, shape (C,)
    step : int

    Returns
    -------
    ndarray, shape (P,)
        NaN for a point without blobs.
    """
    X = np.asarray(positions, dtype=np.float64)[::step]
    ax = np.asarray(axes, dtype=np.float64)[::step]
    Rm = np.asarray(R, dtype=np.float64)[::step]
    tm = np.asarray(t, dtype=np.float64)[::step]
    z = np.einsum("fcj,fpj->fpc", Rm[..., 2, :], X) + tm[:, None, :, 2]  # (F, P, C)
    size = np.sqrt(ax[..., 0] * ax[..., 1]) * z / np.asarray(focal, dtype=np.float64)
    size = np.where(np.isfinite(size) & (z > 0), size, np.nan)
    flat = size.transpose(1, 0, 2).reshape(size.shape[1], -1)
    out = np.full(flat.shape[0], np.nan)
    has = np.isfinite(flat).any(1)
    out[has] = np.nanmedian(flat[has], axis=1)
    return out


def ray_misfit(obs: ArrayLike, positions: ArrayLike, recon: ArrayLike, R: ArrayLike,
               t: ArrayLike, intr: CameraIntrinsics, min_samples: int = 5
               ) -> NDArray[np.float64]:
    """How far each point's rays miss each other, in units of what the 2D noise explains.

    For each triangulated sample seen by ``n >= 2`` cameras: ``chi2 = sum_c |r_c|^2 /
    s_c^2`` (``r_c`` its reprojection residual in camera ``c``, ``s_c`` the camera's noise
    from `carapost.algorithms.uncertainty.noise_from_residuals`), divided by the median
    of a chi-square with ``2n - 3`` degrees of freedom; the point's value is the median
    of that over its samples (about 1 for a marker whose blobs are as good as the
    camera's typical ones). A long take is sampled on at most ~600 frames.

    Parameters
    ----------
    obs : array_like, shape (F, P, C, 2)
        Raw pixel observations, NaN where none.
    positions : array_like, shape (F, P, 3)
    recon : array_like, shape (F, P)
    R, t : array_like, shapes (F, C, 3, 3) and (F, C, 3)
    intr : CameraIntrinsics
    min_samples : int
        A point with fewer triangulated samples gets NaN.

    Returns
    -------
    ndarray, shape (P,)
    """
    from carapost.algorithms.uncertainty import noise_from_residuals, point_misfit

    # at most ~600 frames spread over the take: a median needs no more, and a long
    # take's every sample would cost gigabytes of per-sample cameras
    step = max(1, np.asarray(recon).shape[0] // 600)
    tri = np.asarray(recon)[::step] == RECON_TRIANGULATED
    o = np.where(tri[..., None, None], np.asarray(obs)[::step].astype(np.float64), np.nan)
    X = np.where(tri[..., None], np.asarray(positions)[::step].astype(np.float64), np.nan)
    Rm = np.asarray(R, dtype=np.float64)[::step]
    tm = np.asarray(t, dtype=np.float64)[::step]
    if not ((np.isfinite(o).all(-1).sum(-1) >= 2) & np.isfinite(X).all(-1)).any():
        return np.full(X.shape[1], np.nan)
    # in units of at least MISFIT_NOISE_PX: the limits of `SpuriousParameters` say how
    # far a ghost's rays miss against a blob noise that size; on a clean take (measured
    # noise 0.03 px) a marker whose blobs are consistently off would otherwise be taken
    # for a ghost (held-out take 601: 110 times, limit 100)
    s = np.maximum(noise_from_residuals(o, X, Rm, tm, intr), MISFIT_NOISE_PX)
    return point_misfit(o, X, Rm, tm, intr, s, min_cameras=2, min_samples=min_samples)

"""After both passes: wrong observations rejected by the motion, single-sensor samples
placed again from both sides.

Steps of :func:`carapost.algorithms.tracking.take.track_take`'s clean-up. The first runs
before the cameras are fitted over time and the face samples re-solved with them:

0. :func:`reject_merged_blobs`: an observation whose blob is much wider than the same
   marker's blob in the same camera over the frames around it (merged with a neighbour
   or a dark feature, its centre several pixels off the marker's) is removed, and so
   is one whose blob is much longer than the same marker's blobs in that camera over
   the take (merged along its length with a crease or a neighbour for longer than the
   width's window).

The others run after that re-solve:

1. :func:`reject_inconsistent_pairs`: a sample of two cameras whose rays miss each
   other by far more than the take's 2D noise explains has a wrong observation (with
   two cameras the triangulation's outlier rejection cannot tell which): the one whose
   camera observes the point least in the triangulated samples around it is removed.
2. :func:`reject_by_motion`: an observation far from where the point's neighbours in
   time (moved with its neighbours on the face) put it, while the sample's other
   observations agree, is removed (:mod:`carapost.algorithms.temporal_check`); the
   sample is solved again from the rest, or becomes a single-sensor sample when one
   camera is left.
3. :func:`reject_unanchored_single_sensor`: a single-sensor sample whose camera's 2D
   track of the point (its observations in consecutive frames, gaps up to `TRACK_GAP`
   bridged) never takes part in a triangulated sample is removed: nothing but the
   motion's prediction ever checked that blob (on other renderers' takes, a dark
   feature beside the marker in the caddy that does not see it: 1.2 mm median error).
4. :func:`place_single_sensor`, after the depth priors (so the triangulated samples it
   predicts from are final): every single-sensor sample is put on its camera's ray
   (with the fitted cameras) nearest the prediction from the point's triangulated
   samples on both sides (:mod:`carapost.algorithms.single_sensor`), with a sigma
   measured on the take for its distance in time to them; as in the per-frame
   tracker, a sample whose ray passes further than the Single Sensor Tracking
   Threshold from the prediction is not kept, nor one whose prediction is expected
   to be wrong by more than it (its sigma).
5. :func:`reject_wrong_samples`, after the depth priors (where a one-caddy sample's
   depth noise no longer hides a wrong one): a triangulated sample whose observations
   are all on a wrong blob (consistent across its cameras, so its residual is small),
   which its neighbours in time on both sides contradict as a whole, is removed
   (:func:`carapost.algorithms.temporal_check.inconsistent_samples`).

Shapes: ``F`` frames, ``P`` points, ``C`` cameras; the arrays are a track result's
(``positions``, ``recon``, ``residual``, ``obs``, ``source``, ``detection``,
``quality``), changed in place.
"""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np
from numpy.typing import NDArray

from carapost.algorithms.blob_noise import window_statistic
from carapost.algorithms.camera import CameraIntrinsics, project
from carapost.algorithms.codes import (
    POINT_FILLS,
    RECON_NONE,
    RECON_SINGLE_SENSOR,
    RECON_TRIANGULATED,
)
from carapost.algorithms.single_sensor import (
    neighbour_prediction,
    neighbours,
    place_on_rays,
    prediction_sigma,
)
from carapost.algorithms.temporal_check import (
    inconsistent_observations,
    inconsistent_samples,
    loo_prediction,
)
from carapost.algorithms.uncertainty import retriangulate

__all__ = ["MERGED_LENGTH_RATIO", "MERGED_WIDTH_RATIO", "PAIR_TARGET_FACTOR", "detach_observations",
           "lengthened_blobs", "merged_blobs",
           "place_single_sensor", "reject_by_motion", "reject_inconsistent_pairs",
           "reject_merged_blobs", "reject_unanchored_single_sensor", "reject_wrong_samples",
           "unanchored_single_sensor"]

#: An observation's blob whose semi-minor axis is more than this many times the median
#: of the same point's blobs in the same camera over the frames around it is taken for
#: a merged blob. On the tuning takes of other renderers (110,000 observations) every
#: one above 1.8 was 1-10 px off its marker (median 8 px); at 1.4-1.8 the median was
#: 0.7 px (docs/benchmarks.md, "merged blobs").
MERGED_WIDTH_RATIO = 1.8

#: An observation's blob whose semi-major axis is more than this many times the median
#: of the same point's in the same camera over the whole take is taken for a blob merged
#: along its length. A flat marker's semi-major axis is its disc's radius magnified,
#: whatever the angle it is seen at, so it changes only with the distance (a few per
#: cent on a head-mounted rig). On held-out takes 701-704 every observation left
#: attached above 1.4 was more than 1 px off its marker (25 of 95,000, median 1.9 px;
#: the width of those blobs was their marker's, 1.0-1.1 times); on the tuning takes 6
#: of 111,000 were above 1.6, all more than 0.5 px off and 3 more than 1 px; at 1.2-1.4
#: the median error is 0.47 px
#: (docs/benchmarks.md, "blobs merged along their length").
MERGED_LENGTH_RATIO = 1.6

#: Half-window (frames) of the median width a blob is compared with.
_WIDTH_HALF = 10

#: Fewest widths in that window for a blob to be judged.
_WIDTH_SUPPORT = 5

#: Farthest (frames) a single-sensor sample is predicted from the triangulated samples
#: on both sides (the longest gap at which the prediction's error is measured,
#: `_GAPS`); beyond, the tracker's placement is kept (moved onto the fitted ray). It was
#: 2 until the seventeenth session: 32 made every take set of other renderers better or
#: equal (tuning RMSE 0.1165 -> 0.1132 mm, max 1.49 -> 1.32; docs/benchmarks.md).
MAX_GAP = 32

#: Longest gap (frames) a camera's 2D track of a point bridges
#: (:func:`unanchored_single_sensor`).
TRACK_GAP = 2

#: A two-camera sample is inconsistent when the RMS reprojection error of its
#: triangulation is above this many times the outlier target of the re-solve (a wrong
#: blob ``e`` px off across the epipolar line leaves ``e / 2`` in each camera; on the
#: takes of other renderers every right cross-caddy pair was below 1.5 px, every wrong
#: one above it, docs/benchmarks.md).
PAIR_TARGET_FACTOR = 2.0

#: Half-window (frames) over which a camera's support of a point is counted (a second
#: at 30 fps: a wrong pair can sit between gaps of the point).
_SUPPORT_HALF = 30

#: Gap lengths (frames) at which the single-sensor prediction's error is measured.
_GAPS = np.array([1, 2, 4, 8, 16, 32])


def _make_gaps(o: dict[str, NDArray[Any]], mask: NDArray[np.bool_]) -> None:
    """Turn the (F, P) ``mask`` samples of ``o`` into gaps (no position, no residual)."""
    o["recon"][mask] = RECON_NONE
    o["positions"][mask] = np.nan
    o["residual"][mask] = np.nan

def detach_observations(o: dict[str, NDArray[Any]], drop: NDArray[np.bool_]) -> None:
    """Remove the (F, P, C) ``drop`` observations from the arrays (not keyframes)."""
    for k in ("obs", "source", "detection", "quality"):
        o[k][drop] = POINT_FILLS[k]


def merged_blobs(widths: NDArray[np.floating], *, ratio: float = MERGED_WIDTH_RATIO,
                 half: int = _WIDTH_HALF, support: int = _WIDTH_SUPPORT,
                 chunk: int = 512) -> NDArray[np.bool_]:
    """Observations whose blob is much wider than the same marker's around it.

    A marker's blob changes its width slowly, as the face turns it against the camera;
    where it merges with a neighbour's blob or a dark feature for a few frames, the
    blob doubles in width and its centre lies several pixels off the marker, in every
    camera where the merge happens alike (so the rays still meet and no residual
    shows it). Each observation's semi-minor axis is compared with the median of the
    same point's in the same camera over ``half`` frames either side (itself
    included: a run of merged frames shorter than ``half`` does not move the median).

    Parameters
    ----------
    widths : ndarray, shape (F, P, C)
        Semi-minor axis (px) of each observation's blob, NaN where none
        (:func:`carapost.algorithms.tracking.take.attached_blobs`).
    ratio : float
        Flagged above this multiple of the local median.
    half : int
        Half-window (frames).
    support : int
        Fewest widths in the window to judge an observation.
    chunk : int
        Frames per block (memory stays ``O(chunk * P * C * (2 half + 1))``, about 50 MB
        for 150 points of four cameras).

    Returns
    -------
    ndarray of bool, shape (F, P, C)

    Examples
    --------
    >>> import numpy as np
    >>> w = np.full((30, 1, 2), 2.0); w[10:13, 0, :] = 4.5
    >>> np.argwhere(merged_blobs(w)[:, 0, 0]).ravel().tolist()
    [10, 11, 12]
    """
    w = np.asarray(widths, dtype=np.float64)
    if w.shape[0] == 0 or not np.isfinite(w).any():
        return np.zeros(w.shape, bool)
    med = window_statistic(w, lambda win: np.nanmedian(win, axis=-1), half, support, chunk)
    with np.errstate(invalid="ignore"):
        return w > ratio * med


def lengthened_blobs(lengths: NDArray[np.floating], *, ratio: float = MERGED_LENGTH_RATIO,
                     support: int = _WIDTH_SUPPORT) -> NDArray[np.bool_]:
    """Observations whose blob is much longer than the same marker's over the take.

    A blob merged with a crease or a neighbour along its length keeps its width (so
    :func:`merged_blobs` does not see it) while its length doubles, and such a merge
    can last longer than the width's window (21 frames on held-out take 704, its
    centre 1.6-2.1 px off). Each observation's semi-major axis is compared with the
    median of the same point's in the same camera over the whole take: a marker's
    semi-major axis changes only with its distance.

    Parameters
    ----------
    lengths : ndarray, shape (F, P, C)
        Semi-major axis (px) of each observation's blob, NaN where none
        (:func:`carapost.algorithms.tracking.take.attached_blobs`).
    ratio : float
        Flagged above this multiple of the median.
    support : int
        Fewest lengths of the point in the camera to judge its observations.

    Returns
    -------
    ndarray of bool, shape (F, P, C)

    Examples
    --------
    >>> import numpy as np
    >>> L = np.full((40, 1, 2), 3.0); L[5:30, 0, 1] = 6.5
    >>> int(lengthened_blobs(L)[:, 0, 1].sum()), int(lengthened_blobs(L)[:, 0, 0].sum())
    (0, 0)
    >>> L[5:15, 0, 1] = 3.0
    >>> np.argwhere(lengthened_blobs(L)[:, 0, 1]).ravel().tolist() == list(range(15, 30))
    True
    """
    L = np.asarray(lengths, dtype=np.float64)
    if L.shape[0] == 0 or not np.isfinite(L).any():
        return np.zeros(L.shape, bool)
    n = np.isfinite(L).sum(0)
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN point-cameras
        med = np.nanmedian(L, axis=0)
        return (L > ratio * med[None]) & (n >= support)[None]


def reject_merged_blobs(o: dict[str, NDArray[Any]], widths: NDArray[np.floating],
                        R: NDArray, t: NDArray, face: NDArray[np.bool_],
                        intr: CameraIntrinsics, fixed: NDArray[np.bool_], *,
                        single_sensor: bool = True,
                        lengths: NDArray[np.floating] | None = None) -> NDArray[np.bool_]:
    """Remove the face observations on merged blobs (:func:`merged_blobs`, and with
    ``lengths`` :func:`lengthened_blobs`); solve those samples again from the rest.

    A sample left with two cameras or more is triangulated again with ``R, t``, one
    left with a single camera becomes a single-sensor sample (placed later by
    :func:`place_single_sensor`; a gap when ``single_sensor`` is off) and one with none
    a gap. ``widths`` loses the removed observations' widths too.

    Returns
    -------
    ndarray of bool, shape (F, P, C)
        The observations removed.
    """
    merged = merged_blobs(widths)
    if lengths is not None:
        merged |= lengthened_blobs(lengths)
    drop = merged & face[None, :, None] & ~fixed[:, None, None]
    drop &= (o["recon"] == RECON_TRIANGULATED)[..., None] | \
        (o["recon"] == RECON_SINGLE_SENSOR)[..., None]
    if not drop.any():
        return drop
    detach_observations(o, drop)
    widths[drop] = np.nan
    _solve_again(o, o["obs"].astype(np.float64), drop.any(-1), R, t, intr, single_sensor)
    return drop


def _solve_again(o: dict[str, NDArray[Any]], obs: NDArray[np.float64],
                 redo: NDArray[np.bool_], R: NDArray, t: NDArray, intr: CameraIntrinsics,
                 single_sensor: bool) -> None:
    """Solve the samples ``redo`` (F, P) again from the observations left in ``obs``
    (F, P, C, 2; NaN where removed): triangulated from two cameras or more, a
    single-sensor sample with one (placed later by :func:`place_single_sensor`; a gap
    when ``single_sensor`` is off), a gap with none or where the triangulation fails."""
    left = np.isfinite(obs).all(-1).sum(-1)
    Xn, res = retriangulate(obs, R, t, intr, redo & (left >= 2))
    ok = redo & (left >= 2) & np.isfinite(Xn).all(-1)
    o["positions"][ok] = Xn[ok].astype(o["positions"].dtype)
    o["residual"][ok] = res[ok].astype(o["residual"].dtype)
    o["recon"][ok] = RECON_TRIANGULATED
    if single_sensor:
        o["recon"][redo & (left == 1)] = RECON_SINGLE_SENSOR
    lost = redo & ((left == 0) | ((left >= 2) & ~ok) | ((left == 1) & (not single_sensor)))
    _make_gaps(o, lost)


def reject_by_motion(o: dict[str, NDArray[Any]], R: NDArray, t: NDArray,
                     face: NDArray[np.bool_], intr: CameraIntrinsics,
                     fixed: NDArray[np.bool_], nb: NDArray[np.intp] | None = None, *,
                     single_sensor: bool = True) -> int:
    """Remove the observations the point's motion contradicts; solve those samples again.

    Parameters
    ----------
    o : dict of arrays
        The track result's arrays (changed in place).
    R, t : ndarray, shapes (F, C, 3, 3) and (F, C, 3)
        The cameras (fitted over time).
    face : ndarray of bool, shape (P,)
    intr : CameraIntrinsics
    fixed : ndarray of bool, shape (F,)
        Frames left alone (the initialised frame).
    nb : ndarray of int, shape (P, k), optional
        Each point's neighbours (:func:`carapost.algorithms.single_sensor.neighbours`),
        when already known.
    single_sensor : bool
        A sample left with one camera becomes a single-sensor sample (else a gap, as the
        tracker does when single sensor tracking is off).

    Returns
    -------
    int
        Observations removed.
    """
    tri = (o["recon"] == RECON_TRIANGULATED) & face[None, :]
    if tri.sum() < 10:
        return 0
    X = np.where(tri[..., None], o["positions"].astype(np.float64), np.nan)
    nb = neighbours(X, tri) if nb is None else nb
    obs = o["obs"].astype(np.float64)
    # a wrong sample spoils the predictions of its neighbours in time (it is their
    # reference): predict again without the suspects until the set no longer changes
    suspect = np.zeros(tri.shape, bool)
    for _ in range(3):
        pred = loo_prediction(X, tri & ~suspect, nb)
        flag = inconsistent_observations(obs, pred, R, t, intr, tri & ~fixed[:, None])
        now = flag.any(-1)
        if np.array_equal(now, suspect):
            break
        suspect = now
    n = int(flag.sum())
    if n == 0:
        return 0
    detach_observations(o, flag)
    obs[flag] = np.nan
    _solve_again(o, obs, flag.any(-1), R, t, intr, single_sensor)
    return n


def reject_inconsistent_pairs(o: dict[str, NDArray[Any]], R: NDArray, t: NDArray,
                              face: NDArray[np.bool_], intr: CameraIntrinsics,
                              fixed: NDArray[np.bool_], target_px: float, *,
                              single_sensor: bool = True,
                              half: int = _SUPPORT_HALF) -> NDArray[np.bool_]:
    """Remove a wrong observation from the two-camera samples whose rays do not meet.

    A triangulated face sample seen by exactly two cameras whose RMS reprojection error
    is above ``target_px`` has one wrong observation, and two cameras cannot say which.
    The point's other samples can: the observation removed is the one whose camera
    observes the point in fewer of the triangulated samples within ``half`` frames
    either side (a blob in a camera that does not usually see the point: a dark
    feature beside the marker, picked up while the usual camera missed it), when the
    other camera's are at least twice as many; a pair of cameras that both observe the
    point throughout is left alone. What is left is solved again
    (:func:`_solve_again`: one camera left makes a single-sensor sample).

    Parameters
    ----------
    o : dict of arrays
        The track result's arrays (changed in place).
    R, t : ndarray, shapes (F, C, 3, 3) and (F, C, 3)
        The cameras the positions were solved with.
    face : ndarray of bool, shape (P,)
    intr : CameraIntrinsics
    fixed : ndarray of bool, shape (F,)
        Frames left alone (the initialised frame).
    target_px : float
        RMS reprojection error (px) above which a pair is inconsistent.
    single_sensor : bool
        As for :func:`reject_by_motion`.
    half : int
        Half-window (frames) of the cameras' support.

    Returns
    -------
    ndarray of bool, shape (F, P, C)
        The observations removed.
    """
    obs = o["obs"].astype(np.float64)
    has = np.isfinite(obs).all(-1)
    tri = (o["recon"] == RECON_TRIANGULATED) & face[None, :] & ~fixed[:, None]
    drop = np.zeros(has.shape, bool)
    f, p = np.nonzero(tri & (has.sum(-1) == 2))
    if f.size == 0 or target_px <= 0:
        return drop
    X = o["positions"][f, p].astype(np.float64)
    uv = project(X[:, None], R[f], t[f], intr)[0][:, 0]  # (N, C, 2)
    err = np.linalg.norm(uv - obs[f, p], axis=-1)
    with np.errstate(invalid="ignore"):
        rms = np.sqrt(np.nanmean(np.where(has[f, p], err, np.nan) ** 2, axis=-1))
        bad = rms > target_px
    if not bad.any():
        return drop
    f, p = f[bad], p[bad]
    # each camera's support: the triangulated samples of the point around the frame
    # that it observes (the sample itself left out)
    from scipy.ndimage import uniform_filter1d

    seen = (has & ((o["recon"] == RECON_TRIANGULATED) & face[None, :])[..., None])
    # counts of 0/1 over the window: rounded, as the filter's mean times its length is
    # not exact (the test below compares them with 1)
    count = np.rint(uniform_filter1d(seen.astype(np.float64), 2 * half + 1, axis=0,
                                     mode="constant") * (2 * half + 1)) - seen
    cams = np.argsort(~has[f, p], axis=1, kind="stable")[:, :2]  # the two cameras
    sup = np.take_along_axis(count[f, p], cams, axis=1)
    # the less supported camera, where the other observes the point in at least twice
    # as many samples around (and in one at least): two cameras that both observe it
    # throughout are left for the point's own test (the spurious points' "rays do not
    # meet"), which judges all of its samples together
    weak = np.argmin(sup, axis=1)
    clear = np.max(sup, axis=1) >= np.maximum(2.0 * np.min(sup, axis=1), 1.0)
    drop[f[clear], p[clear], cams[clear, weak[clear]]] = True
    if not drop.any():
        return drop
    detach_observations(o, drop)
    obs[drop] = np.nan
    _solve_again(o, obs, drop.any(-1), R, t, intr, single_sensor)
    return drop


def unanchored_single_sensor(o: dict[str, NDArray[Any]], face: NDArray[np.bool_],
                             max_gap: int = TRACK_GAP) -> NDArray[np.bool_]:
    """The single-sensor face samples that no triangulated sample anchors.

    A camera's 2D track of a point is its observations of the point in consecutive
    frames (gaps of up to ``max_gap`` frames bridged), in triangulated and single-sensor
    samples alike. A single-sensor sample is anchored when its camera's track through it
    takes part in at least one triangulated sample: the blob was then once checked
    against another camera. An unanchored one was only ever checked against the
    motion's prediction.

    Parameters
    ----------
    o : dict of arrays
        A track result's arrays (read only).
    face : ndarray of bool, shape (P,)
    max_gap : int
        Longest gap (frames) a 2D track bridges.

    Returns
    -------
    ndarray of bool, shape (F, P)

    Examples
    --------
    A point seen by camera 0 on frames 0-4 (triangulated with camera 1 on frames 0-1)
    and by camera 1 alone on frames 8-9:

    >>> import numpy as np
    >>> from carapost.algorithms.codes import RECON_SINGLE_SENSOR, RECON_TRIANGULATED
    >>> obs = np.full((10, 1, 2, 2), np.nan); recon = np.zeros((10, 1), np.int8)
    >>> obs[0:5, 0, 0] = 1.0; obs[0:2, 0, 1] = 1.0; obs[8:10, 0, 1] = 1.0
    >>> recon[0:2] = RECON_TRIANGULATED; recon[2:5] = recon[8:10] = RECON_SINGLE_SENSOR
    >>> m = unanchored_single_sensor({"obs": obs, "recon": recon}, np.ones(1, bool))
    >>> np.flatnonzero(m[:, 0]).tolist()
    [8, 9]
    """
    recon = o["recon"]
    has = np.isfinite(o["obs"]).all(-1)  # (F, P, C)
    F, P, C = has.shape
    single = (recon == RECON_SINGLE_SENSOR) & face[None, :] & (has.sum(-1) == 1)
    out = np.zeros((F, P), bool)
    if not single.any():
        return out
    tri = recon == RECON_TRIANGULATED
    on = has & (tri | (recon == RECON_SINGLE_SENSOR))[..., None]
    # one flat sequence per (point, camera): runs of observations split where the gap
    # exceeds max_gap or the (point, camera) changes
    seq = np.moveaxis(on, 0, -1).reshape(-1)  # (P * C * F,)
    idx = np.flatnonzero(seq)
    if idx.size == 0:
        return out
    pair, frame = np.divmod(idx, F)
    new = np.ones(idx.size, bool)
    new[1:] = (pair[1:] != pair[:-1]) | (frame[1:] - frame[:-1] > max_gap + 1)
    run = np.cumsum(new) - 1
    p_of = pair // C
    anchored_obs = tri[frame, p_of]
    anchored = np.zeros(run[-1] + 1, bool)
    np.logical_or.at(anchored, run, anchored_obs)
    lonely = ~anchored[run] & single[frame, p_of]
    out[frame[lonely], p_of[lonely]] = True
    return out


def reject_unanchored_single_sensor(o: dict[str, NDArray[Any]], face: NDArray[np.bool_],
                                    fixed: NDArray[np.bool_],
                                    max_gap: int = TRACK_GAP) -> NDArray[np.bool_]:
    """Turn the unanchored single-sensor face samples (:func:`unanchored_single_sensor`)
    into gaps; returns them, (F, P)."""
    bad = unanchored_single_sensor(o, face, max_gap) & ~fixed[:, None]
    if bad.any():
        detach_observations(o, np.broadcast_to(bad[..., None], o["detection"].shape))
        _make_gaps(o, bad)
    return bad


def reject_wrong_samples(o: dict[str, NDArray[Any]], face: NDArray[np.bool_],
                         fixed: NDArray[np.bool_], nb: NDArray[np.intp] | None = None
                         ) -> NDArray[np.bool_]:
    """Remove the triangulated face samples the point's motion contradicts as a whole.

    Parameters
    ----------
    o : dict of arrays
        The track result's arrays (changed in place: the flagged samples lose their
        observations and become gaps).
    face : ndarray of bool, shape (P,)
    fixed : ndarray of bool, shape (F,)
        Frames left alone (the initialised frame).
    nb : ndarray of int, shape (P, k), optional
        Each point's neighbours, when already known.

    Returns
    -------
    ndarray of bool, shape (F, P)
        The samples removed.
    """
    tri = (o["recon"] == RECON_TRIANGULATED) & face[None, :]
    if tri.sum() < 10:
        return np.zeros(tri.shape, bool)
    X = np.where(tri[..., None], o["positions"].astype(np.float64), np.nan)
    nb = neighbours(X, tri) if nb is None else nb
    bad = inconsistent_samples(X, tri, nb) & ~fixed[:, None]
    if not bad.any():
        return bad
    detach_observations(o, np.broadcast_to(bad[..., None], o["detection"].shape))
    _make_gaps(o, bad)
    return bad


def place_single_sensor(o: dict[str, NDArray[Any]], R: NDArray, t: NDArray,
                        face: NDArray[np.bool_], intr: CameraIntrinsics,
                        nb: NDArray[np.intp] | None = None, max_gap: int = MAX_GAP,
                        threshold_mm: float | None = None,
                        ref_sigma: NDArray[np.floating] | None = None
                        ) -> NDArray[np.float32]:
    """Put every single-sensor face sample on its ray nearest the prediction from both
    sides; return their sigmas.

    Parameters
    ----------
    o, R, t, face, intr, nb
        As for :func:`reject_by_motion` (every frame is placed, the fixed one too).
    max_gap : int
        Farthest (frames) the prediction from both sides is used.
    threshold_mm : float, optional
        The Single Sensor Tracking Threshold: a sample whose ray passes further than
        this from its prediction, or whose prediction's expected error there (RMS per
        axis) is above it, is removed (a gap), as the per-frame tracker does not keep
        such samples. None keeps every sample.
    ref_sigma : ndarray, shape (F, P), optional
        Sigma (mm) of the triangulated samples. A prediction carries its references'
        own error: where a reference is worse than the point's typical sample (the
        frames where the caddy's second camera starts to lose the marker), its excess
        variance, weighted as in the blend, is added to the sample's.

    Returns
    -------
    ndarray, shape (F, P), float32
        Sigma (mm) of each single-sensor sample: the RMS length of the prediction's
        error measured on the take for its distance in time to the triangulated
        samples (``sqrt(3)`` times :func:`prediction_sigma`'s per-axis figure); NaN
        elsewhere.
    """
    F, P = o["recon"].shape
    sigma = np.full((F, P), np.nan, np.float32)
    obs = o["obs"].astype(np.float64)
    has = np.isfinite(obs).all(-1)
    # the fixed (initialised) frame too: what it holds of a point found later is the
    # per-frame tracker's placement, predicted from one side only and with no sigma
    # (Track Take keeps the initialised points' samples of that frame as they were)
    single = (o["recon"] == RECON_SINGLE_SENSOR) & face[None, :] & (has.sum(-1) == 1)
    tri = (o["recon"] == RECON_TRIANGULATED) & face[None, :]
    if not single.any() or tri.sum() < 10:
        return sigma
    X = np.where(tri[..., None], o["positions"].astype(np.float64), np.nan)
    nb = neighbours(X, tri) if nb is None else nb
    pred, gap = neighbour_prediction(X, tri, nb=nb)
    # far from both sides the tracker's own placement (its elastic prediction, frame by
    # frame) is kept, only moved onto the ray of the fitted cameras
    old = o["positions"].astype(np.float64)
    far = ~((gap >= 0) & (gap <= max_gap)) & np.isfinite(old).all(-1)
    pred[far] = old[far]
    f, p = np.nonzero(single & np.isfinite(pred).all(-1))
    if f.size:
        cam = np.argmax(has[f, p], axis=1)
        Xs, dist, _ = place_on_rays(pred[f, p], obs[f, p, cam], R[f], t[f], intr, cam)
        ok = np.isfinite(Xs).all(-1)
        f, p, Xs, dist = f[ok], p[ok], Xs[ok], dist[ok]
        o["positions"][f, p] = Xs.astype(o["positions"].dtype)
        o["residual"][f, p] = dist.astype(o["residual"].dtype)
    # the sigma: the prediction's error measured on the take at that distance in time
    # (interpolated between the measured gaps, the longest one beyond)
    curve = prediction_sigma(X, tri, nb, _GAPS)  # (P, G)
    extra = np.zeros((F, P))
    good = np.isfinite(curve)
    if good.any():
        curve = np.maximum.accumulate(np.where(good, curve, 0.0), axis=1)
        fs, ps = np.nonzero(single)
        g = np.where(gap[fs, ps] > 0, gap[fs, ps], _GAPS[-1]).astype(np.float64)
        # piecewise linear in the gap per point (the longest measured one beyond)
        j = np.clip(np.searchsorted(_GAPS, g) - 1, 0, _GAPS.size - 2)
        w = np.clip((g - _GAPS[j]) / (_GAPS[j + 1] - _GAPS[j]), 0.0, 1.0)
        val = curve[ps, j] * (1 - w) + curve[ps, j + 1] * w
        sigma[fs, ps] = val.astype(np.float32)  # per axis (the threshold's test)
        if ref_sigma is not None:
            # per axis, like the curve: the reference's error lies mostly along the
            # depth of its caddy, which is about the single camera's ray. Not in the
            # threshold's test: that asks how well the face's motion carries a point
            # over the gap, as the per-frame tracker does
            extra[fs, ps] = _reference_excess(ref_sigma, tri, fs, ps) / 3.0
    if threshold_mm is not None:
        res = o["residual"].astype(np.float64)
        with np.errstate(invalid="ignore"):
            # the sigma too: a prediction expected to be off by more than the tolerated
            # error places the sample along its ray no better than that
            drop = single & ((res > threshold_mm) | (sigma > threshold_mm))
        if drop.any():
            detach_observations(o, drop[..., None] & has)
            _make_gaps(o, drop)
            sigma[drop] = np.nan
    # the stored sigma is the RMS length of the prediction's error, as every sample's is
    # (the root of its covariance's trace): the sample's error lies along its ray, often
    # the prediction's worst direction, and the per-axis figure left 35 % of the errors
    # within one sigma on the takes of other renderers (docs/benchmarks.md)
    sigma = np.sqrt(sigma.astype(np.float64) ** 2 + extra)
    return (sigma * np.sqrt(3.0)).astype(np.float32)


def _reference_excess(ref_sigma: NDArray[np.floating], tri: NDArray[np.bool_],
                      fs: NDArray[np.intp], ps: NDArray[np.intp]) -> NDArray[np.float64]:
    """(N,) variance (mm^2, RMS length squared) the references of samples ``(fs, ps)``
    add beyond the point's typical triangulated sample: each side's sigma squared less
    the point's median one, weighted by its blend weight squared (the nearer side
    weighs more, linearly in time, as :func:`neighbour_prediction` blends them).

    The measured prediction error (:func:`prediction_sigma`) already holds a typical
    reference's error; only what a particular reference has beyond that is added."""
    F, P = tri.shape
    sg = np.where(tri, np.asarray(ref_sigma, np.float64), np.nan)
    typical = np.zeros(P)
    known = np.isfinite(sg).any(0)  # a point with no sigma at all: nothing to compare
    typical[known] = np.nanmedian(sg[:, known], axis=0)
    frames = np.arange(F)[:, None]
    before = np.maximum.accumulate(np.where(tri, frames, -1), axis=0)
    after = np.minimum.accumulate(np.where(tri, frames, F)[::-1], axis=0)[::-1]
    a, b = before[fs, ps], after[fs, ps]
    has_a, has_b = a >= 0, b < F
    da = np.where(has_a, fs - a, 0).astype(np.float64)
    db = np.where(has_b, b - fs, 0).astype(np.float64)
    both = has_a & has_b
    wa = np.where(both, db / np.maximum(da + db, 1.0), has_a.astype(np.float64))
    wb = np.where(both, da / np.maximum(da + db, 1.0), has_b.astype(np.float64))
    typ = np.nan_to_num(typical[ps]) ** 2
    ea = np.where(has_a, np.nan_to_num(sg[np.where(has_a, a, 0), ps]) ** 2 - typ, 0.0)
    eb = np.where(has_b, np.nan_to_num(sg[np.where(has_b, b, 0), ps]) ** 2 - typ, 0.0)
    return wa ** 2 * np.maximum(ea, 0.0) + wb ** 2 * np.maximum(eb, 0.0)

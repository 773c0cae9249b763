"""Partial occlusion and missed markers of a synthetic take, with their truth.

Two things the Target Tracker is for, and the automatic tracker struggles with:

- *Partial occlusion*: an eyelid fold creeping over an upper-lid marker while the eye
  closes, and a lip curling over a lip marker. The occluder is a straight edge lying on
  the marker disc's plane (the fold and the lip lie on the skin), so the hidden part is
  the same in every camera. It is described per frame and marker by a unit direction
  ``cover_dir`` in the disc's plane (pointing from the centre towards the occluder) and
  an offset ``cover_offset`` (mm): the points ``x`` of the disc with
  ``(x - centre) . cover_dir > cover_offset`` are hidden. An offset at or above the
  radius hides nothing.
- *Missed markers*: a marker whose ink fades to a low contrast over a stretch of frames
  (sweat, a smudged marker, a grazing light), so that the blob detector misses it while
  it stays visible to the eye. Described by a per-frame ``contrast`` factor (F, M) of
  the ink's opacity (1 = as painted).

The truth of a partial occlusion is the centroid of the visible part of the disc (a
circular segment removed from the disc: a closed form), in 3D and projected into every
camera, next to the disc centre (`SynthScene.uv`). Like ``uv`` it is the projection of
a point on the disc, not the image centroid of the ellipse.

>>> import numpy as np
>>> float(np.round(segment_centroid_offset(np.array([1.0]), np.array([0.0]))[0], 4))
-0.4244
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["segment_centroid_offset", "partial_cover", "missed_stretches",
           "MISSED_CONTRAST", "LID_START", "CURL_START"]

#: Blink activation at which an upper-lid fold starts covering the lid marker; the fold
#: covers it linearly up to `carapost.synth.scene.BLINK_HIDE`, where it is hidden.
LID_START = 0.15
#: Largest fraction of an upper-lid marker's diameter covered before it is hidden.
LID_MAX_COVER = 0.85
#: Lip-curl activation at which a curling lip starts covering a lip marker.
CURL_START = 0.2
#: Lip-curl activation at which the cover reaches `CURL_MAX_COVER`.
CURL_FULL = 0.6
#: Largest fraction of a lip marker's diameter a lip curl covers (it stays visible).
CURL_MAX_COVER = 0.6
#: Contrast factor of a missed marker's ink in the middle of its stretch (1 = as painted).
MISSED_CONTRAST = 0.2
#: Frames over which a missed marker's contrast ramps down and back up.
MISSED_RAMP = 3


def segment_centroid_offset(radius: NDArray, offset: NDArray) -> NDArray[np.float64]:
    """Signed distance (mm) from a disc's centre to the centroid of its visible part.

    Parameters
    ----------
    radius : ndarray, shape (N,)
        Disc radii (mm).
    offset : ndarray, shape (N,)
        Cover offsets (mm): the part beyond ``offset`` along the cover direction is
        hidden; ``offset >= radius`` hides nothing.

    Returns
    -------
    ndarray, shape (N,)
        The centroid's coordinate along the cover direction (mm, <= 0: away from the
        occluder); 0 where nothing is hidden; the edge (``offset``) where all but a
        vanishing sliver is hidden.
    """
    r = np.asarray(radius, dtype=np.float64)
    o = np.clip(np.asarray(offset, dtype=np.float64) / r, -1.0, 1.0)
    th = np.arccos(o)  # half-angle of the hidden cap
    cap_area = th - np.sin(th) * np.cos(th)  # in units of r^2
    # the cap's centroid (along the direction) is 2 sin^3 / (3 cap_area) in units of r
    cap_moment = 2.0 / 3.0 * np.sin(th) ** 3
    vis_area = np.pi - cap_area
    with np.errstate(divide="ignore", invalid="ignore"):
        c = np.where(vis_area > 1e-9, -cap_moment / vis_area, -1.0)
    return np.where(o >= 1.0, 0.0, c) * r


def partial_cover(labels: list[str], eyelid: NDArray, radii: NDArray, normals: NDArray,
                  head_R: NDArray, blink: NDArray, lip_curl: NDArray, blink_hide: float
                  ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Where an eyelid fold or a curling lip covers part of a marker disc.

    Parameters
    ----------
    labels : list of str, length M
    eyelid : ndarray of bool, shape (M,)
        Upper-lid markers (covered from above by the fold while the eye closes).
    radii : ndarray, shape (M,)
        Disc radii (mm).
    normals : ndarray, shape (F, M, 3)
        Disc normals (helmet frame).
    head_R : ndarray, shape (F, 3, 3)
        Head orientation (the fold and lips move with the head).
    blink, lip_curl : ndarray, shape (F,)
        Expression activations.
    blink_hide : float
        Blink activation from which upper-lid markers are hidden.

    Returns
    -------
    cover_dir : ndarray, shape (F, M, 3)
        Unit direction in each disc's plane towards its occluder (helmet frame).
    cover_offset : ndarray, shape (F, M)
        Offset of the occluding edge from the centre (mm); ``inf`` where nothing covers.
    """
    F, M = normals.shape[:2]
    up = head_R[:, :, 1]  # the head's up axis in the helmet frame (F, 3)
    cover = np.zeros((F, M))
    sign = np.zeros(M)  # +1: covered from above (fold, lower lip curling up), -1: below
    lid = np.clip((blink - LID_START) / (blink_hide - LID_START), 0.0, 1.0) * LID_MAX_COVER
    curl = np.clip((lip_curl - CURL_START) / (CURL_FULL - CURL_START), 0.0, 1.0) \
        * CURL_MAX_COVER
    for m, label in enumerate(labels):
        if eyelid[m]:
            cover[:, m], sign[m] = lid, 1.0
        elif "Upper_Lip" in label:
            cover[:, m], sign[m] = curl, -1.0   # the upper lip rolls in from the mouth line
        elif "Lower_Lip" in label:
            cover[:, m], sign[m] = curl, 1.0
    dirs = np.einsum("fi,m->fmi", up, np.where(sign == 0, 1.0, sign))
    dirs -= np.einsum("fmi,fmi->fm", normals, dirs)[..., None] * normals
    dirs /= np.maximum(np.linalg.norm(dirs, axis=-1, keepdims=True), 1e-12)
    offset = np.where(cover > 0, radii[None] * (1.0 - 2.0 * cover), np.inf)
    return dirs, offset


def missed_stretches(candidates: NDArray, n: int, n_markers: int, n_frames: int,
                     rng: np.random.Generator
                     ) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Pick ``n`` markers and one stretch of frames each over which their ink fades.

    Parameters
    ----------
    candidates : ndarray of int
        Markers that may be picked (e.g. visible throughout).
    n : int
        How many to pick (at most ``len(candidates)``).
    n_markers, n_frames : int
        ``M`` and ``F`` of the take.
    rng : numpy.random.Generator

    Returns
    -------
    contrast : ndarray, shape (F, M)
        Factor of each marker's ink opacity: 1 outside the stretches, ramping down over
        `MISSED_RAMP` frames to `MISSED_CONTRAST` and back up.
    missed : ndarray of bool, shape (F, M)
        The stretches (every frame whose contrast is below 1).
    """
    F, M = int(n_frames), int(n_markers)
    contrast = np.ones((F, M))
    picks = rng.permutation(np.asarray(candidates, dtype=np.int64))[:max(0, int(n))]
    length = int(np.clip(round(0.3 * F), 2 * MISSED_RAMP + 2, max(F - 4, 2 * MISSED_RAMP + 2)))
    for m in np.sort(picks):
        if F < length + 4:
            break
        a = int(rng.integers(2, F - length - 1))
        k = np.arange(length, dtype=np.float64)
        # a smooth fade in and out: 1 -> MISSED_CONTRAST over MISSED_RAMP frames each end
        ramp = np.clip(np.minimum(k + 1, length - k) / (MISSED_RAMP + 1), 0.0, 1.0)
        ramp = 0.5 - 0.5 * np.cos(np.pi * ramp)
        contrast[a:a + length, m] = 1.0 - (1.0 - MISSED_CONTRAST) * ramp
    return contrast, contrast < 1.0

"""Blob (painted marker) detection in camera images.

The detector turns one grey image into a table of elliptical blob detections, each with
a sub-pixel centre, semi-axes, angle, colour (black / white) and a calibrated
probability ``score`` that it is really a blob centre. All steps work on whole images
with OpenCV, on all candidates at once with numpy, or in compiled (numba) loops over the
candidates; there is no Python loop per pixel or blob:

1. Polarity: black blobs are found on the inverted image, so blobs are always bright
   peaks ``d`` on a darker surround.
2. Seeds per scale: a small pyramid (1x, 2x, 4x, ... reduced copies) gives each level a
   band of blob sizes (semi-major axis up to ~10 px of that level). On every level the
   surround is a grey opening with a window just larger than the band's largest blob,
   so a blob is judged against the skin right around it (the opening runs on the next
   coarser level); pixels at least half their local peak contrast form regions whose
   outlines (``cv2.findContours``) give the seed ellipses by their area moments, for
   all outlines at once. Regions too large for the full-resolution level (a marker
   joined to a nostril, a crease or the dark image border) are cut again at stricter
   fractions of their local peak contrast; compact parts of the right size become
   *split* seeds.
3. Refinement at the blob's own scale: per seed, a plane fitted (twice, the second time
   without ring pixels far above the first plane) to a ring of pixels around the seed
   ellipse is the local background, which removes shading gradients; each pixel's
   coverage is its contrast over the plane divided by the full paint contrast there
   (the core's, scaled by the light at that pixel), clipped to 0-1, inside the seed
   ellipse grown by 1.5 px. Its centroid (leaving out the faintest coverage, the blur
   tail at the support's edge and the skin's noise) is the sub-pixel centre
   and its second moments the ellipse (``a = 2 sqrt(lambda_1)``). Seeds larger than
   ~12 px are refined on a reduced copy (moments survive area reduction). A compiled
   kernel (numba) visits each seed's support and ring pixels once per pass; the numpy
   reference (seeds grouped by patch size, sums as products with one fixed design
   matrix) gives the same sums.
4. Probability: a small neural network (one hidden layer of 32 tanh units, trained on
   log-loss with an L2 penalty) over scale-free features (signal-to-noise, contrast
   relative to the surround, how well the coverage fills its ellipse, ring roughness,
   symmetry, axis ratio, how much of the ring is as dark as the blob, how far the ring
   plane sits above the surround) and over the candidate's appearance (its surroundings
   sampled on a grid aligned with its ellipse and on a wider context grid, scaled to
   its contrast and folded about both axes) gives the probability that the candidate
   is a blob centre; split seeds have a model of their own. It was fitted on synthetic images
   with known truth by ``scripts/train_blob_model.py`` (weights in
   ``carapost/resources/blob_model.json``). Candidates whose major axis (the full
   length of the longest ellipse axis, ``2 a``) is outside the radius range, or whose
   score is below the threshold, are dropped; the same blob seen on two levels is kept
   once.

Fully saturated regions (255) have no contrast against their surround and give no
detections; candidates that are mostly at the image's clipping level (0 for black
blobs, 255 for white ones) are rejected.

The package is split by stage; this module re-exports the public API:

- :mod:`.params` -- :class:`BlobParameters` (the Blob Parameters section);
- :mod:`.detections` -- :class:`BlobDetections`, :class:`Candidates`, FEATURE_NAMES;
- :mod:`.image` -- input validation, 8-bit conversion, noise level;
- :mod:`.pyramid` -- size bands of the levels, area pyramid, levels in one buffer;
- :mod:`.seeds` -- step 2, seed ellipses of one level (and split seeds);
- :mod:`.refine` (numpy reference) and :mod:`._refine_jit` (compiled) -- step 3;
- :mod:`.appearance` and :mod:`._appearance_jit` -- the appearance features;
- :mod:`.score` -- step 4, the probability networks;
- :mod:`.candidates` -- all candidates of one colour (steps 1-4 for one image);
- :mod:`.detect` -- :func:`detect_blobs`, :func:`preview_blobs`,
  :func:`detect_blobs_batch` (worker processes of :mod:`carapost.parallel`),
  :func:`warm_up`, :func:`start_workers`, :func:`shutdown_workers`; :mod:`._pool` --
  :func:`start_server` (the forkserver, without importing the detector).

Examples
--------
>>> import numpy as np, cv2
>>> from carapost.algorithms.blobs import BlobParameters, detect_blobs
>>> img = np.full((64, 64), 200, np.uint8)
>>> _ = cv2.circle(img, (32, 30), 6, 20, -1)
>>> det = detect_blobs(img, BlobParameters(black_threshold=0.5))
>>> np.round(det.centre).tolist(), det.colour.tolist()
([[32.0, 30.0]], [0])
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from carapost.algorithms._lazy import lazy_names
from carapost.algorithms.blobs.detections import (
    BLACK,
    FEATURE_NAMES,
    WHITE,
    BlobDetections,
    Candidates,
)
from carapost.algorithms.blobs.params import BlobParameters

# The detector's stages load numba and its compiled kernels (~0.5 s): they are imported
# on first use, so that importing the parameters (the properties registry, the window
# at start-up) stays fast. The window warms the kernels up on a background thread.
_LAZY = {
    "blob_candidates": "candidates",
    "PROCESS_CHUNK": "detect", "PROCESS_MIN_IMAGES": "detect", "detect_blobs": "detect",
    "detect_blobs_batch": "detect", "preview_blobs": "detect", "shutdown_workers": "detect",
    "warm_up": "detect", "start_workers": "detect", "start_server": "_pool",
    "MODEL_HIDDEN": "score", "MODEL_INPUTS": "score", "MODEL_KINDS": "score",
    "ScoreNet": "score", "blob_probability": "score", "net_logit": "score",
}

if TYPE_CHECKING:
    from carapost.algorithms.blobs._pool import start_server
    from carapost.algorithms.blobs.candidates import blob_candidates
    from carapost.algorithms.blobs.detect import (
        PROCESS_CHUNK,
        PROCESS_MIN_IMAGES,
        detect_blobs,
        detect_blobs_batch,
        preview_blobs,
        shutdown_workers,
        start_workers,
        warm_up,
    )
    from carapost.algorithms.blobs.score import (
        MODEL_HIDDEN,
        MODEL_INPUTS,
        MODEL_KINDS,
        ScoreNet,
        blob_probability,
        net_logit,
    )


__getattr__, __dir__ = lazy_names(__name__, _LAZY, globals())

__all__ = [
    "BlobParameters",
    "BlobDetections",
    "Candidates",
    "detect_blobs",
    "detect_blobs_batch",
    "preview_blobs",
    "blob_candidates",
    "blob_probability",
    "FEATURE_NAMES",
    "BLACK",
    "WHITE",
    "MODEL_KINDS",
    "MODEL_INPUTS",
    "MODEL_HIDDEN",
    "ScoreNet",
    "net_logit",
    "PROCESS_MIN_IMAGES",
    "PROCESS_CHUNK",
    "warm_up",
    "start_workers",
    "start_server",
    "shutdown_workers",
]

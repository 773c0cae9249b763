"""The skin following the markers: a warp of the background layer through their motion.

The renderer's background (skin texture, shading, the eyes, lips and nostrils) is ray
cast once per camera with the head at rest and warped each frame by the affine map that
follows the head (`carapost.synth.render`). The markers move with the expression as
well, so by default they slide over a skin that does not: on the lips by up to 15 px
over a speech take. Painted markers move with the skin they are painted on, and a
tracker that matches the skin around a marker (a faded marker, whose disc no longer
dominates its pattern) sees a skin that moved with it.

With `SynthConfig.skin_motion` the background is resampled through a smooth
displacement field that carries every visible marker exactly along: at each marker's
image position in the frame, the field is the marker's offset from where the head's
affine map puts the skin under it (its place on the head at rest); in between, a thin-
plate spline through those offsets, and zero offsets on the head's outline far from any
marker (hair, ears and the head's edge follow the head alone).

Coordinates are raw pixels with the centre of the top-left pixel at (0, 0).
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from carapost.algorithms.camera import project

__all__ = ["marker_offsets", "warp_head"]

#: Spacing of the grid the displacement field is evaluated on (px); the field is
#: smooth (a thin-plate spline through markers 10-40 px apart), bilinear in between.
GRID_PX = 8
#: Outline points of the head this far from every marker (px) are held still.
ANCHOR_PX = 40.0


def marker_offsets(scene, frame: int, camera: int, A: NDArray
                   ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Where the visible markers are and how far they are off the head-following skin.

    Parameters
    ----------
    scene : SynthScene
        With ``rest_points3d`` (`SynthConfig.skin_motion`).
    frame, camera : int
    A : ndarray, shape (2, 3)
        The head's affine map of this image (reference -> frame pixels).

    Returns
    -------
    at : ndarray, shape (K, 2)
        Image positions (px) of the field's control points: the visible markers, then
        the still outline points.
    offset : ndarray, shape (K, 2)
        Displacement (px) at each: the marker's image position minus the affine image
        of the skin under it at rest; zero for the outline points.
    """
    key = f"skin_ref{camera}"
    if key not in scene.cache:
        R0, t0 = scene.nominal_R[camera:camera + 1], scene.nominal_t[camera:camera + 1]
        ref, _ = project(scene.rest_points3d, R0, t0, scene.intrinsics.subset([camera]))
        scene.cache[key] = ref[:, 0]
    ref = scene.cache[key]
    vis = scene.visible[frame, :, camera] & np.isfinite(scene.uv[frame, :, camera]).all(-1)
    uv = scene.uv[frame, vis, camera]
    moved = ref[vis] @ A[:, :2].T + A[:, 2]
    # the head's outline: a ring of points the markers do not reach, held still
    w, h = scene.size
    g = np.linspace(0.0, 1.0, 9)[:-1]   # each edge without its last corner: no repeats
    ring = np.concatenate([np.stack([g * (w - 1), np.zeros_like(g)], 1),
                           np.stack([(1 - g) * (w - 1), np.full_like(g, h - 1)], 1),
                           np.stack([np.zeros_like(g), (1 - g) * (h - 1)], 1),
                           np.stack([np.full_like(g, w - 1), g * (h - 1)], 1)])
    if len(uv):
        far = np.min(np.linalg.norm(ring[:, None] - uv[None], axis=-1), axis=1) > ANCHOR_PX
        ring = ring[far]
    at = np.concatenate([uv, ring])
    offset = np.concatenate([uv - moved, np.zeros_like(ring)])
    return at, offset


def warp_head(scene, src: NDArray[np.float32], A: NDArray, frame: int, camera: int,
              roi: tuple[int, int, int, int]) -> tuple[NDArray[np.float32],
                                                       tuple[int, int, int, int]]:
    """The background layer ``src`` (reference pixels) as the frame shows it.

    Each output pixel ``q`` takes the reference pixel ``A^-1 (q - D(q))``, ``D`` the
    displacement field of :func:`marker_offsets` (so a marker's own pixel takes the
    skin under it at rest).

    Parameters
    ----------
    scene : SynthScene
    src : ndarray (H, W) float32
        The layer in reference pixels.
    A : ndarray, shape (2, 3)
        The head's affine map (reference -> frame pixels).
    frame, camera : int
    roi : tuple of int
        (x0, y0, x1, y1): the region of ``src`` (reference pixels) with content.

    Returns
    -------
    out : ndarray (y1 - y0, x1 - x0) float32
    roi : tuple of int
        (x0, y0, x1, y1): the region of the frame ``out`` covers.
    """
    at, offset = marker_offsets(scene, frame, camera, A)
    # the output region: the layer's region under the affine map, grown by the largest
    # displacement (the field's extremes are at its control points, give or take)
    w, h = scene.size
    sx0, sy0, sx1, sy1 = roi
    corners = np.array([[sx0, sy0, 1], [sx1, sy0, 1], [sx0, sy1, 1], [sx1, sy1, 1]],
                       float) @ np.asarray(A, float).T
    grow = 3 + (float(np.abs(offset).max()) * 1.5 if len(offset) else 0.0)
    x0 = int(max(np.floor(corners[:, 0].min() - grow), 0))
    y0 = int(max(np.floor(corners[:, 1].min() - grow), 0))
    x1 = int(min(np.ceil(corners[:, 0].max() + grow) + 1, w))
    y1 = int(min(np.ceil(corners[:, 1].max() + grow) + 1, h))
    if x1 <= x0 or y1 <= y0:
        return np.zeros((0, 0), np.float32), (0, 0, 0, 0)
    gx = np.arange(x0, x1 + GRID_PX, GRID_PX, dtype=np.float64)
    gy = np.arange(y0, y1 + GRID_PX, GRID_PX, dtype=np.float64)
    grid = np.stack(np.meshgrid(gx, gy), axis=-1).reshape(-1, 2)
    if len(at) >= 3:
        # imported here: every render imports this module, few takes move their skin
        from scipy.interpolate import RBFInterpolator

        field = RBFInterpolator(at, offset, kernel="thin_plate_spline")(grid)
    else:
        field = np.zeros_like(grid)
    field = np.ascontiguousarray(field.reshape(len(gy), len(gx), 2), dtype=np.float32)
    # bilinear between the grid's nodes (node i at pixel x0 + i * GRID_PX exactly)
    nx, ny = np.meshgrid(np.arange(x1 - x0, dtype=np.float32) / GRID_PX,
                         np.arange(y1 - y0, dtype=np.float32) / GRID_PX)
    dense = cv2.remap(field, nx, ny, interpolation=cv2.INTER_LINEAR,
                      borderMode=cv2.BORDER_REPLICATE)
    qx, qy = np.meshgrid(np.arange(x0, x1, dtype=np.float32),
                         np.arange(y0, y1, dtype=np.float32))
    px, py = qx - dense[..., 0], qy - dense[..., 1]
    Ai = cv2.invertAffineTransform(np.asarray(A, dtype=np.float64))
    mx = (Ai[0, 0] * px + Ai[0, 1] * py + Ai[0, 2]).astype(np.float32)
    my = (Ai[1, 0] * px + Ai[1, 1] * py + Ai[1, 2]).astype(np.float32)
    out = cv2.remap(src, mx, my, interpolation=cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return out, (x0, y0, x1, y1)

"""Refinement of blob seeds: sub-pixel centre, ellipse and features of each seed.

At the blob's own scale, per seed, a plane fitted (twice, the second time without ring
pixels far above the first plane) to a ring of pixels around the seed ellipse is the
local background, which removes shading gradients; each pixel's coverage is its
contrast over the plane divided by the full paint contrast there (the core's, scaled by
the light at that pixel), clipped to 0-1, inside the seed ellipse grown by
``SUPPORT_MARGIN``. Its centroid (of the coverage above ``CENTRE_DEAD_ZONE``) is the
sub-pixel centre and its second moments the ellipse (``a = 2 sqrt(lambda_1)``). The compiled kernel
(:func:`carapost.algorithms.blobs._refine_jit.refine_sums`) visits each seed's support
and ring pixels once per pass; the numpy reference :func:`refine_patches` (seeds grouped
by patch size, sums as products with one fixed design matrix) gives the same sums.

Examples
--------
>>> import numpy as np
>>> from carapost.algorithms.blobs.refine import refine_seeds
>>> y, x = np.mgrid[:40, :40]
>>> d = np.where((x - 20) ** 2 / 25 + (y - 18) ** 2 / 9 <= 1, 220, 40).astype(np.uint8)
>>> one = np.ones(1)
>>> cx, cy, a, b, th, feats, saturated, ok = refine_seeds(
...     d.ravel(), 40 * one.astype(np.int64), 40 * one.astype(np.int64),
...     np.zeros(1, np.int64), one, 20.3 * one, 17.6 * one, 5.0 * one, 3.0 * one,
...     0.0 * one, 40.0 * one, colour=0)
>>> np.round([cx[0], cy[0]], 2).tolist(), bool(ok[0]), feats.shape
([20.0, 18.0], True, (1, 9))
"""

from __future__ import annotations

import math
from functools import cache

import numpy as np

from carapost.algorithms.blobs._refine_jit import refine_sums
from carapost.algorithms.blobs.detections import BLACK

__all__ = ["LOG_SNR_CAP", "CORE_FRACTION", "SUPPORT_MARGIN", "RING_WIDTH", "REFINE_RADIUS",
           "EDGE_COVERAGE", "EDGE_FRACTION", "CENTRE_DEAD_ZONE", "USE_JIT",
           "ellipse_from_moments",
           "refine_seeds", "refine_patches"]

#: Cap of the log signal-to-noise feature: beyond ~90x the noise more contrast is no
#: more evidence of a marker, and without the cap the score learned to distrust very
#: high contrast (dark facial features), which rejected the clean dots of real
#: calibration-target photos.
LOG_SNR_CAP = 4.5
#: Fraction of the peak contrast from which a pixel belongs to a blob's core, whose
#: mean level is the paint's level in the coverage.
CORE_FRACTION = 0.8
#: Margin (px) of the refinement support beyond the seed ellipse, and ring width (px).
#: A 2 px ring (3 px before) sees the shading closest to the blob, where a plane fits it
#: best: centre p95 0.234 -> 0.219 px on the benchmark views, thin markers 0.49 -> 0.45
#: px, recall and the dot grids unchanged.
SUPPORT_MARGIN = 1.5
RING_WIDTH = 2.0
#: Seeds larger than this (px of a level) are refined on the next coarser level.
REFINE_RADIUS = 12.0
#: A blob is cut by the image border when the outermost rows and columns hold at least
#: EDGE_COVERAGE px and EDGE_FRACTION of its coverage: a chord across the blob. One that
#: only touches the border has just its tip there (2 % of a 23 x 17 px brim dot) and an
#: unbiased centroid; a shading gradient running out of the image has much more.
EDGE_COVERAGE = 1.5
EDGE_FRACTION = 0.03
#: Coverage below which a pixel does not count in the blob's centre (the ellipse
#: moments keep every pixel); coverage from it to 0.9 is stretched linearly to 0-1 (and
#: saturates above 0.9), which
#: keeps the centre of a symmetric blob where it is. The lowest coverages are the
#: optics' blur tail at the edge of the support, which pixels of it fall inside the
#: support depending on the sub-pixel position (a thin oblique marker: centre error
#: 0.024 -> 0.011 px RMS), and the skin's texture and noise clipped to positive
#: coverage; on the takes of other renderers the face centres' RMS error against the
#: disc's image went 0.076-0.087 -> 0.070-0.081 px, the brim dots' 0.022-0.031 ->
#: 0.019-0.028 px. It costs a perfectly sharp image (no blur at all) a little
#: pixel-locking (0.004 -> 0.015 px on a large disc), which no camera delivers.
CENTRE_DEAD_ZONE = 0.1


def ellipse_from_moments(s0, sx, sy, sxx, syy, sxy):
    """Centre, semi-axes and angle from raw weighted moments (arrays per candidate)."""
    s0 = np.maximum(s0, 1e-9)
    mx, my = sx / s0, sy / s0
    cxx = np.maximum(sxx / s0 - mx * mx - 1.0 / 12.0, 1e-6)  # less a pixel's own variance
    cyy = np.maximum(syy / s0 - my * my - 1.0 / 12.0, 1e-6)
    cxy = sxy / s0 - mx * my
    tr = cxx + cyy
    root = np.sqrt(((cxx - cyy) * 0.5) ** 2 + cxy * cxy)
    a = 2.0 * np.sqrt(tr * 0.5 + root)
    b = 2.0 * np.sqrt(np.maximum(tr * 0.5 - root, 1e-6))
    theta = 0.5 * np.arctan2(2.0 * cxy, cxx - cyy)
    return mx, my, a, b, theta



#: Half-widths (px) of the square patch classes used by the refinement.
_PATCH_RADII = (6, 8, 10, 13, 17, 22)


@cache
def _design(r: int) -> np.ndarray:
    """[P*P, 6] float32 columns 1, x, y, x^2, y^2, xy of a (2r+1)^2 patch (row-major,
    coordinates relative to the patch centre)."""
    off = np.arange(-r, r + 1, dtype=np.float32)
    y, x = np.meshgrid(off, off, indexing="ij")
    x, y = x.ravel(), y.ravel()
    return np.ascontiguousarray(np.column_stack([np.ones_like(x), x, y, x * x, y * y, x * y]))


@cache
def _design3(r: int) -> np.ndarray:
    """First three columns (1, x, y) of :func:`_design` (contiguous), [P*P, 3]."""
    return np.ascontiguousarray(_design(r)[:, :3])


@cache
def _design_t(r: int) -> np.ndarray:
    """Transpose of :func:`_design` (contiguous), [6, P*P]."""
    return np.ascontiguousarray(_design(r).T)


#: Columns of the plane's normal matrix [[n, sx, sy], [sx, sxx, sxy], [sy, sxy, syy]] in
#: the design sums (1, x, y, x^2, y^2, xy).
_PLANE_IDX = np.array([0, 1, 2, 1, 3, 5, 2, 5, 4])
#: Per-seed sums returned by refine_patches and refine_sums (see there).
_N_SUMS = 21
#: Largest m * n * k of a matrix product that OpenBLAS runs on the calling thread (its
#: default GEMM_MULTITHREAD_THRESHOLD 4 x 65536). Above it, it wakes its own threads,
#: which for these small products costs far more than the product (the detector took
#: 3.6x as long on a loaded 2-core machine), so seeds are refined in chunks that stay
#: below it.
_BLAS_ONE_THREAD = 4 * 65536


#: Refine with the compiled kernel (False: the numpy reference, refine_patches).
USE_JIT = True


def refine_seeds(d: np.ndarray, lw: np.ndarray, lh: np.ndarray, lb: np.ndarray,
                 sigma: np.ndarray, cx, cy, a, b, th, open_bg, colour: int):
    """Centre, ellipse and features of seed ellipses, each on its own pyramid level.

    ``d`` holds the flattened levels (contrast image: the inverted image for black
    blobs) one after the other; per seed ``lw``, ``lh`` are its level's width and
    height, ``lb`` the start of its level in ``d``, ``sigma`` the level's noise and the
    geometry is in that level's pixels.

    Per candidate, a plane fitted to a ring of pixels around the seed ellipse is the
    local background (so a shading gradient neither shifts the centre nor changes the
    contrast); each pixel's coverage is its contrast over that plane relative to the
    paint's full contrast there (the core's, scaled by the light at that pixel: paint
    reflects a fixed fraction of the light), clipped to 0-1 (the painted fraction of an
    anti-aliased pixel); the coverage moments inside the support give the centre and
    ellipse.

    Seeds are grouped by the size of the square patch that holds their ring. Within a
    group every patch has the same pixel grid, so all sums over pixels (plane normal
    equations, moments) and all quadratic forms over pixels (ellipse masks, planes) are
    products with one fixed design matrix [P*P, 6] (BLAS), and the rest is a handful of
    whole-array operations on the stack of patches [n, P*P]. The groups return per-seed
    sums; the ellipses and features are computed once for all seeds.

    The sums come from the compiled
    :func:`~carapost.algorithms.blobs._refine_jit.refine_sums` (``USE_JIT``, default) or
    from its numpy reference :func:`refine_patches`.

    Parameters
    ----------
    d : ndarray [sum of level sizes] uint8
        The contrast pyramid in one buffer (:func:`~.pyramid.stack_levels`).
    lw, lh, lb : ndarray [n] int64
        Width, height and buffer offset of each seed's level.
    sigma : ndarray [n]
        Noise sigma of each seed's level, grey levels.
    cx, cy, a, b, th : ndarray [n]
        Seed centres, semi-axes (px of the seed's level) and angles (rad).
    open_bg : ndarray [n]
        Surround level (the opening) under each seed centre (the ``pedestal`` feature).
    colour : int
        BLACK (``d`` is the inverted image) or WHITE.

    Returns
    -------
    cx, cy, a, b, th : ndarray [n]
        Refined centres, semi-axes and angles (px of the seed's level, rad).
    features : ndarray [n, N_REFINED]
        The refined features, in FEATURE_NAMES order.
    saturated : ndarray [n] bool
        Fully saturated pixels cover much of the half-contrast area.
    ok : ndarray [n] bool
        The refinement holds a blob (finite features, not cut by the image border,
        centre near its seed).
    """
    n = cx.size
    zero = 255.0 if colour == BLACK else 0.0  # the contrast image's level of no light
    m = SUPPORT_MARGIN
    ai, bi = a + m, b + m
    ao, bo = ai + RING_WIDTH, bi + RING_WIDTH
    c, s = np.cos(th), np.sin(th)
    need = np.ceil(np.maximum(np.sqrt((ao * c) ** 2 + (bo * s) ** 2),
                              np.sqrt((ao * s) ** 2 + (bo * c) ** 2)) + 0.5)
    radii = np.asarray(_PATCH_RADII)
    cls = np.minimum(np.searchsorted(radii, need), radii.size - 1)
    xi, yi = np.rint(cx), np.rint(cy)
    dx, dy = cx - xi, cy - yi  # seed centre relative to its patch centre
    if USE_JIT:
        # Compiled: one pass per seed over its own support and ring (3-4x faster).
        # Fixed argument types: one compiled specialisation (a new one costs ~3 s).
        i64 = [np.ascontiguousarray(v, np.int64)
               for v in (lw, lh, lb, np.minimum(need, radii[-1]), xi, yi)]
        f64 = [np.ascontiguousarray(v, np.float64) for v in (sigma, dx, dy, ai, bi, ao, bo, c, s)]
        sums = refine_sums(np.ascontiguousarray(d, np.uint8), *i64[:3], f64[0], *i64[3:],
                           *f64[1:], zero, CORE_FRACTION, CENTRE_DEAD_ZONE)
        cls = cls[:0]
    else:
        sums = np.zeros((n, _N_SUMS))
    for ci in np.unique(cls):
        r = int(radii[ci])
        step = max(1, _BLAS_ONE_THREAD // (6 * (2 * r + 1) ** 2))
        k = np.flatnonzero(cls == ci)
        for i in (k[j:j + step] for j in range(0, k.size, step)):
            sums[i] = refine_patches(d, lw[i], lh[i], lb[i], sigma[i], r,
                                     xi[i].astype(np.int64), yi[i].astype(np.int64),
                                     dx[i], dy[i], ai[i], bi[i], ao[i], bo[i], c[i], s[i],
                                     zero)
    mom, hm = sums[:, 0:6], sums[:, 6:9]
    n_ring, rr2, ring_fill, peak = sums[:, 9], sums[:, 10], sums[:, 11], sums[:, 12]
    coef, n_sat, n_edge = sums[:, 13:16], sums[:, 16], sums[:, 17]
    s0 = mom[:, 0]
    mx, my, a2, b2, th2 = ellipse_from_moments(*mom.T)
    # the centre from the coverage above CENTRE_DEAD_ZONE (the moments' where too faint)
    w0 = sums[:, 18]
    has = w0 > 0.5
    mx = np.where(has, sums[:, 19] / np.maximum(w0, 1e-9), mx)
    my = np.where(has, sums[:, 20] / np.maximum(w0, 1e-9), my)
    n_half = hm[:, 0]
    hx, hy = hm[:, 1] / np.maximum(n_half, 1), hm[:, 2] / np.maximum(n_half, 1)
    rr = np.sqrt(rr2 / np.maximum(n_ring, 1))
    ell_area = math.pi * a2 * b2
    bg_c = np.clip(coef[:, 0] + coef[:, 1] * dx + coef[:, 2] * dy, 0, 255)
    pk = np.maximum(peak, 1e-3)
    with np.errstate(divide="ignore", invalid="ignore"):
        feats = np.column_stack([
            np.minimum(np.log(pk / sigma), LOG_SNR_CAP),
            np.clip(peak / np.maximum(255.0 - bg_c, 1.0), 0, 2),
            np.clip(np.abs(1.0 - s0 / ell_area), 0, 5),
            np.clip(np.abs(1.0 - n_half / ell_area), 0, 5),
            np.clip(rr / pk, 0, 2),
            np.clip(np.hypot(hx - mx, hy - my) / np.maximum(b2, 0.5), 0, 5),
            b2 / a2,
            ring_fill,
            np.clip((bg_c - open_bg) / pk, -2, 5),
        ])
    # Fully saturated pixels (255 in the contrast image: 0 of a black blob's raw image,
    # 255 of a white one's) covering much of the half-contrast area.
    saturated = n_sat > 0.3 * n_half
    ok = (peak > 0) & np.isfinite(feats).all(axis=1) & (n_half > 0)
    # A blob cut by the image border (a chord of it lies on the outermost rows or
    # columns) has a biased centre and a shape that is not its own: a dark band
    # along the border otherwise passes for a large blob.
    ok &= (n_edge < EDGE_COVERAGE) | (n_edge < EDGE_FRACTION * s0)
    # A refined centre far from its seed means the support did not hold the blob.
    ok &= np.hypot(mx - dx, my - dy) <= 0.5 * a + 1.0
    return xi + mx, yi + my, a2, b2, th2, feats, saturated, ok



def refine_patches(d, w, h, lb, sigma, r, xi, yi, dx, dy, ai, bi, ao, bo, c, s,
                   zero=255.0):
    """Sums of :func:`refine_seeds` for seeds whose ring fits a (2r+1)-pixel square patch
    centred on pixel (xi, yi).

    Returns [n, _N_SUMS]: coverage moments (6, design columns about the patch centre),
    half-contrast pixel count and coordinate sums (3), ring pixels used by the plane,
    their squared residual sum, fraction of the ring at half contrast, peak contrast,
    plane coefficients (3), saturated half-contrast pixels, summed coverage of the
    half-contrast pixels on the image's outermost rows and columns, and the centre sums
    (3: 1, x, y) of the coverage above ``CENTRE_DEAD_ZONE``.

    This is the numpy reference of the compiled
    :func:`~carapost.algorithms.blobs._refine_jit.refine_sums` (used when ``USE_JIT`` is
    off).
    """
    g = _design(r)
    g3 = _design3(r)
    gt = _design_t(r)
    n = xi.size
    off = np.arange(-r, r + 1)
    cols, rows = xi[:, None] + off, yi[:, None] + off  # [n, P]
    w, h = w[:, None], h[:, None]
    valid = None
    if (cols[:, 0] < 0).any() or (rows[:, 0] < 0).any() or (cols[:, -1] >= w[:, 0]).any() or (
            rows[:, -1] >= h[:, 0]).any():
        # Patches that reach past the image border: those pixels are neither blob nor
        # background.
        valid = (((rows >= 0) & (rows < h))[:, :, None]
                 & ((cols >= 0) & (cols < w))[:, None, :]).reshape(n, -1)
        cols = np.clip(cols, 0, w - 1)
        rows = np.clip(rows, 0, h - 1)
    flat = ((rows * w + lb[:, None])[:, :, None] + cols[:, None, :]).reshape(n, -1)
    dv8 = np.take(d, flat)  # [n, P*P] uint8
    dv = dv8.astype(np.float32)

    def quad(ea, eb):
        # (u / ea)^2 + (v / eb)^2 about the seed centre, u / v along the ellipse axes,
        # expanded on the design columns.
        ea2, eb2 = 1.0 / (ea * ea), 1.0 / (eb * eb)
        qa, qc = c * c * ea2 + s * s * eb2, s * s * ea2 + c * c * eb2
        qb = 2 * c * s * (ea2 - eb2)
        k = np.column_stack([qa * dx * dx + qc * dy * dy + qb * dx * dy,
                             -2 * qa * dx - qb * dy, -2 * qc * dy - qb * dx, qa, qc, qb])
        return k.astype(np.float32) @ gt

    support = quad(ai, bi) <= 1.0
    ring = quad(ao, bo) <= 1.0
    if valid is not None:
        support &= valid
        ring &= valid
    ring &= ~support
    supf, ringf = support.astype(np.float32), ring.astype(np.float32)
    # Pixels outside the support pushed far down, so a row maximum is one over the support.
    outside = (1.0 - supf) * np.float32(1e9)

    def plane(wgt):
        # Weighted least-squares plane dv ~ c0 + c1 x + c2 y over the pixels in wgt:
        # the normal equations' sums for all seeds in one product.
        sg = (wgt @ g).astype(np.float64)
        rhs = ((wgt * dv) @ g3).astype(np.float64)
        mat = sg[:, _PLANE_IDX].reshape(n, 3, 3)
        mat[:, [0, 1, 2], [0, 1, 2]] += 1e-3
        coef = np.linalg.solve(mat, rhs[..., None])[..., 0]
        n0 = sg[:, 0]
        few = n0 < 3
        if few.any():
            coef[few] = 0.0
            coef[few, 0] = rhs[few, 0] / np.maximum(n0[few], 1)
        return coef, n0

    coef, _ = plane(ringf)
    res = dv - coef.astype(np.float32) @ gt[:3]
    # Second pass without ring pixels well above the plane (a neighbouring marker's
    # edge, a dark crease): they would lift the background under this blob.
    peak = (res - outside).max(axis=1)
    ring2 = ringf * (res < np.maximum(3.0 * sigma, 0.25 * peak)[:, None])
    coef, n_ring = plane(ring2)
    bgp = coef.astype(np.float32) @ gt[:3]
    res = dv - bgp
    peak = (res - outside).max(axis=1)
    pk = np.maximum(peak, 1e-3).astype(np.float32)[:, None]
    # Paint reflects a fixed fraction of the light that skin would: under a shading
    # gradient the fully covered level follows the light, so the full-coverage contrast
    # at each pixel is the core's contrast scaled by the light there, (plane - zero) /
    # (plane at the core - zero), ``zero`` being the contrast image's level of no light
    # (255 for black blobs, whose image is inverted; 0 for white). One number per blob
    # would weight the centroid towards brighter skin; a paint level that ignores the
    # light (the plane less a constant) still weights a thin marker along a steep
    # gradient (scaling by the light: centre p95 of thin markers 0.52 -> 0.49 px). The core's
    # level is its mean (pixels at CORE_FRACTION of the peak contrast or more), not its
    # darkest pixel: noise, and ink or light that is not quite even across a blob, would
    # otherwise leave its interior less than fully covered (a real dot-grid photo's
    # dots then looked unlike painted markers).
    corem = support & (res >= CORE_FRACTION * pk)
    ncore = np.maximum(corem.sum(axis=1), 1)[:, None]
    core = (dv * corem).sum(axis=1)[:, None] / ncore
    bg_core = (bgp * corem).sum(axis=1)[:, None] / ncore
    den = bg_core - np.float32(zero)
    den = np.where(np.abs(den) < 1.0, np.where(den < 0, -1.0, 1.0), den).astype(np.float32)
    full = np.maximum((core - bg_core) * (bgp - np.float32(zero)) / den, 0.25 * pk)
    cov = np.clip(res / full, 0.0, 1.0)
    cov *= supf
    above = res >= 0.5 * pk
    half = above & support
    halff = half.astype(np.float32)
    out = np.empty((n, _N_SUMS))
    out[:, 0:6] = cov @ g
    span = np.float32(1.0 - 2.0 * CENTRE_DEAD_ZONE)
    wc = np.clip((cov - np.float32(CENTRE_DEAD_ZONE)) / span, 0.0, 1.0) * supf
    out[:, 18:21] = wc @ g3
    out[:, 6:9] = halff @ g3
    out[:, 9] = n_ring
    out[:, 10] = np.einsum("ij,ij->i", ring2 * res, res)
    out[:, 11] = np.count_nonzero(above & ring, axis=1) / np.maximum(ringf.sum(axis=1), 1)
    out[:, 12] = peak
    out[:, 13:16] = coef
    out[:, 16] = np.count_nonzero((dv8 == 255) & half, axis=1)
    out[:, 17] = 0
    if (rows[:, 0] <= 0).any() or (cols[:, 0] <= 0).any() or (
            rows[:, -1] >= h[:, 0] - 1).any() or (cols[:, -1] >= w[:, 0] - 1).any():
        # Half-contrast pixels on the outermost rows / columns of the image: the blob
        # is cut by the border.
        edge = (((rows == 0) | (rows == h - 1))[:, :, None]
                | ((cols == 0) | (cols == w - 1))[:, None, :]).reshape(n, -1)
        if valid is not None:
            edge &= valid
        out[:, 17] = np.einsum("ij,ij->i", (edge & half).astype(np.float32), cov)
    return out


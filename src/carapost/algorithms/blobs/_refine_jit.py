"""Compiled (numba) kernel of the blob refinement: the sums of
:func:`carapost.algorithms.blobs.refine.refine_patches`, one seed at a time.

Compiled on first use and cached on disk (``cache=True``, in ``__pycache__`` beside this
file): installing or changing this file compiles the kernels once (~3 s), later runs
load them. Every argument has a fixed type, so one specialisation serves every call.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["refine_sums"]

@numba.njit(cache=True, nogil=True, inline="always")
def _add_plane_pixel(m: np.ndarray, rhs: np.ndarray, x: float, y: float, v: float
                     ) -> None:  # pragma: no cover - jit
    """Add pixel (x, y) of value v to the weight sums ``m`` (1, x, y, x^2, y^2, xy) and
    right-hand sums ``rhs`` (v, v x, v y) of a plane fit (see :func:`_solve_plane`)."""
    m[0] += 1.0
    m[1] += x
    m[2] += y
    m[3] += x * x
    m[4] += y * y
    m[5] += x * y
    rhs[0] += v
    rhs[1] += v * x
    rhs[2] += v * y


@numba.njit(cache=True, nogil=True, inline="always")
def _plane_residuals(pv, px, py, pflag, coef, pres, cnt):  # pragma: no cover - jit
    """Residuals over the plane ``coef`` of the first ``cnt`` pixels into ``pres``;
    returns the largest residual over the support pixels (flag 1), -1e9 if none."""
    peak = -1e9
    for j in range(cnt):
        res = pv[j] - (coef[0] + coef[1] * px[j] + coef[2] * py[j])
        pres[j] = res
        if pflag[j] & 1 and res > peak:
            peak = res
    return peak


@numba.njit(cache=True, nogil=True)
def _solve_plane(m: np.ndarray, rhs: np.ndarray, out: np.ndarray) -> None:  # pragma: no cover - jit
    """Least-squares plane c0 + c1 x + c2 y from weight sums ``m`` (1, x, y, x^2, y^2,
    xy) and right-hand sums ``rhs`` (v, v x, v y) into ``out``; a level plane (the mean)
    when fewer than 3 pixels are given. The 3x3 normal matrix gets 1e-3 on its diagonal,
    as in :func:`~carapost.algorithms.blobs.refine.refine_patches`."""
    n0 = m[0]
    if n0 < 3:
        out[0] = rhs[0] / max(n0, 1.0)
        out[1] = 0.0
        out[2] = 0.0
        return
    a00, a01, a02 = m[0] + 1e-3, m[1], m[2]
    a11, a12, a22 = m[3] + 1e-3, m[5], m[4] + 1e-3
    c00 = a11 * a22 - a12 * a12
    c01 = a02 * a12 - a01 * a22
    c02 = a01 * a12 - a02 * a11
    c11 = a00 * a22 - a02 * a02
    c12 = a01 * a02 - a00 * a12
    c22 = a00 * a11 - a01 * a01
    det = a00 * c00 + a01 * c01 + a02 * c02
    out[0] = (c00 * rhs[0] + c01 * rhs[1] + c02 * rhs[2]) / det
    out[1] = (c01 * rhs[0] + c11 * rhs[1] + c12 * rhs[2]) / det
    out[2] = (c02 * rhs[0] + c12 * rhs[1] + c22 * rhs[2]) / det


@numba.njit(cache=True, nogil=True)
def refine_sums(d, lw, lh, lb, sigma, rad, xi, yi, dx, dy, ai, bi, ao, bo, c, s, zero,
                core_fraction, dead):  # pragma: no cover - jit
    """The sums of :func:`~carapost.algorithms.blobs.refine.refine_patches` (same order
    and meaning) for all seeds, one seed at a time, visiting only the pixels of its
    support and ring (compiled).

    ``rad`` is the half-width of the square around (xi, yi) searched for them (px);
    ``core_fraction`` is ``refine.CORE_FRACTION``; ``dead`` is the coverage below which
    a pixel does not count in the centre sums (``refine.CENTRE_DEAD_ZONE``).
    """
    n = xi.size
    out = np.zeros((n, 21))
    span = 1.0 - 2.0 * dead
    cap = int(2 * rad.max() + 1) ** 2 if n else 1
    px = np.empty(cap)
    py = np.empty(cap)
    pv = np.empty(cap)
    pres = np.empty(cap)
    pflag = np.empty(cap, np.uint8)  # 1 support, 2 ring, 4 ring2, 8 image edge, 16 saturated
    m = np.empty(6)
    rhs = np.empty(3)
    coef = np.empty(3)
    for k in range(n):
        w, h, base, r = lw[k], lh[k], lb[k], rad[k]
        ca, sa = c[k], s[k]
        ia2, ib2 = 1.0 / (ai[k] * ai[k]), 1.0 / (bi[k] * bi[k])
        oa2, ob2 = 1.0 / (ao[k] * ao[k]), 1.0 / (bo[k] * bo[k])
        m[:] = 0.0
        rhs[:] = 0.0
        cnt = 0
        for iy in range(-r, r + 1):
            row = yi[k] + iy
            if row < 0 or row >= h:
                continue
            v0 = iy - dy[k]
            for ix in range(-r, r + 1):
                col = xi[k] + ix
                if col < 0 or col >= w:
                    continue
                u0 = ix - dx[k]
                p = ca * u0 + sa * v0
                q = ca * v0 - sa * u0
                pp, qq = p * p, q * q
                if pp * ia2 + qq * ib2 <= 1.0:
                    f = 1
                elif pp * oa2 + qq * ob2 <= 1.0:
                    f = 2
                else:
                    continue
                val = d[base + row * w + col]
                if row == 0 or row == h - 1 or col == 0 or col == w - 1:
                    f |= 8
                if val == 255:
                    f |= 16
                x, y, v = float(ix), float(iy), float(val)
                px[cnt], py[cnt], pv[cnt], pflag[cnt] = x, y, v, f
                cnt += 1
                if f & 2:
                    _add_plane_pixel(m, rhs, x, y, v)
        _solve_plane(m, rhs, coef)
        # Second plane without ring pixels well above the first one.
        peak = _plane_residuals(pv, px, py, pflag, coef, pres, cnt)
        thr = max(3.0 * sigma[k], 0.25 * peak)
        m[:] = 0.0
        rhs[:] = 0.0
        for j in range(cnt):
            if pflag[j] & 2 and pres[j] < thr:
                pflag[j] |= 4
                _add_plane_pixel(m, rhs, px[j], py[j], pv[j])
        n_ring = m[0]
        _solve_plane(m, rhs, coef)
        peak = _plane_residuals(pv, px, py, pflag, coef, pres, cnt)
        pk = max(peak, 1e-3)
        # Paint level: mean over the core, scaled by the light (see refine_patches).
        core_sum, bg_sum, core_n = 0.0, 0.0, 0
        for j in range(cnt):
            if pflag[j] & 1 and pres[j] >= core_fraction * pk:
                core_sum += pv[j]
                bg_sum += pv[j] - pres[j]
                core_n += 1
        core = core_sum / max(core_n, 1)
        bg_core = bg_sum / max(core_n, 1)
        den = bg_core - zero
        if abs(den) < 1.0:
            den = -1.0 if den < 0 else 1.0
        scale = (core - bg_core) / den
        o = out[k]
        n_ring_all, ring_above = 0, 0
        for j in range(cnt):
            f = pflag[j]
            res = pres[j]
            x, y = px[j], py[j]
            above = res >= 0.5 * pk
            if f & 1:
                full = max(scale * (pv[j] - res - zero), 0.25 * pk)
                cov = min(max(res / full, 0.0), 1.0)
                o[0] += cov
                o[1] += cov * x
                o[2] += cov * y
                o[3] += cov * x * x
                o[4] += cov * y * y
                o[5] += cov * x * y
                wc = min(max((cov - dead) / span, 0.0), 1.0)
                o[18] += wc
                o[19] += wc * x
                o[20] += wc * y
                if above:
                    o[6] += 1.0
                    o[7] += x
                    o[8] += y
                    if f & 16:
                        o[16] += 1.0
                    if f & 8:
                        o[17] += cov
            else:
                n_ring_all += 1
                if above:
                    ring_above += 1
                if f & 4:
                    o[10] += res * res
        o[9] = n_ring
        o[11] = ring_above / max(n_ring_all, 1)
        o[12] = peak
        o[13] = coef[0]
        o[14] = coef[1]
        o[15] = coef[2]
    return out

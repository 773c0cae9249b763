"""Compiled (numba) kernel of the appearance features: bilinear sampling of each
candidate's grid, scaling to its contrast and folding
(:func:`carapost.algorithms.blobs.appearance.appearance_features`).

Compiled on first use and cached on disk (``cache=True``, in ``__pycache__`` beside this
file).
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["sample_fold"]


@numba.njit(cache=True, nogil=True, error_model="numpy")
def sample_fold(buf, lb, lw, lh, lf, min_scale, cx, cy, su, sv, c, s, k, out
                ):  # pragma: no cover - jit
    """The sampling, scaling and folding of
    :func:`~carapost.algorithms.blobs.appearance.appearance_features`, one candidate at a
    time: bilinear samples of level ``lf`` (pixels beyond the border repeat the border),
    ring median, centre mean, fold."""
    q = np.empty((k, k))
    ring = np.empty(4 * (k - 1))
    t = np.empty(k)
    for a in range(k):
        t[a] = 2.0 * a / (k - 1) - 1.0
    m = k // 2
    for i in range(cx.size):
        f = lf[i]
        o = 0.5 * (f - 1.0)
        w, h, b0 = lw[i], lh[i], lb[i]
        # grid steps along the major (u) and minor (v) axis, in level pixels
        ux, uy = su[i] * c[i] / f, su[i] * s[i] / f
        vx, vy = -sv[i] * s[i] / f, sv[i] * c[i] / f
        x_c, y_c = (cx[i] - o) / f, (cy[i] - o) / f
        wm, hm = w - 1.0, h - 1.0
        for a in range(k):
            xa, ya = x_c + t[a] * ux, y_c + t[a] * uy
            for bb in range(k):
                x = min(max(xa + t[bb] * vx, 0.0), wm)
                y = min(max(ya + t[bb] * vy, 0.0), hm)
                x0 = min(int(x), w - 2) if w > 1 else 0
                y0 = min(int(y), h - 2) if h > 1 else 0
                fx, fy = x - x0, y - y0
                x1 = min(x0 + 1, w - 1)
                y1 = min(y0 + 1, h - 1)
                r0 = b0 + y0 * w
                r1 = b0 + y1 * w
                top_row = (1.0 - fx) * buf[r0 + x0] + fx * buf[r0 + x1]
                bottom_row = (1.0 - fx) * buf[r1 + x0] + fx * buf[r1 + x1]
                q[a, bb] = (1.0 - fy) * top_row + fy * bottom_row
        r = 0
        for j in range(k):
            ring[r] = q[0, j]
            ring[r + 1] = q[k - 1, j]
            r += 2
        for j in range(1, k - 1):
            ring[r] = q[j, 0]
            ring[r + 1] = q[j, k - 1]
            r += 2
        for j in range(1, r):  # insertion sort of the ring in place (32 values)
            v = ring[j]
            jj = j - 1
            while jj >= 0 and ring[jj] > v:
                ring[jj + 1] = ring[jj]
                jj -= 1
            ring[jj + 1] = v
        base = 0.5 * (ring[r // 2 - 1] + ring[r // 2])
        top = 0.0
        for a in range(m - 1, m + 2):
            for bb in range(m - 1, m + 2):
                top += q[a, bb]
        scale = max(top / 9.0 - base, min_scale)
        for a in range(k):
            for bb in range(k):
                q[a, bb] = min(max((q[a, bb] - base) / scale, -1.5), 1.5)
        du = 0.0
        dv = 0.0
        for a in range(k):
            for bb in range(k):
                du += abs(q[a, bb] - q[k - 1 - a, bb])
                dv += abs(q[a, bb] - q[a, k - 1 - bb])
        col = 0
        for a in range(m, k):
            for bb in range(m, k):
                out[i, col] = 0.25 * (q[a, bb] + q[k - 1 - a, bb] + q[a, k - 1 - bb]
                                      + q[k - 1 - a, k - 1 - bb])
                col += 1
        out[i, col] = du / (k * k)
        out[i, col + 1] = dv / (k * k)

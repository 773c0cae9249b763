"""Rendering of synthetic head-rig images.

An image is built in three layers:

1. Background, ray cast once per camera at the nominal rig pose with the head at rest:
   the shaded, textured skin (ring light at the camera: Lambert + inverse-square
   fall-off, optional specular highlights) and the brim strip. Each frame warps the two
   layers with the affine map that best follows the head slip and rig flex.
2. Marker and brim discs, rendered exactly per frame: every pixel of a disc's bounding
   box is super-sampled, each sample is undistorted (closed form), back-projected onto the
   disc's plane and tested against its radius. This gives the true projected ellipse with
   exact anti-aliasing; the truth ``uv`` is the projection of the disc centre.
3. Sensor: optical blur (Gaussian) and signal-dependent noise.
"""

from __future__ import annotations

import threading

import cv2
import numpy as np
from numpy.typing import NDArray

from carapost.algorithms.camera import camera_centres, pixel_rays, project
from carapost.synth import face, rig, skin_motion
from carapost.synth.scene import SynthScene

__all__ = ["render_frame", "render_background", "prepare"]

_VOID = 9.0          # grey level where no surface is hit (dark background)
_GAIN = 270.0        # grey level of a white, frontal surface 150 mm from its ring light
_SKIN_INK = 0.16     # reflectance of a painted marker relative to skin
_BRIM_INK = 0.08     # reflectance of a printed brim dot relative to the white strip
_SUBSAMPLES = 6      # per pixel axis, for pixels on a disc rim
_LOCK = threading.Lock()


# --------------------------------------------------------------------------- background

def _ray_cast_head(o: NDArray, d: NDArray) -> tuple[NDArray[np.bool_], NDArray[np.float64]]:
    """First intersection of rays with the neutral head; ``(hit, t)`` per ray.

    Marches with steps proportional to the radial gap (the surface's slopes are bounded,
    so 0.35 of the gap never jumps over it), then bisects the bracketing interval.
    """
    n = len(o)
    b = np.einsum("ij,ij->i", o, d)
    c = np.einsum("ij,ij->i", o, o) - face.HEAD_BOUND**2
    disc = b * b - c
    hit = np.zeros(n, dtype=bool)
    t_hit = np.full(n, np.nan)
    active = np.nonzero(disc > 0)[0]
    sq = np.sqrt(np.maximum(disc[active], 0))
    t = -b[active] - sq
    t_end = -b[active] + sq
    prev = t.copy()
    while active.size:
        q = o[active] + t[:, None] * d[active]
        rq = np.linalg.norm(q, axis=1)
        gap = rq - face.head_radius_lut(q / rq[:, None])
        inside = gap < 0
        if inside.any():
            idx = np.nonzero(inside)[0]
            lo, hi = prev[idx].copy(), t[idx].copy()
            oi, di = o[active[idx]], d[active[idx]]
            for _ in range(10):
                mid = 0.5 * (lo + hi)
                qm = oi + mid[:, None] * di
                rm = np.linalg.norm(qm, axis=1)
                ins = rm < face.head_radius_lut(qm / rm[:, None])
                hi = np.where(ins, mid, hi)
                lo = np.where(ins, lo, mid)
            hit[active[idx]] = True
            t_hit[active[idx]] = hi
        step = np.maximum(0.35 * gap, 0.6)
        keep = ~inside & (t + step <= t_end)
        active, prev, t, t_end = active[keep], t[keep], (t + step)[keep], t_end[keep]
    return hit, t_hit


def _ray_cast_brim(o: NDArray, d: NDArray) -> tuple[NDArray[np.bool_], NDArray[np.float64]]:
    """Intersection of rays with the brim band (a cone section), front side only."""
    k = np.tan(np.radians(rig.BRIM_TILT_DEG))
    # x^2 + z^2 = (R0 + k (y - Y0))^2  ->  quadratic in t
    ry = o[:, 1] - rig.BRIM_Y0
    A = d[:, 0] ** 2 + d[:, 2] ** 2 - (k * d[:, 1]) ** 2
    B = 2 * (o[:, 0] * d[:, 0] + o[:, 2] * d[:, 2] - k * d[:, 1] * (rig.BRIM_R0 + k * ry))
    C = o[:, 0] ** 2 + o[:, 2] ** 2 - (rig.BRIM_R0 + k * ry) ** 2
    disc = B * B - 4 * A * C
    ok = disc > 0
    sq = np.sqrt(np.where(ok, disc, 0))
    A_safe = np.where(np.abs(A) > 1e-12, A, 1e-12)
    best = np.full(len(o), np.inf)
    for sgn in (-1.0, 1.0):
        t = (-B + sgn * sq) / (2 * A_safe)
        p = o + t[:, None] * d
        v = (p[:, 1] - rig.BRIM_Y0) / np.cos(np.radians(rig.BRIM_TILT_DEG))
        alpha = np.degrees(np.arctan2(p[:, 0], p[:, 2]))
        good = ok & (t > 0) & (v >= 0) & (v <= rig.BRIM_WIDTH) & \
            (np.abs(alpha) <= rig.BRIM_HALF_ANGLE_DEG) & (p[:, 2] > 0)
        best = np.where(good & (t < best), t, best)
    hit = np.isfinite(best)
    return hit, np.where(hit, best, np.nan)


def _texture(p: NDArray, rng: np.random.Generator) -> NDArray[np.float64]:
    """Band-limited 3D noise of unit-ish amplitude at points ``p`` (N, 3), fixed pattern."""
    out = np.zeros(len(p))
    for lam, amp, n in ((1.6, 0.35, 10), (4.0, 0.45, 8), (25.0, 0.8, 5)):
        k = rng.normal(size=(n, 3))
        k *= (2 * np.pi / lam) / np.linalg.norm(k, axis=1, keepdims=True)
        ph = rng.uniform(0, 2 * np.pi, n)
        out += amp / np.sqrt(n) * np.cos(p @ k.T + ph).sum(axis=1)
    return out


def _soft(x: NDArray, width: float) -> NDArray[np.float64]:
    """Smooth step from 1 (x << 0) to 0 (x >> 0) over ``width``."""
    return 0.5 - 0.5 * np.tanh(x / width)


def _skin_albedo(p: NDArray, tex_rng: np.random.Generator) -> NDArray[np.float64]:
    """Reflectance of the head surface at head-frame points ``p`` (N, 3)."""
    phi, psi = face.dirs_to_angles(p)
    ap = np.abs(phi)
    tex = _texture(p, tex_rng)
    alb = 0.62 * (1.0 + 0.05 * tex)
    # hair above the hairline and over the ears
    hair = 1 - _soft(psi - 52 + 0.004 * phi**2, 1.5)
    hair = np.maximum(hair, (1 - _soft(ap - 70, 2.0)) * (1 - _soft(psi - 15, 3.0)))
    alb = alb * (1 - hair) + hair * 0.14 * (1 + 0.3 * tex)
    # eyebrows
    brow_line = 25.0 - 0.010 * (ap - 17.0) ** 2 + 0.06 * (ap - 17.0)
    brow = _soft(np.abs(psi - brow_line) - 1.6, 0.5) * _soft(np.abs(ap - 20.0) - 12.5, 1.0)
    alb *= 1 - 0.62 * brow * (0.85 + 0.15 * tex)
    # eyes: sclera, iris, pupil, lash line
    de = np.hypot((ap - 21.0) / 7.0, (psi - 15.0) / 2.9)
    eye = _soft(de - 1.0, 0.08)
    diris = np.hypot(ap - 21.0, psi - 15.0)
    sclera = np.where(diris < 2.5, 0.22, 0.78)
    sclera = np.where(diris < 1.0, 0.05, sclera)
    alb = alb * (1 - eye) + eye * sclera
    lash = _soft(np.abs(de - 1.0) - 0.12, 0.05) * (psi > 14.0)
    alb *= 1 - 0.65 * lash
    # lips, mouth line, nostrils
    lips = _soft(np.hypot(phi / 15.5, (psi + 26.0) / 5.5) - 1.0, 0.08)
    alb *= 1 - 0.3 * lips
    mouth = _soft(np.abs(psi + 26.0 - 0.012 * phi**2) - 0.35, 0.15) * _soft(ap - 15.0, 0.6)
    alb *= 1 - 0.8 * mouth
    nostril = _soft(np.hypot((ap - 5.0) / 2.3, (psi + 9.8) / 1.2) - 1.0, 0.1)
    alb *= 1 - 0.85 * nostril
    return alb


def _shade(p: NDArray, n: NDArray, cam: NDArray, albedo: NDArray, highlights: bool,
           d_cam: NDArray, axis: NDArray) -> NDArray[np.float64]:
    """Grey level of surface points lit by a ring light at the camera centre ``cam``."""
    L = cam - p
    dist = np.linalg.norm(L, axis=-1)
    L /= dist[:, None]
    ndl = np.clip(np.einsum("ij,ij->i", n, L), 0.0, 1.0)
    falloff = (150.0 / dist) ** 2
    vignette = np.clip(d_cam @ axis, 0, 1) ** 3
    val = _GAIN * falloff * vignette * albedo * (0.12 + 0.88 * ndl)
    spec = 0.06 * ndl**25
    if highlights:
        spec = spec + 1.8 * ndl**90
    return val + _GAIN * falloff * vignette * spec


def render_background(scene: SynthScene, camera: int
                      ) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Background layers of one camera at the nominal pose, head at rest.

    Returns
    -------
    head : ndarray, shape (H, W, 2), float32
        Premultiplied grey level and coverage of the skin.
    brim : ndarray, shape (H, W, 2), float32
        Premultiplied grey level and coverage of the brim strip.
    """
    w, h = scene.size
    scale = 0.5 if w * h > 400_000 else 1.0
    ws, hs = int(round(w * scale)), int(round(h * scale))
    ii, jj = np.meshgrid((np.arange(ws) + 0.5) / scale - 0.5, (np.arange(hs) + 0.5) / scale - 0.5)
    uv = np.stack([ii.ravel(), jj.ravel()], axis=-1)[:, None, :]
    intr = scene.intrinsics.subset([camera])
    R0, t0 = scene.nominal_R[camera:camera + 1], scene.nominal_t[camera:camera + 1]
    o, d = pixel_rays(uv, R0, t0, intr)
    o, d = np.ascontiguousarray(o[:, 0]), np.ascontiguousarray(d[:, 0])
    cam = camera_centres(R0[0], t0[0])
    axis = R0[0, 2]
    tex_rng = np.random.default_rng(20261122)  # the actor's skin is the same in every take

    layers = []
    S = np.asarray(scene.head_scale, dtype=np.float64)
    # an axis-scaled head: cast in its unscaled frame (unit directions there, so the ray
    # parameter scales by the direction's length)
    ds = d / S
    dl = np.linalg.norm(ds, axis=1)
    hit, t = _ray_cast_head(o / S, ds / dl[:, None])
    t = t / dl
    p = o[hit] + t[hit, None] * d[hit]
    phi, psi = face.dirs_to_angles(p / S)
    n = face.surface_normals(phi, psi) / S
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    val = np.zeros(len(o))
    val[hit] = _shade(p, n, cam, _skin_albedo(p, tex_rng), scene.config.highlights, d[hit], axis)
    layers.append((val, hit))

    hit_b, tb = _ray_cast_brim(o, d)
    pb = o[hit_b] + tb[hit_b, None] * d[hit_b]
    nb = rig.brim_normal(pb)
    v = (pb[:, 1] - rig.BRIM_Y0) / np.cos(np.radians(rig.BRIM_TILT_DEG))
    edge = 1 - 0.5 * (_soft(v - 0.8, 0.3) + _soft(rig.BRIM_WIDTH - 0.8 - v, 0.3))
    alb_b = 0.9 * edge + 0.02 * _texture(pb, np.random.default_rng(7))
    val_b = np.zeros(len(o))
    val_b[hit_b] = _shade(pb, nb, cam, alb_b, False, d[hit_b], axis)
    layers.append((val_b, hit_b))

    out = []
    for val, hit in layers:
        img = np.stack([val.reshape(hs, ws), hit.reshape(hs, ws)], axis=-1).astype(np.float32)
        if scale != 1.0:
            # area-average the coverage so silhouettes come out anti-aliased
            img = cv2.resize(img, (w, h), interpolation=cv2.INTER_LINEAR)
        out.append(np.ascontiguousarray(img))
    return out[0], out[1]


def _fit_affine(src: NDArray, dst: NDArray, weight: NDArray) -> NDArray[np.float64]:
    """Least-squares affine maps src -> dst, batched: (..., K, 2) -> (..., 2, 3)."""
    X = np.concatenate([src, np.ones(src.shape[:-1] + (1,))], axis=-1) * weight[..., None]
    Y = dst * weight[..., None]
    XtX = np.einsum("...ki,...kj->...ij", X, X) + 1e-9 * np.eye(3)
    XtY = np.einsum("...ki,...kj->...ij", X, Y)
    A = np.linalg.solve(XtX, XtY)  # (..., 3, 2)
    return np.swapaxes(A, -1, -2)


def prepare(scene: SynthScene) -> None:
    """Compute and cache what `render_frame` needs (background layers, warps, noise).

    Called automatically by `render_frame`; call it once before rendering from several
    threads to avoid doing the work twice.
    """
    with _LOCK:
        if "warps" in scene.cache:
            return
        F, C = scene.n_frames, scene.n_cameras
        intr = scene.intrinsics
        # head-following warp: a spread of face points, ref = nominal camera, head at rest
        phi, psi = np.meshgrid(np.linspace(-55, 55, 12), np.linspace(-45, 45, 10))
        S = np.asarray(scene.head_scale, dtype=np.float64)
        ph = face.surface_points(phi.ravel(), psi.ravel()) * S
        nh = face.surface_normals(phi.ravel(), psi.ravel()) / S
        ref, _ = project(ph, scene.nominal_R, scene.nominal_t, intr)  # (K, C, 2)
        cen = camera_centres(scene.nominal_R, scene.nominal_t)  # (C, 3)
        vis = np.einsum("kci,ki->kc", cen[None] - ph[:, None], nh) > 0
        ph_f = np.einsum("fcij,kj->fcki", scene.seen_head_R, ph) + scene.seen_head_t[:, :, None]
        cur = np.empty((F, C, len(ph), 2))
        for c in range(C):
            u, _ = project(ph_f[:, c], scene.cam_R[:, c:c + 1], scene.cam_t[:, c:c + 1],
                           intr.subset([c]))
            cur[:, c] = u[:, :, 0]
        refc = np.transpose(ref, (1, 0, 2))[None]  # (1, C, K, 2)
        wt = (vis.T[None] & np.isfinite(cur).all(-1) & np.isfinite(refc).all(-1)).astype(float)
        A_head = _fit_affine(np.nan_to_num(np.broadcast_to(refc, cur.shape)),
                             np.nan_to_num(cur), wt)
        # brim-following warp: brim points under the camera flex only
        pb = rig.brim_point(*[a.ravel() for a in np.meshgrid(np.linspace(-45, 45, 10),
                                                               np.linspace(0, rig.BRIM_WIDTH, 3))])
        refb, _ = project(pb, scene.nominal_R, scene.nominal_t, intr)
        curb, _ = project(pb, scene.cam_R, scene.cam_t, intr)  # (F, K, C, 2)
        refb = np.transpose(refb, (1, 0, 2))[None]
        curb = np.transpose(curb, (0, 2, 1, 3))
        wb = (np.isfinite(curb).all(-1) & np.isfinite(refb).all(-1)).astype(float)
        A_brim = _fit_affine(np.nan_to_num(np.broadcast_to(refb, curb.shape)),
                             np.nan_to_num(curb), wb)
        w, h = scene.size
        rng = np.random.default_rng([int(scene.config.seed), 977])
        noise = [rng.standard_normal((h + 64, w + 64)).astype(np.float32) for _ in range(3)]
        scene.cache["noise"] = noise
        scene.cache["warps"] = (A_head, A_brim)


def _background(scene: SynthScene, camera: int) -> dict:
    key = f"bg{camera}"
    if key not in scene.cache:
        head, brim = render_background(scene, camera)
        # the void is a constant, so the skin needs one channel: value - coverage * void
        layers = {
            "head": np.ascontiguousarray(head[..., 0] - head[..., 1] * np.float32(_VOID)),
            "head_roi": _bbox(head[..., 1] > 0),
            "brim": brim,
            "brim_roi": _bbox(brim[..., 1] > 0),
        }
        with _LOCK:
            scene.cache.setdefault(key, layers)
    return scene.cache[key]


def _disc_ink(ink: NDArray[np.float32], scene: SynthScene, camera: int, R: NDArray, t: NDArray,
              centres: NDArray, normals: NDArray, radii: NDArray,
              strength: float | NDArray, cover: tuple[NDArray, NDArray] | None = None
              ) -> None:
    """Accumulate the coverage of discs into ``ink`` (H, W) in place.

    ``centres``/``normals`` are (S, J, 3): S time samples (motion blur) of J discs in the
    helmet frame; the coverage is averaged over the samples. Pixels whose centre is far
    inside or outside a disc (by more than the pixel's footprint on the disc's plane) are
    classified from that one sample; only pixels near the rim are super-sampled.
    ``strength`` is the ink's opacity, one value or one per disc (J,). ``cover`` is an
    optional occluding edge per disc, ``(directions (J, 3) helmet frame, offsets (J,) mm)``:
    the part of a disc beyond the offset along the direction is not drawn (an offset at
    or above the radius hides nothing).
    """
    S, J, _ = centres.shape
    strength = np.broadcast_to(np.asarray(strength, dtype=np.float64), (J,))
    if J == 0:
        return
    intr = scene.intrinsics
    c = camera
    h_img, w_img = ink.shape
    Pc = np.einsum("ij,sdj->sdi", R, centres) + t  # camera frame (S, J, 3)
    Nc = np.einsum("ij,sdj->sdi", R, normals)
    uv, _ = project(centres.reshape(-1, 3), R[None], t[None], intr.subset([c]))
    uv = uv[:, 0].reshape(S, J, 2)
    ok = np.isfinite(uv).all(-1).all(0) & (Pc[..., 2] > 1).all(0)
    uv = np.where(ok[None, :, None], uv, 0.0)
    cx, cy = uv[..., 0].mean(axis=0), uv[..., 1].mean(axis=0)
    spread = np.max(np.hypot(uv[..., 0] - cx, uv[..., 1] - cy), axis=0)
    zmin = np.where(ok, np.min(Pc[..., 2], axis=0), 1.0)
    rad_px = intr.focal[c] * radii / zmin
    half = np.ceil(rad_px * 1.08 + spread + 1.5)
    # bucket sizes so each bucket is one vectorised evaluation
    half = np.where(ok, np.minimum(4 * np.ceil(half / 4), 64), 0).astype(int)
    f, ppx, ppy = intr.focal[c], intr.principal_point[c, 0], intr.principal_point[c, 1]
    asp, skew = intr.aspect[c], intr.skew[c]
    dcx, dcy = intr.distortion_centre[c]
    k1, k2, k3 = intr.radial[c]

    def rays(xs: NDArray, ys: NDArray) -> tuple[NDArray, NDArray]:
        # raw -> corrected pixels (closed form) -> normalised image coordinates
        dx = xs - dcx
        dy = asp * (ys - dcy)
        r2 = dx * dx + dy * dy
        sc = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        yn = (dcy + sc * dy / asp - ppy) * (asp / f)
        xn = (dcx + sc * dx - ppx - skew * yn) / f
        return xn, yn

    def dist2(xn: NDArray, yn: NDArray, P: NDArray, N: NDArray) -> NDArray:
        # squared distance (mm^2) from the disc centre of the ray's hit on the disc plane
        num = np.einsum("...i,...i->...", N, P)
        den = N[..., 0] * xn + N[..., 1] * yn + N[..., 2]
        lam = num / den
        e = (lam * xn - P[..., 0]) ** 2 + (lam * yn - P[..., 1]) ** 2 + (lam - P[..., 2]) ** 2
        return np.where(lam > 0, e, np.inf)

    if cover is not None:
        cover_c = np.einsum("ij,dj->di", R, np.asarray(cover[0], dtype=np.float64))
        cover_o = np.asarray(cover[1], dtype=np.float64)

    def beyond(xn: NDArray, yn: NDArray, P: NDArray, N: NDArray, U: NDArray) -> NDArray:
        # coordinate (mm) along the cover direction U of the ray's hit on the disc plane
        lam = np.einsum("...i,...i->...", N, P) / (N[..., 0] * xn + N[..., 1] * yn + N[..., 2])
        return (lam * xn - P[..., 0]) * U[..., 0] + (lam * yn - P[..., 1]) * U[..., 1] + \
            (lam - P[..., 2]) * U[..., 2]

    ss = _SUBSAMPLES
    sub = (np.arange(ss) + 0.5) / ss - 0.5
    for hb in np.unique(half[ok]):
        sel = np.nonzero(ok & (half == hb))[0]
        n = 2 * hb + 1
        x0 = np.round(cx[sel]).astype(int) - hb
        y0 = np.round(cy[sel]).astype(int) - hb
        ax = np.arange(n, dtype=np.float64)
        xs = x0[:, None, None] + ax[None, None, :]
        ys = y0[:, None, None] + ax[None, :, None]
        xs, ys = np.broadcast_arrays(xs, ys)
        xn, yn = rays(xs, ys)
        r = radii[sel][:, None, None]
        cov = np.zeros((len(sel), n, n))
        for s in range(S):
            P = Pc[s, sel][:, None, None, :]
            N = Nc[s, sel][:, None, None, :]
            d = np.sqrt(dist2(xn, yn, P, N)) - r
            # footprint of one pixel on the disc plane (mm), with foreshortening
            cosv = np.abs(N[..., 2] + N[..., 0] * xn + N[..., 1] * yn) / np.sqrt(
                1 + xn * xn + yn * yn)
            foot = 0.75 * P[..., 2] / f / np.maximum(cosv, 0.05)
            c_s = (d < 0).astype(np.float64)
            rim = np.abs(d) < foot
            if cover is not None:
                U = cover_c[sel][:, None, None, :]
                o = cover_o[sel][:, None, None]
                g = beyond(xn, yn, P, N, U) - o
                c_s *= g < 0
                rim = (rim | (np.abs(g) < foot)) & (d < foot)
            j, yy, xx = np.nonzero(rim)
            if j.size:
                sxs = xs[j, yy, xx][:, None, None] + sub[None, None, :]
                sys = ys[j, yy, xx][:, None, None] + sub[None, :, None]
                sxn, syn = rays(*np.broadcast_arrays(sxs, sys))
                Pj, Nj = P[j, 0, 0][:, None, None, :], N[j, 0, 0][:, None, None, :]
                inside = dist2(sxn, syn, Pj, Nj) < (radii[sel][j] ** 2)[:, None, None]
                if cover is not None:
                    inside &= beyond(sxn, syn, Pj, Nj, U[j, 0, 0][:, None, None, :]) < \
                        o[j, 0, 0][:, None, None]
                c_s[j, yy, xx] = inside.mean(axis=(1, 2))
            cov += c_s
        cov *= strength[sel][:, None, None] / S
        cov = cov.astype(np.float32)
        for k in range(len(sel)):
            xa, ya = x0[k], y0[k]
            xb, yb = max(xa, 0), max(ya, 0)
            xe, ye = min(xa + n, w_img), min(ya + n, h_img)
            if xe <= xb or ye <= yb:
                continue
            patch = cov[k, yb - ya:ye - ya, xb - xa:xe - xa]
            region = ink[yb:ye, xb:xe]
            region += patch * (1 - region)


def _warp_roi(src: NDArray, A: NDArray, roi: tuple[int, int, int, int], size: tuple[int, int]
              ) -> tuple[NDArray, tuple[int, int, int, int]]:
    """Warp ``src`` by the affine ``A`` (reference -> frame pixels) into the part of the
    output image that can receive content: ``roi`` (x0, y0, x1, y1) grown by the motion."""
    w, h = size
    x0, y0, x1, y1 = roi
    corners = np.array([[x0, y0, 1], [x1, y0, 1], [x0, y1, 1], [x1, y1, 1]], float) @ A.T
    ox0 = int(max(np.floor(corners[:, 0].min()) - 2, 0))
    oy0 = int(max(np.floor(corners[:, 1].min()) - 2, 0))
    ox1 = int(min(np.ceil(corners[:, 0].max()) + 3, w))
    oy1 = int(min(np.ceil(corners[:, 1].max()) + 3, h))
    if ox1 <= ox0 or oy1 <= oy0:
        return np.zeros((0, 0) + src.shape[2:], src.dtype), (0, 0, 0, 0)
    M = A.copy()
    M[:, 2] -= (ox0, oy0)
    out = cv2.warpAffine(src, M, (ox1 - ox0, oy1 - oy0), flags=cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return out, (ox0, oy0, ox1, oy1)


def _bbox(mask: NDArray) -> tuple[int, int, int, int]:
    ys, xs = np.nonzero(mask)
    if xs.size == 0:
        return (0, 0, 0, 0)
    return int(xs.min()), int(ys.min()), int(xs.max()) + 1, int(ys.max()) + 1


def render_frame(scene: SynthScene, frame: int, camera: int, *, sensor: bool = True
                 ) -> NDArray[np.uint8]:
    """Render one grayscale image of the take.

    Parameters
    ----------
    scene : SynthScene
    frame : int
        Frame index in ``0 .. F-1``.
    camera : int
        Camera index in ``0 .. C-1``.
    sensor : bool
        Apply optical blur and sensor noise (False gives the ideal anti-aliased image).

    Returns
    -------
    ndarray, shape (H, W), uint8
        The image; deterministic for the scene's seed.

    Raises
    ------
    IndexError
        If ``frame`` or ``camera`` is out of range.
    """
    if not 0 <= frame < scene.n_frames:
        raise IndexError(f"frame {frame} out of range 0..{scene.n_frames - 1}")
    if not 0 <= camera < scene.n_cameras:
        raise IndexError(f"camera {camera} out of range 0..{scene.n_cameras - 1}")
    prepare(scene)
    bg = _background(scene, camera)
    A_head, A_brim = scene.cache["warps"]
    w, h = scene.size
    img = np.full((h, w), np.float32(_VOID))
    if scene.rest_points3d is not None:   # the skin follows the markers
        hw, (x0, y0, x1, y1) = skin_motion.warp_head(scene, bg["head"], A_head[frame, camera],
                                                     frame, camera, bg["head_roi"])
    else:
        hw, (x0, y0, x1, y1) = _warp_roi(bg["head"], A_head[frame, camera], bg["head_roi"],
                                         (w, h))
    img[y0:y1, x0:x1] += hw
    bw, (x0, y0, x1, y1) = _warp_roi(bg["brim"], A_brim[frame, camera], bg["brim_roi"], (w, h))
    if bw.size:
        sub = img[y0:y1, x0:x1]
        sub *= 1 - bw[..., 1]
        sub += bw[..., 0]

    R, t = scene.cam_R[frame, camera], scene.cam_t[frame, camera]
    ink = np.zeros((h, w), dtype=np.float32)
    vis = scene.visible[frame, :, camera]
    if scene.blur_points is not None:
        cen = scene.blur_points[frame, camera][:, vis]
        nor = scene.blur_normals[frame, camera][:, vis]  # type: ignore[index]
    else:
        cen = scene.seen_points[frame, camera][None, vis]
        nor = scene.seen_normals[frame, camera][None, vis]
    marker_ink = _SKIN_INK if scene.marker_ink is None else scene.marker_ink[vis]
    strength = 1 - marker_ink
    if scene.contrast is not None:   # markers fading over a stretch (missed markers)
        strength = strength * scene.contrast[frame, vis]
    cover = None
    if scene.cover_dir is not None:  # an eyelid fold or a curling lip over part of a disc
        cover = (scene.cover_dir[frame, vis], scene.cover_offset[frame, vis])
    _disc_ink(ink, scene, camera, R, t, cen, nor, scene.marker_radius_mm[vis],
              strength, cover)
    bvis = scene.brim_visible[frame, :, camera]
    _disc_ink(ink, scene, camera, R, t, scene.brim3d[None, bvis], scene.brim_normals[None, bvis],
              scene.brim_radius_mm[bvis], 1 - _BRIM_INK)
    img *= 1 - ink

    if sensor:
        cfg = scene.config
        if cfg.blur > 0:
            img = cv2.GaussianBlur(img, (0, 0), cfg.blur)
        if cfg.noise > 0:
            ss = np.random.SeedSequence([int(cfg.seed), int(frame), int(camera)])
            k, ox, oy = (int(v) for v in np.random.default_rng(ss).integers(0, 64, 3))
            tiles = scene.cache["noise"]
            nz = tiles[k % len(tiles)][oy:oy + h, ox:ox + w]
            # shot noise grows with the signal: sigma = noise at grey 128, noise/2 at black
            sigma = cv2.sqrt(np.maximum(img, 0))
            sigma *= np.float32(0.5 * cfg.noise / np.sqrt(128.0))
            sigma += np.float32(0.5 * cfg.noise)
            img += sigma * nz
    np.clip(img, 0, 255, out=img)
    img += 0.5
    return img.astype(np.uint8)

"""The synthetic head: an analytic star-shaped surface, marker sets and expression fields.

Head-local frame (mm): origin at the centre of the head, **x to the actor's left, y up,
z forward** (out of the face); right-handed. At rest the head frame coincides with the
helmet frame. A surface point is addressed by the spherical angles of its direction from
the origin: azimuth ``phi = atan2(x, z)`` (degrees, + towards the actor's left) and
elevation ``psi = asin(y / |p|)`` (degrees, + up). The surface is
``S(phi, psi) = R(phi, psi) u(phi, psi)`` with ``R`` a piecewise ellipsoid plus smooth
Gaussian bumps (nose, brow ridge, eye sockets, cheekbones, lips, chin).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

# Piecewise ellipsoid semi-axes (mm): one value per sign of the axis.
_AX = 76.0
_AY_UP, _AY_DOWN = 118.0, 128.0
_AZ_FRONT, _AZ_BACK = 94.0, 100.0

# Gaussian bumps on the radius: (phi0, psi0, sigma_phi, sigma_psi, amplitude mm), degrees.
_BUMPS = np.array(
    [
        # nose: bridge -> tip, and the alar wings
        (0.0, 20.0, 3.5, 5.0, 3.0),
        (0.0, 10.0, 4.0, 5.0, 8.0),
        (0.0, 1.0, 4.5, 4.5, 14.0),
        (0.0, -5.0, 5.5, 3.5, 19.0),
        (5.5, -8.0, 3.0, 2.5, 6.0),
        (-5.5, -8.0, 3.0, 2.5, 6.0),
        # eye sockets (negative) and eyeballs
        (21.0, 15.5, 8.0, 5.5, -9.0),
        (-21.0, 15.5, 8.0, 5.5, -9.0),
        (21.0, 15.0, 5.5, 3.2, 6.5),
        (-21.0, 15.0, 5.5, 3.2, 6.5),
        # brow ridge
        (18.0, 24.0, 12.0, 3.5, 4.0),
        (-18.0, 24.0, 12.0, 3.5, 4.0),
        # cheekbones and cheeks
        (37.0, 5.0, 9.0, 7.0, 6.0),
        (-37.0, 5.0, 9.0, 7.0, 6.0),
        (27.0, -12.0, 9.0, 8.0, 3.0),
        (-27.0, -12.0, 9.0, 8.0, 3.0),
        # upper lip / philtrum, lips, mouth corners, chin
        (0.0, -16.0, 8.0, 3.0, 4.0),
        (0.0, -22.0, 9.0, 2.2, 5.0),
        (0.0, -29.5, 8.0, 2.4, 4.5),
        (15.5, -26.0, 2.5, 2.5, -2.5),
        (-15.5, -26.0, 2.5, 2.5, -2.5),
        (0.0, -35.0, 7.0, 2.0, -2.0),
        (0.0, -42.0, 9.0, 5.0, 7.0),
    ]
)

#: Radius of a sphere that contains the whole head surface (mm).
HEAD_BOUND = 140.0


def angles_to_dirs(phi_deg: ArrayLike, psi_deg: ArrayLike) -> NDArray[np.float64]:
    """Unit directions for azimuth/elevation (degrees), shape (..., 3)."""
    phi = np.radians(np.asarray(phi_deg, dtype=np.float64))
    psi = np.radians(np.asarray(psi_deg, dtype=np.float64))
    cp = np.cos(psi)
    return np.stack([cp * np.sin(phi), np.sin(psi), cp * np.cos(phi)], axis=-1)


def dirs_to_angles(u: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Azimuth and elevation (degrees) of (not necessarily unit) vectors ``(..., 3)``."""
    u = np.asarray(u, dtype=np.float64)
    phi = np.degrees(np.arctan2(u[..., 0], u[..., 2]))
    psi = np.degrees(np.arctan2(u[..., 1], np.hypot(u[..., 0], u[..., 2])))
    return phi, psi


def _smoothstep(e0: float, e1: float, x: NDArray[np.float64]) -> NDArray[np.float64]:
    s = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return s * s * (3.0 - 2.0 * s)


def head_radius(u: ArrayLike) -> NDArray[np.float64]:
    """Surface radius (mm) along unit directions ``u`` of shape (..., 3)."""
    u = np.asarray(u, dtype=np.float64)
    ux, uy, uz = u[..., 0], u[..., 1], u[..., 2]
    ay = np.where(uy > 0, _AY_UP, _AY_DOWN)
    az = np.where(uz > 0, _AZ_FRONT, _AZ_BACK)
    # narrower jaw below the cheekbones
    ax = _AX * (1.0 - 0.30 * _smoothstep(-0.1, -0.75, uy))
    r = 1.0 / np.sqrt((ux / ax) ** 2 + (uy / ay) ** 2 + (uz / az) ** 2)
    phi, psi = dirs_to_angles(u)
    front = _smoothstep(-0.2, 0.3, uz)
    bumps = np.zeros_like(r)
    for p0, s0, sp, ss, amp in _BUMPS:
        bumps += amp * np.exp(-0.5 * (((phi - p0) / sp) ** 2 + ((psi - s0) / ss) ** 2))
    return r + front * bumps


def surface_points(phi_deg: ArrayLike, psi_deg: ArrayLike) -> NDArray[np.float64]:
    """Neutral surface points (mm, head frame) at the given angles, shape (..., 3)."""
    u = angles_to_dirs(phi_deg, psi_deg)
    return head_radius(u)[..., None] * u


def surface_normals(phi_deg: ArrayLike, psi_deg: ArrayLike, step: float = 0.02
                    ) -> NDArray[np.float64]:
    """Outward unit normals of the neutral surface at the given angles, shape (..., 3)."""
    phi = np.asarray(phi_deg, dtype=np.float64)
    psi = np.asarray(psi_deg, dtype=np.float64)
    dphi = surface_points(phi + step, psi) - surface_points(phi - step, psi)
    dpsi = surface_points(phi, psi + step) - surface_points(phi, psi - step)
    n = np.cross(dphi, dpsi)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    return n


def inside_head(q: ArrayLike) -> NDArray[np.bool_]:
    """True where head-frame points ``q`` (..., 3) are inside the neutral head."""
    q = np.asarray(q, dtype=np.float64)
    d = np.linalg.norm(q, axis=-1)
    safe = np.where(d > 0, d, 1.0)[..., None]
    return d < head_radius(q / safe)


# --------------------------------------------------------------------------- expressions

#: Expression modes, in the column order of the activation arrays.
MODES = ("jaw_open", "smile", "brow_raise", "pucker", "blink", "lip_curl")

_JAW_PIVOT = np.array([0.0, -8.0, 12.0])
_JAW_MAX_DEG = 15.0


def _gauss(phi: NDArray, psi: NDArray, p0: float, s0: float, sp: float, ss: float) -> NDArray:
    return np.exp(-0.5 * (((phi - p0) / sp) ** 2 + ((psi - s0) / ss) ** 2))


def expression_displacement(p: ArrayLike, act: ArrayLike) -> NDArray[np.float64]:
    """Displacement (mm) of neutral head-frame points under expression activations.

    Parameters
    ----------
    p : array_like, shape (..., N, 3)
        Neutral points (head frame, mm).
    act : array_like, shape (..., len(MODES))
        Activations in [0, 1] of each mode in `MODES`; leading axes broadcast with ``p``'s.

    Returns
    -------
    ndarray, shape (..., N, 3)
        Displacement to add to ``p`` (mm).
    """
    p = np.asarray(p, dtype=np.float64)
    a = np.asarray(act, dtype=np.float64)[..., None, :]  # (..., 1, K)
    phi, psi = dirs_to_angles(p)
    side = np.tanh(phi / 4.0)  # +1 on the actor's left, -1 on the right, 0 at the midline
    out = np.zeros(np.broadcast_shapes(p.shape, a.shape[:-1] + (3,)))

    # jaw: rotation of the lower face about a transverse axis near the TMJ
    w = _smoothstep(-13.0, -30.0, psi) * _smoothstep(75.0, 50.0, np.abs(phi))
    ang = np.radians(_JAW_MAX_DEG) * a[..., 0] * w
    rel = p - _JAW_PIVOT
    c, s = np.cos(ang), np.sin(ang)
    out[..., 1] += rel[..., 1] * (c - 1.0) - rel[..., 2] * s
    out[..., 2] += rel[..., 1] * s + rel[..., 2] * (c - 1.0)

    # smile: mouth corners up/out/back, cheeks up, lower lids up a little
    g = 7.0 * (_gauss(phi, psi, 16.0, -26.0, 9.0, 7.0) + _gauss(phi, psi, -16.0, -26.0, 9.0, 7.0))
    gc = 3.0 * (_gauss(phi, psi, 30.0, -6.0, 10.0, 8.0) + _gauss(phi, psi, -30.0, -6.0, 10.0, 8.0))
    out[..., 0] += a[..., 1] * g * 0.55 * side
    out[..., 1] += a[..., 1] * (0.75 * g + gc)
    out[..., 2] += a[..., 1] * (-0.35 * g)

    # brow raise: brows and forehead up
    g = 6.0 * _gauss(phi, psi, 0.0, 27.0, 30.0, 8.0) + 2.0 * _gauss(phi, psi, 0.0, 19.5, 28.0, 2.5)
    out[..., 1] += a[..., 2] * g
    out[..., 2] += a[..., 2] * (-0.15 * g)

    # pucker: lips forward and towards the midline
    g = _gauss(phi, psi, 0.0, -26.0, 12.0, 6.0)
    out[..., 0] += a[..., 3] * g * (-0.35 * p[..., 0])
    out[..., 2] += a[..., 3] * g * 8.0

    # blink: upper lids down (fully closed at 1), lower lids up a little
    gu = _gauss(phi, psi, 21.0, 19.5, 6.0, 2.0) + _gauss(phi, psi, -21.0, 19.5, 6.0, 2.0)
    gl = _gauss(phi, psi, 21.0, 10.5, 6.0, 2.0) + _gauss(phi, psi, -21.0, 10.5, 6.0, 2.0)
    out[..., 1] += a[..., 4] * (-7.0 * gu + 1.0 * gl)
    out[..., 2] += a[..., 4] * (1.5 * gu)

    # lip curl: upper lip up and out, lower lip down and out
    gu = _gauss(phi, psi, 0.0, -21.5, 10.0, 3.0)
    gl = _gauss(phi, psi, 0.0, -30.5, 10.0, 3.0)
    out[..., 1] += a[..., 5] * (2.0 * gu - 1.5 * gl)
    out[..., 2] += a[..., 5] * (4.0 * gu + 3.5 * gl)
    return out


def deform(p: ArrayLike, act: ArrayLike) -> NDArray[np.float64]:
    """Neutral points displaced by the expression: ``p + expression_displacement(p, act)``."""
    p = np.asarray(p, dtype=np.float64)
    return p + expression_displacement(p, act)


def inside_deformed_head(q: ArrayLike, act: ArrayLike) -> NDArray[np.bool_]:
    """Inside test against the expression-deformed head (two fixed-point inversions)."""
    q = np.asarray(q, dtype=np.float64)
    p = q
    for _ in range(2):
        p = q - expression_displacement(p, act)
    return inside_head(p)


# --------------------------------------------------------------------------- marker sets

@dataclass(frozen=True)
class MarkerSpec:
    """One face marker: anatomical label, surface angles (deg), disc radius (mm)."""

    label: str
    phi: float
    psi: float
    radius: float
    eyelid: bool = False
    level: int = 0


MARKER_SETS = {"sparse35": 0, "standard": 1, "dense156": 2}

# (label stem, phi, psi, radius, eyelid, level); "_L" entries are mirrored to "_R".
_CENTRE = [
    ("Forehead_C", 0, 38, 2.0, False, 0),
    ("Nose_Bridge", 0, 17, 1.5, False, 0),
    ("Nose_Tip", 0, -4, 1.5, False, 0),
    ("Upper_Lip_C", 0, -21.5, 1.25, False, 0),
    ("Lower_Lip_C", 0, -30.5, 1.25, False, 0),
    ("Chin_Crease", 0, -36, 1.5, False, 0),
    ("Chin_C", 0, -43, 2.0, False, 0),
    ("Forehead_C_Lo", 0, 30, 2.0, False, 1),
    ("Nose_Mid", 0, 6, 1.5, False, 1),
    ("Chin_Lo", 0, -50, 2.0, False, 1),
    ("Philtrum", 0, -15.5, 1.0, False, 1),
    ("Forehead_C_Hi", 0, 45, 2.0, False, 2),
    ("Nose_Bridge_Hi", 0, 23, 1.25, False, 2),
    ("Chin_Mid", 0, -39.5, 1.5, False, 2),
]
_LEFT = [
    ("Brow_Inner", 9, 26, 1.5, False, 0),
    ("Brow_Mid", 20, 28, 1.5, False, 0),
    ("Brow_Outer", 31, 25, 1.5, False, 0),
    ("Forehead", 17, 39, 2.0, False, 0),
    ("Upper_Lid", 21, 19.5, 1.0, True, 0),
    ("Lower_Lid", 21, 10.5, 1.0, False, 0),
    ("Cheekbone", 35, 5, 1.75, False, 0),
    ("Cheek", 27, -10, 1.75, False, 0),
    ("Nostril", 7.5, -8.5, 1.25, False, 0),
    ("Nasolabial", 13, -15, 1.5, False, 0),
    ("Mouth_Corner", 15.5, -26, 1.25, False, 0),
    ("Upper_Lip", 8, -22, 1.25, False, 0),
    ("Lower_Lip", 8, -30, 1.25, False, 0),
    ("Jaw", 32, -36, 2.0, False, 0),
    ("Forehead_Outer", 32, 37, 2.0, False, 1),
    ("Forehead_Hi", 10, 45, 2.0, False, 1),
    ("Brow_Inner_Hi", 10, 33, 1.5, False, 1),
    ("Brow_Outer_Hi", 28, 32, 1.5, False, 1),
    ("Temple", 42, 22, 1.75, False, 1),
    ("Eye_Outer", 31, 13, 1.0, False, 1),
    ("Eye_Inner", 11.5, 14, 1.0, False, 1),
    ("Upper_Lid_Inner", 16, 19, 1.0, True, 1),
    ("Cheekbone_Outer", 45, 4, 1.75, False, 1),
    ("Cheek_Hi", 24, 1, 1.5, False, 1),
    ("Cheek_Mid", 36, -8, 1.75, False, 1),
    ("Cheek_Lo", 32, -20, 1.75, False, 1),
    ("Cheek_Outer", 47, -12, 2.0, False, 1),
    ("Nose_Side", 6, 5, 1.25, False, 1),
    ("Nose_Wing", 9, -3.5, 1.25, False, 1),
    ("Nasolabial_Lo", 18, -20, 1.5, False, 1),
    ("Upper_Lip_Outer", 12.5, -23.5, 1.0, False, 1),
    ("Lower_Lip_Outer", 12, -29, 1.0, False, 1),
    ("Mouth_Outer", 21, -27, 1.5, False, 1),
    ("Jaw_Front", 20, -41, 2.0, False, 1),
    ("Jaw_Back", 45, -30, 2.0, False, 1),
    ("Chin", 9, -44, 2.0, False, 1),
    ("Chin_Lo", 10, -50, 2.0, False, 1),
    ("Jaw_Lo", 30, -46, 2.0, False, 1),
    ("Cheek_Jaw", 41, -20, 2.0, False, 1),
]


def _region(phi: float, psi: float) -> str:
    if psi > 30:
        return "Forehead"
    if psi > 21:
        return "Brow"
    if psi > 8 and phi > 32:
        return "Temple"
    if psi > -17:
        return "Cheek"
    if psi > -33 and phi < 24:
        return "Mouth"
    return "Jaw"


def _dense_fill(existing: list[tuple[float, float]], count: int) -> list[tuple[str, float, float]]:
    """Farthest-point fill of the left half-face, avoiding the eyes, nostrils and lips."""
    ph, ps = np.meshgrid(np.arange(4.0, 50.0, 1.0), np.arange(-50.0, 46.0, 1.0))
    ph, ps = ph.ravel(), ps.ravel()
    eye = ((ph - 21) / 8.5) ** 2 + ((ps - 15) / 4.0) ** 2 < 1.0
    nose = (ph < 9) & (ps > -12) & (ps < 22)
    lips = (ph < 14) & (ps > -32) & (ps < -19)
    side = ((ph > 46) & (ps < -36))
    keep = ~(eye | nose | lips | side)
    ph, ps = ph[keep], ps[keep]
    pts = np.array(existing, dtype=np.float64)
    d = np.min(np.hypot(ph[:, None] - pts[:, 0], ps[:, None] - pts[:, 1]), axis=1)
    chosen: list[tuple[str, float, float]] = []
    counters: dict[str, int] = {}
    for _ in range(count):
        i = int(np.argmax(d))
        p, s = float(ph[i]), float(ps[i])
        region = _region(p, s)
        counters[region] = counters.get(region, 0) + 1
        chosen.append((f"{region}_Fill{counters[region]:02d}", p, s))
        d = np.minimum(d, np.hypot(ph - p, ps - s))
    return chosen


def marker_set(name: str) -> list[MarkerSpec]:
    """The markers of a named set (``"sparse35"``, ``"standard"`` or ``"dense156"``).

    Sets are nested: every label of ``sparse35`` is in ``standard`` at the same place and
    every label of ``standard`` is in ``dense156``.

    Raises
    ------
    ValueError
        For an unknown set name.
    """
    if name not in MARKER_SETS:
        raise ValueError(f"markers must be one of {sorted(MARKER_SETS)}, got {name!r}")
    level = MARKER_SETS[name]
    out: list[MarkerSpec] = []
    for lab, phi, psi, r, lid, lev in _CENTRE:
        if lev <= level:
            out.append(MarkerSpec(lab, phi, psi, r, lid, lev))
    left = [m for m in _LEFT if m[5] <= level]
    if level >= 2:
        existing = [(m[1], m[2]) for m in _LEFT] + [(0.0, m[2]) for m in _CENTRE]
        n_fill = (156 - len([m for m in _CENTRE if m[5] <= level])) // 2 - len(left)
        left = left + [(lab, p, s, 1.25, False, 2) for lab, p, s in _dense_fill(existing, n_fill)]
    for lab, phi, psi, r, lid, lev in left:
        out.append(MarkerSpec(f"{lab}_L", phi, psi, r, lid, lev))
        out.append(MarkerSpec(f"{lab}_R", -phi, psi, r, lid, lev))
    return out


_LUT: dict[str, NDArray[np.float32]] = {}
_LUT_STEP = 0.4  # degrees


def head_radius_lut(u: ArrayLike) -> NDArray[np.float32]:
    """`head_radius` from a tabulated (phi, psi) grid with bilinear interpolation.

    Several times faster than the analytic form and within ~0.05 mm of it; used to ray
    cast the background images (the truth always uses the analytic surface).
    """
    if "r" not in _LUT:
        phi = np.arange(-180.0, 180.0 + _LUT_STEP / 2, _LUT_STEP)
        psi = np.arange(-90.0, 90.0 + _LUT_STEP / 2, _LUT_STEP)
        pp, ss = np.meshgrid(phi, psi)
        _LUT["r"] = head_radius(angles_to_dirs(pp, ss)).astype(np.float32)
    import cv2  # local: keep the geometry importable without OpenCV

    u = np.asarray(u)
    phi = np.degrees(np.arctan2(u[..., 0], u[..., 2]))
    psi = np.degrees(np.arctan2(u[..., 1], np.hypot(u[..., 0], u[..., 2])))
    n = phi.size
    width = 1024  # remap wants maps of fewer than 32767 rows
    rows = max(1, -(-n // width))
    mx = np.zeros(rows * width, np.float32)
    my = np.zeros(rows * width, np.float32)
    mx[:n] = (phi.ravel() + 180.0) / _LUT_STEP
    my[:n] = (psi.ravel() + 90.0) / _LUT_STEP
    out = cv2.remap(_LUT["r"], mx.reshape(rows, width), my.reshape(rows, width),
                    cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return out.ravel()[:n].reshape(phi.shape)


def poisson_marker_set(count: int, rng: np.random.Generator,
                       radius_mm: tuple[float, float] = (1.2, 2.0)) -> list[MarkerSpec]:
    """``count`` markers placed by Poisson-disk sampling over the front of the face.

    Another marker layout than the anatomical sets: blue-noise positions with no
    symmetry and no anatomical labels (``P001``...), away from the eyes, nostrils and the
    lip line, as a painter with a stencil-free brush would place them. Samples come from
    :class:`scipy.stats.qmc.PoissonDisk` on the (azimuth, elevation) rectangle, the
    radius shrunk until enough samples fall outside the excluded areas; ``count`` of
    them are kept at random.

    Parameters
    ----------
    count : int
        Number of markers (>= 1).
    rng : numpy.random.Generator
    radius_mm : (float, float)
        Range of the disc radii (mm), drawn uniformly per marker.

    Returns
    -------
    list of MarkerSpec
    """
    from scipy.stats import qmc

    lo, hi = np.array([-50.0, -50.0]), np.array([50.0, 45.0])
    r = 0.75 / np.sqrt(count)  # about 1.2 count samples on the rectangle
    for _ in range(40):
        seed = int(rng.integers(2**31))
        pts = qmc.scale(qmc.PoissonDisk(2, radius=r, seed=seed).fill_space(), lo, hi)
        ph, ps = pts[:, 0], pts[:, 1]
        a = np.abs(ph)
        eye = ((a - 21) / 8.5) ** 2 + ((ps - 15) / 4.0) ** 2 < 1.0
        nose = (a < 7) & (ps > -12) & (ps < 22)
        lips = (a < 14) & (ps > -28) & (ps < -24)
        side = (a > 46) & (ps < -36)
        keep = ~(eye | nose | lips | side)
        if keep.sum() >= count:
            ph, ps = ph[keep], ps[keep]
            break
        r *= 0.92
    else:  # pragma: no cover - the radius shrinks geometrically
        raise ValueError(f"cannot place {count} markers on the face")
    pick = np.sort(rng.choice(len(ph), size=count, replace=False))
    radii = rng.uniform(radius_mm[0], radius_mm[1], count)
    return [MarkerSpec(f"P{i + 1:03d}", float(ph[j]), float(ps[j]), float(rad))
            for i, (j, rad) in enumerate(zip(pick, radii, strict=True))]

"""Small synthetic face-image renderer with exact marker truth, for the blob detector.

This is the blob detector's own ground-truth generator (used by its training script,
tests and benchmark; moved here from ``carapost.algorithms._blob_synth``: the product
packages never import it). It draws a shaded, textured skin-coloured face with facial
features that look a bit like blobs (eyebrows, eyes, nostrils, mouth, hair, pores), a
calibration brim strip with black dots, and painted markers as exactly anti-aliased
ellipses (supersampled 8x8 per pixel). The truth centre of every marker is its
geometric centre in the OpenCV pixel-centre convention.

Not part of the product API: the rest of ``carapost.synth`` is the project's general
take generator.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

REGION_BACKGROUND = 0
REGION_FACE = 1
REGION_BRIM = 2
REGION_NAMES = {REGION_BACKGROUND: "background", REGION_FACE: "face", REGION_BRIM: "brim"}

PRESETS = {
    # name: (number of face markers, marker radius range px, minimum gap px)
    "standard": (100, (4.5, 9.0), 10.0),
    "dense156": (156, (3.5, 7.0), 6.0),
    "speech": (100, (4.5, 8.5), 8.0),
    "fast": (100, (4.5, 9.0), 10.0),
}


@dataclass
class SynthImage:
    """One rendered image and its truth.

    Attributes
    ----------
    image : ndarray [H, W] uint8
    centre : ndarray [N, 2] float64, truth marker centres (px, pixel-centre convention)
    axes : ndarray [N, 2] float64, semi-axes (major first), px, before blur
    angle : ndarray [N] float64, major-axis angle, radians
    colour : ndarray [N] int8, 0 black / 1 white
    region : ndarray [N] uint8, REGION_FACE or REGION_BRIM
    merged : ndarray [N] bool, marker touches or overlaps another marker
    visible : ndarray [N] bool, marker differs from its surround (False: washed out)
    region_map : ndarray [H, W] uint8, region label of every pixel
    blurred : bool, motion blur was applied
    """

    image: np.ndarray
    centre: np.ndarray
    axes: np.ndarray
    angle: np.ndarray
    colour: np.ndarray
    region: np.ndarray
    merged: np.ndarray
    visible: np.ndarray
    region_map: np.ndarray
    blurred: bool


def ellipse_coverage(
    cx: float, cy: float, a: float, b: float, theta: float, ss: int = 8
) -> tuple[int, int, np.ndarray]:
    """Exact-ish pixel coverage of an ellipse by ``ss x ss`` supersampling.

    Parameters
    ----------
    cx, cy : float
        Centre (px, pixel-centre convention).
    a, b : float
        Semi-axes (px).
    theta : float
        Angle of the ``a`` axis from +x towards +y (rad).
    ss : int
        Sub-samples per pixel along each axis.

    Returns
    -------
    x0, y0 : int
        Top-left pixel of the patch.
    cov : ndarray [n, n] float
        Covered fraction of each pixel of the patch (0-1).

    Examples
    --------
    >>> x0, y0, cov = ellipse_coverage(10.0, 10.0, 3.0, 3.0, 0.0)
    >>> (x0, y0), round(float(cov.sum()), 1)  # ~ pi r^2
    ((5, 5), 28.2)
    """
    ext = int(np.ceil(a)) + 2
    x0 = int(np.floor(cx)) - ext
    y0 = int(np.floor(cy)) - ext
    n = 2 * ext + 2
    # Sub-sample offsets inside a pixel whose centre is at the integer coordinate.
    sub = (np.arange(ss) + 0.5) / ss - 0.5
    xs = (x0 + np.arange(n))[:, None] + sub[None, :]
    ys = (y0 + np.arange(n))[:, None] + sub[None, :]
    dx = xs.reshape(1, -1) - cx
    dy = ys.reshape(-1, 1) - cy
    c, s = np.cos(theta), np.sin(theta)
    u = (dx * c + dy * s) / a
    v = (-dx * s + dy * c) / b
    inside = (u * u + v * v <= 1.0).astype(np.float32)
    cov = inside.reshape(n, ss, n, ss).mean(axis=(1, 3))
    return x0, y0, cov


def paint(img: np.ndarray, x0: int, y0: int, cov: np.ndarray, target: np.ndarray | float,
          alpha: float = 1.0) -> None:
    """Blend ``target`` into ``img`` with weight ``alpha * cov`` (clipped to the image).

    ``img`` is a float image [H, W] changed in place; ``(x0, y0, cov)`` as returned by
    :func:`ellipse_coverage`; ``target`` a grey level or an array shaped like ``cov``.
    """
    h, w = img.shape
    n0, n1 = cov.shape
    ya, yb = max(0, y0), min(h, y0 + n0)
    xa, xb = max(0, x0), min(w, x0 + n1)
    if ya >= yb or xa >= xb:
        return
    c = alpha * cov[ya - y0 : yb - y0, xa - x0 : xb - x0]
    patch = img[ya:yb, xa:xb]
    if isinstance(target, np.ndarray):
        target = target[ya - y0 : yb - y0, xa - x0 : xb - x0]
    img[ya:yb, xa:xb] = patch * (1.0 - c) + target * c


def _soft_ellipse(shape: tuple[int, int], cx: float, cy: float, a: float, b: float,
                  theta: float, soft: float) -> np.ndarray:
    """Float mask in 0-1 of an ellipse with a blurred edge (``soft`` = blur sigma px)."""
    mask = np.zeros(shape, np.float32)
    cv2.ellipse(mask, ((cx, cy), (2 * a, 2 * b), np.degrees(theta)), 1.0, -1, cv2.LINE_AA)
    if soft > 0:
        mask = cv2.GaussianBlur(mask, (0, 0), soft)
    return mask


def render_face(
    rng: np.random.Generator,
    *,
    preset: str = "standard",
    size: tuple[int, int] = (720, 1280),
    motion_blur: bool | None = None,
    noise: float | None = None,
    merged: bool = False,
    highlights: bool = False,
    dark: bool = False,
    white: bool = False,
    psf_sigma: float = 0.5,
) -> SynthImage:
    """Render one synthetic head-camera face image with painted markers and truth.

    Parameters
    ----------
    rng : numpy Generator
    preset : {"standard", "dense156", "speech", "fast"}
        Marker count / size layout; "fast" turns motion blur on by default.
    size : (H, W)
    motion_blur : bool, optional
        Linear motion blur of 3-9 px in a random direction over the whole image.
    noise : float, optional
        Gaussian noise sigma in grey levels (default random in 1-3.5).
    merged : bool
        Add about ten touching or overlapping marker pairs (flagged ``merged``).
    highlights : bool
        Add saturated (255) specular highlight patches on the skin.
    dark : bool
        Very dark exposure (skin around 15-35 grey levels).
    white : bool
        White markers (brighter than the skin) instead of black ones.
    psf_sigma : float
        Camera blur sigma in px applied to the whole image.
    """
    if preset not in PRESETS:
        raise ValueError(f"unknown preset {preset!r}; choose one of {sorted(PRESETS)}")
    n_markers, (r_lo, r_hi), gap = PRESETS[preset]
    if motion_blur is None:
        motion_blur = preset == "fast"
    if noise is None:
        noise = float(rng.uniform(1.0, 3.5))
    h, w = size
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)

    # Background: a dim room with a gradient and coarse texture.
    bg_level = rng.uniform(25, 70)
    tex = cv2.GaussianBlur(rng.standard_normal((h, w)).astype(np.float32), (0, 0), 12) * 40
    img = bg_level + tex + (xx / w - 0.5) * rng.uniform(-30, 30)

    # Face: ellipse, shaded like a lit ellipsoid, with low-frequency skin texture.
    fcx, fcy = w * 0.5 + rng.uniform(-60, 60), h * 0.58 + rng.uniform(-20, 20)
    fa, fb = w * rng.uniform(0.28, 0.34), h * rng.uniform(0.62, 0.7)
    u, v = (xx - fcx) / fa, (yy - fcy) / fb
    rho2 = u * u + v * v
    face = _soft_ellipse((h, w), fcx, fcy, fa, fb, 0.0, 3.0)
    skin = rng.uniform(100, 215)
    nz = np.sqrt(np.clip(1 - rho2, 0, 1))
    light = np.array([rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.2), 1.0])
    light /= np.linalg.norm(light)
    lambert = np.clip(u * light[0] * 0.8 + v * light[1] * 0.8 + nz * light[2], 0, 1)
    shade = 0.35 + 0.65 * lambert
    stex = cv2.GaussianBlur(rng.standard_normal((h, w)).astype(np.float32), (0, 0), 6) * 0.25
    fine = cv2.GaussianBlur(rng.standard_normal((h, w)).astype(np.float32), (0, 0), 1.2) * 0.04
    skin_img = skin * shade * (1 + stex * 0.2 + fine)
    img = img * (1 - face) + skin_img * face

    occupied = np.zeros((h, w), np.uint8)  # where markers must not go (features)

    def feature(cx, cy, a, b, th, soft, depth):
        m = _soft_ellipse((h, w), cx, cy, a, b, th, soft)
        nonlocal img
        img = img * (1 - depth * m)
        cv2.ellipse(occupied, ((cx, cy), (2 * a + 30, 2 * b + 30), np.degrees(th)), 255, -1)

    # Hair above the forehead.
    hair_y = fcy - fb * rng.uniform(0.7, 0.8)
    hair = np.clip((hair_y - yy) / 6.0 + 0.5, 0, 1) * face
    img = img * (1 - 0.75 * hair)
    occupied[: int(hair_y) + 15] = 255
    # Eyebrows, eyes, nostrils, mouth.
    eye_y = fcy - fb * 0.3
    for side in (-1, 1):
        ex = fcx + side * fa * 0.38
        feature(ex, eye_y - 45, 65, 11, side * 0.12, 3.0, 0.6)
        feature(ex, eye_y, 48, 17, 0.0, 3.0, 0.55)
        feature(fcx + side * 22, fcy + fb * 0.08, 16, 8, side * 0.4, 4.0, 0.55)
    feature(fcx, fcy + fb * 0.32, 80, 7 + rng.uniform(0, 20), 0.0, 3.0, 0.6)
    # Pores / freckles: small, low-contrast dark spots.
    n_pores = 400
    px = rng.uniform(fcx - fa, fcx + fa, n_pores)
    py = rng.uniform(fcy - fb, fcy + fb, n_pores)
    for x, y in zip(px, py, strict=True):
        r = rng.uniform(0.6, 2.0)
        x0, y0, cov = ellipse_coverage(x, y, r, r * rng.uniform(0.6, 1), rng.uniform(0, np.pi))
        paint(img, x0, y0, cov, img[int(min(max(y, 0), h - 1)), int(min(max(x, 0), w - 1))]
               * 0.85, alpha=rng.uniform(0.2, 0.6))

    region_map = np.where(face > 0.5, REGION_FACE, REGION_BACKGROUND).astype(np.uint8)

    # Brim: a white strip at the top with a row of black dots.
    brim_top = rng.uniform(8, 30)
    brim_h = rng.uniform(55, 75)
    brim = ((yy >= brim_top) & (yy <= brim_top + brim_h)).astype(np.float32)
    brim = cv2.GaussianBlur(brim, (0, 0), 1.0)
    brim_level = rng.uniform(170, 235)
    img = img * (1 - brim) + brim_level * (1 + (xx / w - 0.5) * 0.2) * brim
    region_map[brim > 0.5] = REGION_BRIM

    centres, axes, angles, regions, merged_flags = [], [], [], [], []

    # Brim dots (always black).
    step = rng.uniform(55, 75)
    for bx in np.arange(rng.uniform(20, 50), w - 20, step):
        by = brim_top + brim_h / 2 + rng.uniform(-3, 3)
        r = rng.uniform(6.0, 8.0)
        centres.append((bx + rng.uniform(-0.5, 0.5), by))
        axes.append((r, r * rng.uniform(0.6, 0.95)))
        angles.append(rng.uniform(-0.2, 0.2))
        regions.append(REGION_BRIM)
        merged_flags.append(False)

    # Face markers: rejection sampling inside the face, away from features.
    face_c, face_a, face_ang = [], [], []
    tries = 0
    if preset == "speech":
        area = (fcx - fa * 0.75, fcx + fa * 0.75, fcy - fb * 0.15, fcy + fb * 0.85)
    else:
        area = (fcx - fa * 0.9, fcx + fa * 0.9, fcy - fb * 0.6, fcy + fb * 0.9)
    pts = np.zeros((0, 2))
    rads = np.zeros(0)
    while len(face_c) < n_markers and tries < 20000:
        tries += 1
        x = rng.uniform(area[0], area[1])
        y = rng.uniform(area[2], area[3])
        uu, vv = (x - fcx) / fa, (y - fcy) / fb
        rr2 = uu * uu + vv * vv
        if rr2 > 0.85 or y < brim_top + brim_h + 20 or not (20 < x < w - 20 and 20 < y < h - 20):
            continue
        if occupied[int(y), int(x)]:
            continue
        r = rng.uniform(r_lo, r_hi)
        if len(pts) and np.min(np.hypot(*(pts - (x, y)).T) - rads) < r + gap:
            continue
        ratio = max(0.35, np.sqrt(1 - rr2) * rng.uniform(0.9, 1.0))
        ang = np.arctan2(vv * fa, uu * fb) + np.pi / 2  # tangent to the face outline
        face_c.append((x, y))
        face_a.append((r, r * ratio))
        face_ang.append(ang)
        pts = np.vstack([pts, (x, y)])
        rads = np.append(rads, r)
    for c, ax, an in zip(face_c, face_a, face_ang, strict=True):
        centres.append(c)
        axes.append(ax)
        angles.append(an)
        regions.append(REGION_FACE)
        merged_flags.append(False)

    if merged:
        # Touching / overlapping pairs: move a partner next to ten random face markers.
        face_idx = [i for i, g in enumerate(regions) if g == REGION_FACE]
        for i in rng.choice(face_idx, size=min(10, len(face_idx)), replace=False):
            r1 = axes[i][0]
            r2 = rng.uniform(r_lo, r_hi)
            d = (r1 + r2) * rng.uniform(0.8, 1.02)
            phi = rng.uniform(0, 2 * np.pi)
            c2 = (centres[i][0] + d * np.cos(phi), centres[i][1] + d * np.sin(phi))
            centres.append(c2)
            axes.append((r2, r2 * rng.uniform(0.8, 1.0)))
            angles.append(rng.uniform(0, np.pi))
            regions.append(REGION_FACE)
            merged_flags[i] = True
            merged_flags.append(True)

    if highlights:
        # Saturated specular patches on forehead, nose and cheeks (drawn under the markers
        # only where no marker is; markers are matte paint).
        for _ in range(int(rng.integers(2, 5))):
            hx = fcx + rng.uniform(-0.6, 0.6) * fa
            hy = fcy + rng.uniform(-0.6, 0.5) * fb
            ha = rng.uniform(8, 35)
            m = _soft_ellipse((h, w), hx, hy, ha, ha * rng.uniform(0.4, 1), rng.uniform(0, 3),
                              ha * 0.3)
            img = img + m * 400.0

    base = img.copy()
    marker_refl = rng.uniform(0.08, 0.3)
    colours, visible = [], []
    for (cx, cy), (a, b), th, reg in zip(centres, axes, angles, regions, strict=True):
        x0, y0, cov = ellipse_coverage(cx, cy, a, b, th)
        yc = int(np.clip(cy, 0, h - 1))
        xc = int(np.clip(cx, 0, w - 1))
        local = min(base[yc, xc], 255.0)
        is_white = white and reg == REGION_FACE  # the brim always has black dots
        if is_white:
            target = min(local * 1.6 + 50, 250.0)
        else:
            target = local * marker_refl
        colours.append(1 if is_white else 0)
        # A white marker on a saturated highlight cannot be seen at all.
        visible.append(abs(target - local) >= 20.0)
        paint(img, x0, y0, cov, target)

    if psf_sigma > 0:
        img = cv2.GaussianBlur(img, (0, 0), psf_sigma)
    if motion_blur:
        length = int(rng.integers(3, 10))
        k = np.zeros((length * 2 + 1, length * 2 + 1), np.float32)
        ang = rng.uniform(0, np.pi)
        cv2.line(k, (length - int(round(length * np.cos(ang) / 2)),
                     length - int(round(length * np.sin(ang) / 2))),
                 (length + int(round(length * np.cos(ang) / 2)),
                  length + int(round(length * np.sin(ang) / 2))), 1.0, 1, cv2.LINE_AA)
        k = (k + k[::-1, ::-1]) / (2 * k.sum())  # exactly point-symmetric: no centre shift
        img = cv2.filter2D(img, -1, k)
    if dark:
        img = img * rng.uniform(0.12, 0.2)
        noise = noise * 0.4
    img = img + rng.standard_normal((h, w)).astype(np.float32) * noise
    image = np.clip(np.rint(img), 0, 255).astype(np.uint8)

    n = len(centres)
    return SynthImage(
        image=image,
        centre=np.asarray(centres, np.float64).reshape(n, 2),
        axes=np.asarray(axes, np.float64).reshape(n, 2),
        angle=np.asarray(angles, np.float64).reshape(n),
        colour=np.asarray(colours, np.int8).reshape(n),
        region=np.asarray(regions, np.uint8),
        merged=np.asarray(merged_flags, bool),
        visible=np.asarray(visible, bool).reshape(n),
        region_map=region_map,
        blurred=bool(motion_blur),
    )


def match_to_truth(
    det_centre: np.ndarray, truth_centre: np.ndarray, truth_minor: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """One-to-one match of detections to truth markers by distance.

    A detection matches a marker when it is within ``clip(0.5 * minor semi-axis, 1, 3)``
    px of its centre; each marker keeps only its closest detection
    (:func:`match_nearest` with that tolerance).

    Returns
    -------
    det_to_truth : ndarray [N] int64, truth index or -1
    truth_to_det : ndarray [M] int64, detection index or -1
    """
    return match_nearest(det_centre, truth_centre, np.clip(0.5 * truth_minor, 1.0, 3.0))


def match_nearest(det: np.ndarray, truth: np.ndarray, tol: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """One-to-one nearest matching within a per-truth tolerance (closest pairs first).

    Parameters
    ----------
    det : ndarray [N, 2]
        Detected centres (px).
    truth : ndarray [M, 2]
        Truth centres (px).
    tol : ndarray [M]
        Largest distance (px) at which a detection matches each truth centre.

    Returns
    -------
    det_to_truth : ndarray [N] int64, truth index or -1
    truth_to_det : ndarray [M] int64, detection index or -1

    Examples
    --------
    >>> import numpy as np
    >>> d2t, t2d = match_nearest(np.array([[0.0, 0.0], [5.0, 5.0]]),
    ...                          np.array([[0.5, 0.0], [9.0, 9.0]]), np.array([1.0, 1.0]))
    >>> d2t.tolist(), t2d.tolist()
    ([0, -1], [0, -1])
    """
    d2t = np.full(len(det), -1, np.int64)
    t2d = np.full(len(truth), -1, np.int64)
    if len(det) == 0 or len(truth) == 0:
        return d2t, t2d
    from scipy.spatial import cKDTree

    dist, idx = cKDTree(truth).query(det, k=1)
    ok = dist <= tol[idx]
    for i in np.argsort(dist):
        if ok[i] and t2d[idx[i]] < 0:
            t2d[idx[i]] = i
            d2t[i] = idx[i]
    return d2t, t2d

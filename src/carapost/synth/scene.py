"""Synthetic take geometry and motion with exact ground truth (no images).

`build_scene` turns a `SynthConfig` into a `SynthScene`: per-frame flexed cameras, face
markers moving with expressions and head slip, the fixed brim, and the truth 2D
positions and visibility of every marker in every camera.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from carapost.algorithms.camera import (
    CameraIntrinsics,
    camera_centres,
    project,
    rodrigues_to_matrix,
)
from carapost.synth import face, occlusion, rig
from carapost.synth.motion import PRESETS, ExpressionMotion, RigidJitter

__all__ = ["SynthConfig", "SynthScene", "build_scene"]

_TIMECODE = re.compile(r"^(\d{2}):(\d{2}):(\d{2})[:;](\d{2})$")
#: Sub-frame sample offsets (in frames) used for motion blur: a half-frame shutter.
BLUR_OFFSETS = np.linspace(-0.25, 0.25, 5)
#: Smallest cosine between a disc's normal and the direction to the camera for it to count
#: as visible (a disc seen more obliquely than ~75 degrees is a sliver, not a blob).
MIN_FACING = 0.25
#: Blink activation above which the upper-lid markers are folded away (invisible).
BLINK_HIDE = 0.5
#: Radius (mm) of a sphere about the head centre that holds the head in any expression.
OCCLUSION_BOUND = 135.0


@dataclass
class SynthConfig:
    """Parameters of a synthetic take.

    Attributes
    ----------
    preset : str
        Motion preset: ``"rom"``, ``"speech"``, ``"fast"`` or ``"blink"``.
    markers : str
        Marker set: ``"sparse35"``, ``"standard"`` (89 markers) or ``"dense156"``.
    frames : int
        Number of frames ``F``.
    seed : int
        Seed of every random choice; the same config gives the same take.
    size : tuple of int
        Image (width, height) in pixels.
    fps : float
        Frame rate (Hz).
    n_cameras : int
        Number of cameras ``C``; the first ceil(C/2) are on the left caddy.
    noise : float
        Standard deviation of the sensor noise (grey levels).
    blur : float
        Standard deviation of the optical blur (pixels).
    motion_blur : bool
        Integrate the markers over a half-frame shutter.
    highlights : bool
        Add saturated specular highlights on the skin (nose, forehead, cheekbones).
    merge_pair : bool
        Add one extra marker (``Merge_Extra``) placed so that it merges with a neighbour
        in camera 0 while staying separate in the other views.
    out_of_sync_camera : int or None
        A camera whose video lags the others by one frame.
    codec : str
        ``"ffv1"`` (lossless, .mkv) or ``"mp4v"`` (lossy, .mp4).
    timecode_start : str
        SMPTE timecode of frame 0, ``"HH:MM:SS:FF"``.
    take_name : str
        Stem of every file of the take.
    variant : int
        0: the standard rig, brim and marker layout. Any other value draws (from that
        value, independently of ``seed``) another rig of the same kind: camera positions,
        aims, rolls and focal lengths, the brim's dot layout and dot size, every marker's
        place on the face (about 1.5 mm) and the marker sizes (within 1-2.5 mm radius).
        Tests use it as a stand-in for takes of other rigs and renderers.
    poisson_markers : int
        0: the named marker set. N > 0: N markers placed by Poisson-disk sampling
        (`carapost.synth.face.poisson_marker_set`, labels ``P001``...) instead.
    marker_radius_mm : (float, float) or None
        Draw every face marker's radius uniformly in this range (mm).
    marker_ink : (float, float) or None
        Draw every face marker's reflectance (relative to the skin under it) uniformly in
        this range; default 0.16 for all (about grey 25-35 on lit skin). (0.12, 0.30)
        gives discs of grey ~20-50.
    head_scale : (float, float, float)
        Scale of the head along x, y, z (another head shape: wider, longer, flatter
        faces); expressions deform the head before the scale.
    caddy_baseline_mm : float
        Distance between the cameras of one caddy (mm).
    caddy_separation_mm : float
        Distance between the two caddies (mm, top cameras).
    flex_scale : float
        Scale of the per-camera rig flex (1: about 0.05 deg and 0.12 mm RMS per camera,
        each camera of a caddy flexing on its own).
    slip_scale : float
        Scale of the helmet slip on the head (1: about 0.35 deg and 0.45 mm RMS).
    partial_occlusion : bool
        An eyelid fold covers part of each upper-lid marker while the eye closes (before
        it hides it), and a curling lip part of each lip marker
        (`carapost.synth.occlusion`); the truth gains the visible part's centroid.
    missed_markers : int
        Markers (visible throughout) whose ink fades to a low contrast over one stretch
        each, so that the blob detector misses them there; the truth gains the stretches.
    skin_motion : bool
        The skin texture and shading follow the markers (`carapost.synth.skin_motion`:
        a thin-plate warp of the background through each visible marker's motion
        relative to the head), as painted markers move with the skin they are painted
        on. Off (the default), the background follows the head's motion only, so a
        marker slides over the skin by its expression motion (up to 15 px on the lips).
    """

    preset: str = "speech"
    markers: str = "standard"
    frames: int = 300
    seed: int = 0
    size: tuple[int, int] = (1280, 720)
    fps: float = 60.0
    n_cameras: int = 4
    noise: float = 2.0
    blur: float = 0.6
    motion_blur: bool = False
    highlights: bool = False
    merge_pair: bool = False
    out_of_sync_camera: int | None = None
    codec: str = "ffv1"
    timecode_start: str = "00:00:00:00"
    take_name: str = "synth"
    variant: int = 0
    poisson_markers: int = 0
    marker_radius_mm: tuple[float, float] | None = None
    marker_ink: tuple[float, float] | None = None
    head_scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    caddy_baseline_mm: float = 45.0
    caddy_separation_mm: float = 128.0
    flex_scale: float = 1.0
    slip_scale: float = 1.0
    partial_occlusion: bool = False
    missed_markers: int = 0
    skin_motion: bool = False

    def validate(self) -> None:
        """Raise ``ValueError`` naming the first bad parameter."""
        if self.preset not in PRESETS:
            raise ValueError(f"preset must be one of {PRESETS}, got {self.preset!r}")
        if self.markers not in face.MARKER_SETS:
            raise ValueError(f"markers must be one of {sorted(face.MARKER_SETS)}, "
                             f"got {self.markers!r}")
        if int(self.frames) < 1:
            raise ValueError(f"frames must be >= 1, got {self.frames}")
        w, h = self.size
        if int(w) < 64 or int(h) < 36:
            raise ValueError(f"size must be at least 64x36 pixels, got {w}x{h}")
        if not self.fps > 0:
            raise ValueError(f"fps must be positive, got {self.fps}")
        if not 1 <= int(self.n_cameras) <= 16:
            raise ValueError(f"n_cameras must be in 1..16, got {self.n_cameras}")
        if self.noise < 0 or self.blur < 0:
            raise ValueError("noise and blur must be >= 0")
        if self.out_of_sync_camera is not None and not (
                0 <= self.out_of_sync_camera < self.n_cameras):
            raise ValueError(f"out_of_sync_camera must be a camera index < {self.n_cameras}, "
                             f"got {self.out_of_sync_camera}")
        if self.codec not in ("ffv1", "mp4v"):
            raise ValueError(f"codec must be 'ffv1' or 'mp4v', got {self.codec!r}")
        m = _TIMECODE.match(self.timecode_start)
        if not m or int(m.group(2)) > 59 or int(m.group(3)) > 59 or \
                int(m.group(4)) >= max(1, int(np.ceil(self.fps))):
            raise ValueError(f"timecode_start must be HH:MM:SS:FF, got {self.timecode_start!r}")
        if int(self.variant) < 0:
            raise ValueError(f"variant must be >= 0, got {self.variant}")
        if int(self.poisson_markers) < 0:
            raise ValueError(f"poisson_markers must be >= 0, got {self.poisson_markers}")
        for name, lo_ok, hi_ok in (("marker_radius_mm", 0.3, 6.0), ("marker_ink", 0.0, 1.0)):
            rng_ = getattr(self, name)
            if rng_ is not None and not (lo_ok <= rng_[0] <= rng_[1] <= hi_ok):
                raise ValueError(f"{name} must be (low, high) within {lo_ok}..{hi_ok}, "
                                 f"got {rng_}")
        if len(self.head_scale) != 3 or not all(0.7 <= v <= 1.3 for v in self.head_scale):
            raise ValueError(f"head_scale must be three factors in 0.7..1.3, "
                             f"got {self.head_scale}")
        if not (10.0 <= self.caddy_baseline_mm <= 120.0
                and 60.0 <= self.caddy_separation_mm <= 300.0):
            raise ValueError("caddy_baseline_mm must be in 10..120 and caddy_separation_mm "
                             "in 60..300")
        if not (0.0 <= self.flex_scale <= 10.0 and 0.0 <= self.slip_scale <= 10.0):
            raise ValueError("flex_scale and slip_scale must be in 0..10")
        if int(self.missed_markers) < 0:
            raise ValueError(f"missed_markers must be >= 0, got {self.missed_markers}")
        if not self.take_name or re.search(r"[\\/:*?\"<>|\s]", self.take_name):
            raise ValueError(f"take_name must be a plain file stem, got {self.take_name!r}")


@dataclass
class SynthScene:
    """Everything needed to render a synthetic take, and its ground truth.

    All 3D quantities are in mm in the helmet frame (x actor's left, y up, z forward);
    2D in raw (distorted) pixels with the centre of the top-left pixel at (0, 0).

    Attributes
    ----------
    config : SynthConfig
    intrinsics : CameraIntrinsics
    cam_R, cam_t : ndarray, shapes (F, C, 3, 3) and (F, C, 3)
        Per-frame flexed extrinsics, ``x_cam = R X + t``.
    points3d : ndarray, shape (F, M, 3)
        Face marker centres.
    marker_radius_mm : ndarray, shape (M,)
    marker_normals : ndarray, shape (F, M, 3)
        Unit normals of the marker discs (the skin normal).
    labels : list of str, length M
    eyelid : ndarray of bool, shape (M,)
        Upper-eyelid markers (hidden while the eye is closed).
    brim3d, brim_normals : ndarray, shape (B, 3)
        Brim dot centres and normals (fixed in the helmet frame).
    brim_radius_mm : ndarray, shape (B,)
    brim_labels : list of str, length B
    visible : ndarray of bool, shape (F, M, C)
        The marker is drawn in that image (in view, facing the camera, not hidden by the
        head, not a folded eyelid).
    uv : ndarray, shape (F, M, C, 2)
        Projected marker centres (NaN behind the camera). For an out-of-sync camera this is
        where the marker is *in its image*, i.e. one frame late.
    brim_visible : ndarray of bool, shape (F, B, C)
    brim_uv : ndarray, shape (F, B, C, 2)
    activations : ndarray, shape (F, K)
        Expression activations (columns `carapost.synth.face.MODES`).
    head_R, head_t : ndarray, shapes (F, 3, 3) and (F, 3)
        Head slip: helmet-frame point = ``head_R @ p_head + head_t``.
    camera_lag : ndarray of int, shape (C,)
        Frames by which each camera's video lags (1 for the out-of-sync camera).
    merge_pair : tuple of int or None
        Indices of the two markers that merge in camera 0.
    """

    config: SynthConfig
    intrinsics: CameraIntrinsics
    cam_R: NDArray[np.float64]
    cam_t: NDArray[np.float64]
    points3d: NDArray[np.float64]
    marker_radius_mm: NDArray[np.float64]
    marker_normals: NDArray[np.float64]
    labels: list[str]
    eyelid: NDArray[np.bool_]
    brim3d: NDArray[np.float64]
    brim_normals: NDArray[np.float64]
    brim_radius_mm: NDArray[np.float64]
    brim_labels: list[str]
    visible: NDArray[np.bool_]
    uv: NDArray[np.float64]
    brim_visible: NDArray[np.bool_]
    brim_uv: NDArray[np.float64]
    activations: NDArray[np.float64]
    head_R: NDArray[np.float64]
    head_t: NDArray[np.float64]
    camera_lag: NDArray[np.int64]
    merge_pair: tuple[int, int] | None
    # What each camera sees (differs from the truth only for a lagging camera):
    seen_points: NDArray[np.float64] = field(repr=False)      # (F, C, M, 3)
    seen_normals: NDArray[np.float64] = field(repr=False)     # (F, C, M, 3)
    seen_head_R: NDArray[np.float64] = field(repr=False)      # (F, C, 3, 3)
    seen_head_t: NDArray[np.float64] = field(repr=False)      # (F, C, 3)
    blur_points: NDArray[np.float64] | None = field(default=None, repr=False)  # (F,C,S,M,3)
    blur_normals: NDArray[np.float64] | None = field(default=None, repr=False)
    nominal_R: NDArray[np.float64] = field(default=None, repr=False)  # type: ignore[assignment]
    nominal_t: NDArray[np.float64] = field(default=None, repr=False)  # type: ignore[assignment]
    #: Reflectance of each face marker relative to the skin (M,); None: 0.16 for all.
    marker_ink: NDArray[np.float64] | None = field(default=None, repr=False)
    #: Head shape scale along x, y, z (see `SynthConfig.head_scale`).
    head_scale: NDArray[np.float64] = field(
        default_factory=lambda: np.ones(3), repr=False)
    #: Partial occlusion (`SynthConfig.partial_occlusion`, else None): per frame and
    #: marker the occluder's direction in the disc plane (F, M, 3), its edge's offset from
    #: the centre (F, M) mm (inf: nothing covered), the visible part's centroid in 3D
    #: (F, M, 3) and projected as each camera sees it (F, M, C, 2).
    cover_dir: NDArray[np.float64] | None = field(default=None, repr=False)
    cover_offset: NDArray[np.float64] | None = field(default=None, repr=False)
    visible_points3d: NDArray[np.float64] | None = field(default=None, repr=False)
    visible_uv: NDArray[np.float64] | None = field(default=None, repr=False)
    #: Missed markers (`SynthConfig.missed_markers`, else None): ink contrast factor
    #: (F, M) and the stretches where it is faded (F, M) bool.
    contrast: NDArray[np.float64] | None = field(default=None, repr=False)
    missed: NDArray[np.bool_] | None = field(default=None, repr=False)
    #: Skin motion (`SynthConfig.skin_motion`, else None): each face marker's place on
    #: the head at rest, undeformed (M, 3) mm in the head frame, where the background
    #: layer shows the skin under it.
    rest_points3d: NDArray[np.float64] | None = field(default=None, repr=False)
    cache: dict[str, Any] = field(default_factory=dict, repr=False)

    @property
    def n_frames(self) -> int:
        """Number of frames ``F``."""
        return int(self.points3d.shape[0])

    @property
    def n_cameras(self) -> int:
        """Number of cameras ``C``."""
        return int(self.cam_R.shape[1])

    @property
    def size(self) -> tuple[int, int]:
        """Image (width, height) in pixels."""
        return int(self.config.size[0]), int(self.config.size[1])


def _marker_geometry(phi: NDArray, psi: NDArray, act: NDArray,
                     scale: NDArray | None = None
                     ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Deformed head-frame points and normals for activations ``act`` (..., K) -> (..., M, 3).

    ``scale`` (3,) stretches the deformed head along its axes (another head shape).
    """
    d = 0.05
    p0 = face.surface_points(phi, psi)
    pts = face.deform(p0, act)
    a = face.deform(face.surface_points(phi + d, psi), act) - \
        face.deform(face.surface_points(phi - d, psi), act)
    b = face.deform(face.surface_points(phi, psi + d), act) - \
        face.deform(face.surface_points(phi, psi - d), act)
    if scale is not None:
        # an axis scale maps tangents by S, so the normal n ~ a x b maps by S^-1
        pts, a, b = pts * scale, a * scale, b * scale
    n = np.cross(a, b)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    return pts, n


def _occluded_by_head(p_head: NDArray, cam_head: NDArray, act: NDArray,
                      reach: float = 64.0, step: float = 2.0, start: float = 1.5,
                      scale: NDArray | None = None) -> NDArray[np.bool_]:
    """True where the segment from a surface point towards its camera enters the head.

    Parameters
    ----------
    p_head : (N, 3) points in the head frame; cam_head : (N, 3) camera centres in the
    head frame; act : (N, K) activations (the head deforms with the expression);
    scale : (3,) head shape scale (the test runs in the unscaled head's frame).
    """
    if scale is not None and not np.all(scale == 1.0):
        p_head, cam_head = p_head / scale, cam_head / scale
    d = cam_head - p_head
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    s = np.arange(start, reach, step)
    out = np.zeros(len(p_head), dtype=bool)
    chunk = max(1, 400_000 // len(s))
    for i in range(0, len(p_head), chunk):
        sl = slice(i, i + chunk)
        q = p_head[sl, None, :] + s[None, :, None] * d[sl, None, :]
        # only samples near the head can be inside it (the deformed head stays within
        # OCCLUSION_BOUND mm of the centre)
        near = np.einsum("nsi,nsi->ns", q, q) < OCCLUSION_BOUND**2
        n_i, s_i = np.nonzero(near)
        inside = face.inside_deformed_head(q[n_i, s_i][:, None, :], act[sl][n_i])[:, 0]
        hit = np.zeros(near.shape, dtype=bool)
        hit[n_i[inside], s_i[inside]] = True
        out[sl] = hit.any(axis=1)
    return out


def _visibility(points: NDArray, normals: NDArray, R: NDArray, t: NDArray,
                intr: CameraIntrinsics, size: tuple[int, int], head_R: NDArray, head_t: NDArray,
                act: NDArray, scale: NDArray | None = None
                ) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """uv (F, N, C, 2) and visibility (F, N, C) of discs seen by each camera.

    ``points``/``normals`` are (F, C, N, 3) (what camera c sees at frame f) and the head
    pose/activations are per (F, C), so a lagging camera can see another instant.
    """
    F, C, N, _ = points.shape
    w, h = size
    uv = np.empty((F, N, C, 2))
    depth = np.empty((F, N, C))
    for c in range(C):
        u, z = project(points[:, c], R[:, c:c + 1], t[:, c:c + 1], intr.subset([c]))
        uv[:, :, c] = u[:, :, 0]
        depth[:, :, c] = z[:, :, 0]
    centres = camera_centres(R, t)  # (F, C, 3)
    to_cam = centres[:, :, None, :] - points
    to_cam /= np.linalg.norm(to_cam, axis=-1, keepdims=True)
    facing = np.einsum("fcnk,fcnk->fcn", to_cam, normals).transpose(0, 2, 1)
    margin = 2.0
    inside = (
        (depth > 0)
        & np.isfinite(uv).all(axis=-1)
        & (uv[..., 0] >= margin) & (uv[..., 0] <= w - 1 - margin)
        & (uv[..., 1] >= margin) & (uv[..., 1] <= h - 1 - margin)
    )
    vis = inside & (facing > MIN_FACING)
    f_i, n_i, c_i = np.nonzero(vis)
    if f_i.size:
        hR = head_R[f_i, c_i]
        ht = head_t[f_i, c_i]
        p_head = np.einsum("nji,nj->ni", hR, points[f_i, c_i, n_i] - ht)
        cam_head = np.einsum("nji,nj->ni", hR, centres[f_i, c_i] - ht)
        occ = _occluded_by_head(p_head, cam_head, act[f_i, c_i], scale=scale)
        vis[f_i[occ], n_i[occ], c_i[occ]] = False
    return uv, vis


def _merge_partner(phi: NDArray, psi: NDArray, radii: NDArray, R0: NDArray, t0: NDArray
                   ) -> tuple[int, float, float]:
    """Pick a cheek marker seen obliquely by camera 0 and an angle offset that makes a
    neighbour 2.8 radii away along the direction most foreshortened in that camera."""
    cands = [i for i in range(len(phi)) if -40 < phi[i] < -20 and -15 < psi[i] < 5]
    if not cands:
        cands = list(range(len(phi)))
    centre = camera_centres(R0[0], t0[0])
    best = None
    for i in cands:
        p = face.surface_points(phi[i], psi[i])
        n = face.surface_normals(phi[i], psi[i])
        v = centre - p
        v /= np.linalg.norm(v)
        cosang = float(n @ v)
        if cosang < 0.45:
            continue
        if best is None or cosang < best[1]:
            best = (i, cosang)
    i = best[0] if best is not None else cands[0]
    p = face.surface_points(phi[i], psi[i])
    v = centre - p
    # tangent direction closest to the viewing ray: offset that projects shortest
    dp = face.surface_points(phi[i] + 0.1, psi[i]) - p
    ds = face.surface_points(phi[i], psi[i] + 0.1) - p
    best_dir, best_len = (0.0, 0.0), np.inf
    for ang in np.radians(np.arange(0, 180, 5)):
        off = np.cos(ang) * dp / np.linalg.norm(dp) + np.sin(ang) * ds / np.linalg.norm(ds)
        perp = off - (off @ v) / (v @ v) * v
        if np.linalg.norm(perp) < best_len:
            best_len = float(np.linalg.norm(perp))
            best_dir = (np.cos(ang) / np.linalg.norm(dp) * 0.1,
                        np.sin(ang) / np.linalg.norm(ds) * 0.1)
    dist = 2.8 * radii[i]
    return i, phi[i] + best_dir[0] * dist, psi[i] + best_dir[1] * dist


def _nearest_distance(points: NDArray) -> NDArray[np.float64]:
    """Distance (mm) from each point to its nearest other point."""
    d = np.linalg.norm(points[:, None] - points[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    return d.min(1)


def build_scene(config: SynthConfig) -> SynthScene:
    """Geometry, motion and truth of a synthetic take (no images).

    Parameters
    ----------
    config : SynthConfig

    Returns
    -------
    SynthScene

    Raises
    ------
    ValueError
        If a configuration parameter is out of range (the message names it).
    """
    config.validate()
    F, C = int(config.frames), int(config.n_cameras)
    size = (int(config.size[0]), int(config.size[1]))
    seeds = np.random.SeedSequence(int(config.seed)).spawn(4)
    rng_motion, rng_slip, rng_flex = (np.random.default_rng(s) for s in seeds[:3])

    rng_variant = (np.random.default_rng([int(config.variant), 7919]) if config.variant
                   else None)
    intr, R0, t0 = rig.rig_cameras(C, size, rng_variant,
                                   baseline_mm=float(config.caddy_baseline_mm),
                                   separation_mm=float(config.caddy_separation_mm))
    # the marker layout, sizes and inks draw from their own stream, so that the options
    # leave every other random choice of the take unchanged
    rng_markers = np.random.default_rng([int(config.seed), int(config.variant), 4241])
    if config.poisson_markers:
        specs = face.poisson_marker_set(int(config.poisson_markers), rng_markers,
                                        config.marker_radius_mm or (1.2, 2.0))
    else:
        specs = face.marker_set(config.markers)
    head_scale = np.asarray(config.head_scale, dtype=np.float64)
    phi = np.array([m.phi for m in specs])
    psi = np.array([m.psi for m in specs])
    radii = np.array([m.radius for m in specs])
    brim3d, brim_labels = rig.brim_model(rng_variant)
    brim_dot_radius = rig.BRIM_DOT_RADIUS
    if rng_variant is not None and not config.poisson_markers:
        # eyelid markers stay on the lid (the blink model depends on their place)
        jitter = np.where(np.array([m.eyelid for m in specs]), 0.3, 1.0)
        phi_j = phi + rng_variant.normal(0.0, 1.0, len(phi)) * jitter
        psi_j = psi + rng_variant.normal(0.0, 1.0, len(psi)) * jitter
        # a marker set keeps its spacing: a marker that the jitter brings much closer
        # to a neighbour than it was stays where it was
        d0 = _nearest_distance(face.surface_points(phi, psi))
        for _ in range(3):
            close = _nearest_distance(face.surface_points(phi_j, psi_j)) < 0.85 * d0
            if not close.any():
                break
            phi_j[close], psi_j[close] = phi[close], psi[close]
        phi, psi = phi_j, psi_j
        radii = np.clip(radii * rng_variant.uniform(0.75, 1.25), 1.0, 2.5)
        brim_dot_radius = float(rng_variant.uniform(2.0, 3.0))
    if config.marker_radius_mm is not None and not config.poisson_markers:
        radii = rng_markers.uniform(*config.marker_radius_mm, len(radii))
    labels = [m.label for m in specs]
    eyelid = np.array([m.eyelid for m in specs], dtype=bool)
    merge = None
    if config.merge_pair:
        i, p2, s2 = _merge_partner(phi, psi, radii, R0, t0)
        phi, psi = np.append(phi, p2), np.append(psi, s2)
        radii = np.append(radii, radii[i])
        labels.append("Merge_Extra")
        eyelid = np.append(eyelid, False)
        merge = (int(i), len(labels) - 1)

    ink = (None if config.marker_ink is None
           else rng_markers.uniform(*config.marker_ink, len(labels)))

    duration = F / config.fps
    motion = ExpressionMotion(config.preset, duration, rng_motion)
    ss, fs = float(config.slip_scale), float(config.flex_scale)
    slip = RigidJitter(rng_slip, 1, ss * np.radians(0.35), ss * 0.45, 0.05, 0.5)
    flex = RigidJitter(rng_flex, C, fs * np.radians(0.05), fs * 0.12, 0.3, 2.5)

    lag = np.zeros(C, dtype=np.int64)
    if config.out_of_sync_camera is not None:
        lag[config.out_of_sync_camera] = 1
    frames = np.arange(F, dtype=np.float64)
    times = (frames[:, None] - lag[None, :]) / config.fps  # (F, C): instant each image shows

    rv, dt = flex(times)  # (F, C, C, 3): take each camera's own channel
    rv = rv[:, np.arange(C), np.arange(C)]
    dt = dt[:, np.arange(C), np.arange(C)]
    dR = rodrigues_to_matrix(rv)
    cam_R = dR @ R0[None]
    cam_t = np.einsum("fcij,cj->fci", dR, t0) + dt

    def head_pose(tt: NDArray) -> tuple[NDArray, NDArray]:
        r, tr = slip(tt)
        return rodrigues_to_matrix(r[..., 0, :]), tr[..., 0, :]

    def markers_at(tt: NDArray) -> tuple[NDArray, NDArray, NDArray, NDArray, NDArray]:
        act = motion(tt)
        p, n = _marker_geometry(phi, psi, act, None if (head_scale == 1).all() else head_scale)
        hR, ht = head_pose(tt)
        pts = np.einsum("...ij,...mj->...mi", hR, p) + ht[..., None, :]
        nrm = np.einsum("...ij,...mj->...mi", hR, n)
        return pts, nrm, act, hR, ht

    points3d, normals, act_true, head_R, head_t = markers_at(frames / config.fps)
    if lag.any():
        seen_points, seen_normals, act_seen, seen_hR, seen_ht = markers_at(times)
    else:
        seen_points = np.broadcast_to(points3d[:, None], (F, C) + points3d.shape[1:])
        seen_normals = np.broadcast_to(normals[:, None], (F, C) + normals.shape[1:])
        act_seen = np.broadcast_to(act_true[:, None], (F, C, act_true.shape[-1]))
        seen_hR = np.broadcast_to(head_R[:, None], (F, C, 3, 3))
        seen_ht = np.broadcast_to(head_t[:, None], (F, C, 3))

    uv, visible = _visibility(seen_points, seen_normals, cam_R, cam_t, intr, size,
                              seen_hR, seen_ht, act_seen, head_scale)
    blink_closed = act_seen[..., face.MODES.index("blink")] > BLINK_HIDE  # (F, C)
    visible &= ~(eyelid[None, :, None] & blink_closed[:, None, :])

    brim_n = rig.brim_normal(brim3d)
    B = len(brim3d)
    bp = np.broadcast_to(brim3d, (F, C, B, 3))
    bn = np.broadcast_to(brim_n, (F, C, B, 3))
    brim_uv, brim_visible = _visibility(bp, bn, cam_R, cam_t, intr, size, seen_hR, seen_ht,
                                        act_seen, head_scale)

    blur_points = blur_normals = None
    if config.motion_blur:
        tb = times[:, :, None] + BLUR_OFFSETS[None, None, :] / config.fps  # (F, C, S)
        blur_points, blur_normals, *_ = markers_at(tb)

    extras: dict[str, Any] = {}
    if config.partial_occlusion:
        extras.update(_partial_occlusion(labels, eyelid, radii, normals, head_R,
                                         act_true, points3d, seen_points, cam_R, cam_t,
                                         intr))
    if config.missed_markers:
        rng_missed = np.random.default_rng([int(config.seed), int(config.variant), 6151])
        cand = np.flatnonzero(visible.all(axis=(0, 2)) & ~eyelid)
        extras["contrast"], extras["missed"] = occlusion.missed_stretches(
            cand, int(config.missed_markers), len(labels), F, rng_missed)

    if config.skin_motion:
        extras["rest_points3d"] = face.surface_points(phi, psi) * head_scale

    return SynthScene(
        config=config, intrinsics=intr, cam_R=cam_R, cam_t=cam_t, points3d=points3d,
        marker_radius_mm=radii, marker_normals=normals, labels=labels, eyelid=eyelid,
        brim3d=brim3d, brim_normals=brim_n, brim_radius_mm=np.full(B, brim_dot_radius),
        brim_labels=brim_labels, visible=visible, uv=uv, brim_visible=brim_visible,
        brim_uv=brim_uv, activations=act_true, head_R=head_R, head_t=head_t,
        camera_lag=lag, merge_pair=merge, seen_points=np.ascontiguousarray(seen_points),
        seen_normals=np.ascontiguousarray(seen_normals),
        seen_head_R=np.ascontiguousarray(seen_hR), seen_head_t=np.ascontiguousarray(seen_ht),
        blur_points=blur_points, blur_normals=blur_normals, nominal_R=R0, nominal_t=t0,
        marker_ink=ink, head_scale=head_scale, **extras,
    )


def _partial_occlusion(labels: list[str], eyelid: NDArray,
                       radii: NDArray, normals: NDArray, head_R: NDArray, act: NDArray,
                       points3d: NDArray, seen_points: NDArray, cam_R: NDArray,
                       cam_t: NDArray, intr: CameraIntrinsics) -> dict[str, NDArray]:
    """The partial-occlusion members of a scene (see `SynthScene.cover_dir`)."""
    blink, curl = act[:, face.MODES.index("blink")], act[:, face.MODES.index("lip_curl")]
    cdir, coff = occlusion.partial_cover(labels, eyelid, radii, normals, head_R, blink,
                                         curl, BLINK_HIDE)
    shift = occlusion.segment_centroid_offset(np.broadcast_to(radii, coff.shape), coff)
    F, M = coff.shape
    C = cam_R.shape[1]
    vuv = np.empty((F, M, C, 2))
    for c in range(C):
        # where the camera sees the disc (a lagging camera one frame late)
        pc = np.asarray(seen_points)[:, c] + cdir * shift[..., None]
        u, _ = project(pc, cam_R[:, c:c + 1], cam_t[:, c:c + 1], intr.subset([c]))
        vuv[:, :, c] = u[:, :, 0]
    vis3d = points3d + cdir * shift[..., None]
    return {"cover_dir": cdir, "cover_offset": coff, "visible_points3d": vis3d,
            "visible_uv": vuv}

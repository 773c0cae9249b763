"""Synthetic projects for tests, screenshots and benchmarks of the window.

:func:`demo_project` fills a project directly with numpy (no rendering): a face of
markers on an ellipsoid moving smoothly in front of the synthetic rig's cameras, their
projections as blob observations and detections, with gaps, interpolated stretches,
patch-tracked and target-tracked samples so every colour of the continuity chart shows.
:func:`render_dots` draws a stand-in image of its detections. :func:`scene_project`
does the same from a rendered synthetic take, with a function rendering its images.

A harness, not product code (tests/ui, ``carapost.ui.screenshots`` and
benchmarks/gui.py use it). It is Qt-free and returns plain arrays and callables: the
window's callers wrap an image function in ``carapost.ui.frames.ArrayFrameSource``.

>>> p = demo_project(20, 6, 2, size=(160, 90))
>>> p.n_frames, p.n_points, p.n_cameras
(20, 6, 2)
>>> render_dots(p, 0, 1).shape
(90, 160)
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial

import cv2
import numpy as np
from numpy.typing import NDArray

from carapost.algorithms.camera import camera_centres
from carapost.algorithms.camera import project as project_points
from carapost.model.project import (
    KIND_BRIM,
    KIND_FACE,
    RECON_INTERPOLATED,
    RECON_NONE,
    RECON_SINGLE_SENSOR,
    RECON_TRIANGULATED,
    SOURCE_BLOB,
    SOURCE_KEYFRAME,
    SOURCE_NONE,
    SOURCE_PATCH,
    SOURCE_TARGET,
    Project,
    new_project,
)
from carapost.synth.render import render_frame
from carapost.synth.rig import rig_cameras
from carapost.synth.scene import SynthConfig, SynthScene, build_scene


def _face_points(n: int, rng: np.random.Generator) -> NDArray[np.float64]:
    """``n`` points spread over the front of an ellipsoidal face (mm, helmet frame)."""
    k = np.arange(n) + 0.5
    # a golden-angle spiral over a cap of the ellipsoid facing +z
    z = 1 - k / n * 0.85
    phi = k * np.pi * (3 - np.sqrt(5))
    r = np.sqrt(1 - z**2)
    pts = np.stack([70 * r * np.cos(phi), 95 * r * np.sin(phi), 80 * z], -1)
    return pts + rng.normal(0, 0.8, pts.shape)


def _fill_observations(p: Project, uv: NDArray, visible: NDArray, rng: np.random.Generator,
                       radius_px: NDArray | float = 4.0) -> None:
    """Blob observations and detections (plus a few clutter blobs) from projections."""
    F, P, C = visible.shape
    pts = p.points
    obs = np.where(visible[..., None], uv, np.nan).astype(np.float32)
    pts.obs[:] = obs
    pts.source[:] = np.where(visible, SOURCE_BLOB, 0)
    pts.quality[:] = np.where(visible, 0.95, 0).astype(np.float16)
    # detections: every visible projection (+ noise) and some clutter, per image
    counts = visible.sum(axis=1)  # [F, C]
    clutter = rng.integers(0, 4, size=(F, C))
    total_per = counts + clutter
    offsets = np.zeros(F * C + 1, np.int64)
    np.cumsum(total_per.reshape(-1), out=offsets[1:])
    N = int(offsets[-1])
    centre = np.empty((N, 2), np.float32)
    det_index = np.full((F, P, C), -1, np.int32)
    w, h = p.take.cameras[0].image_size
    # vectorised placement: visible projections in point order, then clutter
    vis_f, vis_p, vis_c = np.nonzero(visible)
    order = np.lexsort((vis_p, vis_c, vis_f))
    vis_f, vis_p, vis_c = vis_f[order], vis_p[order], vis_c[order]
    img = vis_f * C + vis_c
    first = np.searchsorted(img, np.arange(F * C))
    rank = np.arange(len(img)) - first[img]
    rows = offsets[img] + rank
    centre[rows] = uv[vis_f, vis_p, vis_c] + rng.normal(0, 0.15, (len(rows), 2))
    det_index[vis_f, vis_p, vis_c] = rank
    clutter_rows = np.setdiff1d(np.arange(N), rows)
    centre[clutter_rows] = rng.uniform([0, 0], [w, h], (len(clutter_rows), 2))
    axes = np.empty((N, 2), np.float16)
    rad = np.broadcast_to(np.asarray(radius_px, np.float64), (P,))
    axes[rows, 0] = rad[vis_p] * 1.1
    axes[rows, 1] = rad[vis_p] * 0.9
    axes[clutter_rows] = rng.uniform(2.5, 6.0, (len(clutter_rows), 1))
    det = p.detections
    det.offsets = offsets
    det.arrays = {
        "centre": centre,
        "axes": axes,
        "angle": rng.uniform(-1.5, 1.5, N).astype(np.float16),
        "colour": np.zeros(N, np.int8),
        "score": rng.uniform(0.5, 1.0, N).astype(np.float16),
    }
    pts.detection[:] = det_index


def _decorate(p: Project, rng: np.random.Generator) -> None:
    """Gaps, interpolation, single-sensor, patch and target-track stretches."""
    F, P = p.n_frames, p.n_points
    pts = p.points
    if F < 20 or P == 0:
        return
    for col in rng.choice(P, size=max(1, P // 5), replace=False):
        a = int(rng.integers(5, F - 10))
        n = int(rng.integers(2, max(3, F // 12)))
        sl = slice(a, min(a + n, F - 1))
        stretch = rng.integers(0, 3)
        if stretch == 0:  # a gap
            pts.positions[sl, col] = np.nan
            pts.recon[sl, col] = RECON_NONE
            pts.obs[sl, col] = np.nan
            pts.source[sl, col] = SOURCE_NONE
            pts.detection[sl, col] = -1
        elif stretch == 1:  # interpolated: 3D, no 2D
            pts.recon[sl, col] = RECON_INTERPOLATED
            pts.obs[sl, col] = np.nan
            pts.source[sl, col] = SOURCE_NONE
            pts.detection[sl, col] = -1
        else:  # seen by fewer cameras, patch- or target-tracked in one
            cams = rng.choice(p.n_cameras, size=max(1, p.n_cameras - 2), replace=False)
            for c in cams:
                pts.obs[sl, col, c] = np.nan
                pts.source[sl, col, c] = SOURCE_NONE
                pts.detection[sl, col, c] = -1
            keep = [c for c in range(p.n_cameras) if c not in cams]
            if len(keep) == 1:
                pts.recon[sl, col] = RECON_SINGLE_SENSOR
            c = keep[0]
            if rng.random() < 0.5:
                pts.source[sl, col, c] = SOURCE_PATCH
            else:
                pts.source[sl, col, c] = SOURCE_TARGET
                pts.quality[sl, col, c] = np.linspace(0.95, 0.3, sl.stop - sl.start)
                pts.source[sl.start, col, c] = SOURCE_KEYFRAME
                pts.keyframe[sl.start, col, c] = True


def demo_project(n_frames: int = 120, n_points: int = 40, n_cameras: int = 4, *,
                 size: tuple[int, int] = (640, 360), seed: int = 0,
                 decorate: bool = True, brim: int = 0) -> Project:
    """A tracked-looking project filled with numpy, with known ground truth.

    Parameters
    ----------
    n_frames, n_points, n_cameras : int
    size : (int, int)
        Image (width, height) in px.
    seed : int
    decorate : bool
        Add gaps and stretches of each kind (continuity colours).
    brim : int
        Number of extra brim points (kind BRIM) on a band above the face.

    Returns
    -------
    Project
        Labels ``M01..`` are in the label list; the first half of the points carry them.
    """
    rng = np.random.default_rng(seed)
    p = new_project(n_frames, n_cameras, name="demo", image_size=size)
    intr, R, t = rig_cameras(n_cameras, size)
    p.calibration.intrinsics = intr
    p.calibration.set_static(R, t)
    total = n_points + brim
    labels = [f"M{i + 1:02d}" if i < n_points // 2 else "" for i in range(n_points)]
    labels += [f"Brim{i + 1:02d}" for i in range(brim)]
    kinds = np.array([KIND_FACE] * n_points + [KIND_BRIM] * brim, np.int8)
    p.points.append(total, labels=labels, kind=kinds)
    p.labels = [f"M{i + 1:02d}" for i in range(n_points // 2 + 3)]
    base = _face_points(n_points, rng) + np.array([0.0, 5.0, 60.0])
    if brim:
        a = np.linspace(-1.2, 1.2, brim)
        base = np.vstack([base, np.stack([90 * np.sin(a), np.full(brim, 95.0),
                                          40 + 60 * np.cos(a)], -1)])
    tt = np.arange(n_frames)[:, None] / 60.0
    wobble = np.zeros((n_frames, total, 3))
    freq = rng.uniform(0.2, 0.9, (1, total))
    amp = rng.uniform(0.5, 3.0, (1, total))
    wobble[..., 1] = amp * np.sin(2 * np.pi * freq * tt)
    wobble[..., 0] = 0.5 * amp * np.cos(2 * np.pi * freq * tt * 0.7)
    if brim:
        wobble[:, n_points:] = 0
    pos = base[None] + wobble
    p.points.positions[:] = pos.astype(np.float32)
    p.points.recon[:] = RECON_TRIANGULATED
    p.points.residual[:] = 0.2
    uv, depth = project_points(pos, p.calibration.R, p.calibration.t, intr)
    w, h = size
    inside = (uv[..., 0] >= 2) & (uv[..., 0] < w - 2) & (uv[..., 1] >= 2) & (uv[..., 1] < h - 2)
    # a marker facing away from a camera is hidden in it
    centres = camera_centres(R, t)
    normal = (base - np.array([0.0, 5.0, 20.0]))
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    facing = np.einsum("pk,pck->pc", normal, centres[None] - base[:, None]) > 0
    facing[n_points:] = True  # brim dots face the cameras
    visible = inside & facing[None]
    _fill_observations(p, uv, visible, rng, radius_px=size[1] / 110)
    if decorate:
        _decorate(p, rng)
    p.modified = False
    return p


def render_dots(project: Project, frame: int, camera: int, *, noise: bool = True
                ) -> NDArray[np.uint8]:
    """A grey image [H, W] uint8 with a dark dot at every detection (stand-in for video).

    ``partial(render_dots, project)`` is a ``get_image(frame, camera)`` for the window
    (wrap it in ``ArrayFrameSource``) or a Session.
    """
    w, h = project.take.cameras[camera].image_size
    yy = np.linspace(0, 1, h, dtype=np.float32)[:, None]
    xx = np.linspace(0, 1, w, dtype=np.float32)[None, :]
    img = (150 + 50 * np.exp(-((xx - 0.5) ** 2 * 4 + (yy - 0.5) ** 2 * 3))).astype(np.uint8)
    det = project.detections.get(frame, camera)
    for (x, y), (a, b), ang in zip(det["centre"], det["axes"], det["angle"], strict=True):
        cv2.ellipse(img, (int(round(float(x) * 4)), int(round(float(y) * 4))),
                    (max(int(float(a) * 4), 1), max(int(float(b) * 4), 1)),
                    float(np.degrees(float(ang))), 0, 360, 35, -1, cv2.LINE_AA, 2)
    if noise:
        rng = np.random.default_rng(frame * 97 + camera)
        img = np.clip(img + rng.normal(0, 2.0, img.shape), 0, 255).astype(np.uint8)
    return img


def scene_project(frames: int = 120, size: tuple[int, int] = (1280, 720), *,
                  preset: str = "speech", seed: int = 3, decorate: bool = True,
                  **options: object
                  ) -> tuple[Project, SynthScene, Callable[[int, int], NDArray[np.uint8]]]:
    """A project from a rendered synthetic take.

    ``decorate`` adds gaps and edited stretches (as `demo_project` does); ``options``
    are further `SynthConfig` fields (``missed_markers=4``).

    Returns
    -------
    project : Project
        Points = the scene's face markers and brim dots with their ground-truth 3D
        and 2D.
    scene : SynthScene
    get_image : callable
        ``get_image(frame, camera) -> grey image [H, W] uint8`` rendering the take
        (slow: wrap it in a caching frame source).
    """
    scene = build_scene(SynthConfig(frames=frames, size=size, preset=preset, seed=seed,
                                    **options))  # type: ignore[arg-type]
    F, M, C = scene.visible.shape
    B = scene.brim3d.shape[0]
    p = new_project(F, C, name="synth", image_size=size, fps=scene.config.fps)
    p.calibration.intrinsics = scene.intrinsics.copy()
    p.calibration.R[:] = scene.cam_R
    p.calibration.t[:] = scene.cam_t
    p.calibration.solved[:] = True
    kinds = np.array([KIND_FACE] * M + [KIND_BRIM] * B, np.int8)
    p.points.append(M + B, labels=list(scene.labels) + list(scene.brim_labels), kind=kinds)
    p.labels = list(scene.labels)
    pos = np.concatenate([scene.points3d, np.broadcast_to(scene.brim3d, (F, B, 3))], axis=1)
    p.points.positions[:] = pos.astype(np.float32)
    p.points.recon[:] = RECON_TRIANGULATED
    uv = np.concatenate([scene.uv, scene.brim_uv], axis=1)
    vis = np.concatenate([scene.visible, scene.brim_visible], axis=1)
    radius = np.concatenate([scene.marker_radius_mm, scene.brim_radius_mm]) * size[1] / 260
    rng = np.random.default_rng(seed)
    _fill_observations(p, uv, vis, rng, radius_px=radius)
    if decorate:
        _decorate(p, rng)
    p.modified = False
    return p, scene, partial(render_frame, scene)

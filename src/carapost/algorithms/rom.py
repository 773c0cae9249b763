"""Initialize from ROM: match a frame of an initialised ROM take to a frame of a new take.

The ROM frame's brim points (known structure), face points and cameras are the
"previous frame" of one tracking step (:class:`carapost.algorithms.tracking.FrameMatcher`)
with the Initialize From ROM Parameters as search radii:

1. Brim: the ROM brim is projected with the ROM cameras and matched within ROM Brim Point
   Tracking Distance; the cameras of the new frame are re-solved from the matches, and
   the brim is matched again within Brim Point Tracking Distance.
2. Face (unless brim only): the ROM face points, projected with the new cameras, are
   matched within ROM Face Point Tracking Distance by neighbourhood consensus, then
   elastically; points further than ROM Max Allowed 3D Point Error from where their ROM
   neighbours put them are dropped. A second round starts from the first round's result,
   so points whose neighbours were found late are picked up.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

# FrameMatcher and pack_detections are looked up through the lazy package when used, so
# that importing RomParameters (the properties registry, the window at start-up) does
# not load the tracker
from carapost.algorithms import tracking
from carapost.algorithms.camera import CameraIntrinsics
from carapost.algorithms.codes import KIND_BRIM, PointArrays
from carapost.algorithms.params import INITIALIZE_FROM_ROM, param, validate
from carapost.algorithms.tracking import FrameDetections, TrackingParameters


@dataclass(frozen=True)
class RomParameters:
    """The Initialize From ROM Parameters section (keys of the properties registry).

    Attributes
    ----------
    rom_frame_index : int
        Frame of the ROM take to initialise from.
    rom_face_point_tracking_distance : float
        Search radius (px) for face points.
    rom_brim_point_tracking_distance : float
        Search radius (px) for brim points.
    rom_max_3d_point_error : float
        Largest distance (mm) from the neighbour-based prediction.
    """

    rom_frame_index: int = param(
        0, label="ROM Frame Index", section=INITIALIZE_FROM_ROM, unit="frame",
        min=0, max=1_000_000,
        help="Frame of the loaded ROM take whose face and brim pose best resembles the "
             "frame being initialised. Default is our choice (the guide gives none).")
    rom_face_point_tracking_distance: float = param(
        50.0, label="ROM Face Point Tracking Distance", section=INITIALIZE_FROM_ROM,
        unit="px", min=0.0, max=1000.0,
        help="Search radius when matching face points from the ROM frame to this take; "
             "larger tolerates more change but risks mismatches. Range is our choice.")
    rom_brim_point_tracking_distance: float = param(
        30.0, label="ROM Brim Point Tracking Distance", section=INITIALIZE_FROM_ROM,
        unit="px", min=0.0, max=1000.0,
        help="Search radius when matching brim points from the ROM frame to this take. "
             "Range is our choice.")
    rom_max_3d_point_error: float = param(
        5.0, label="ROM Max Allowed 3D Point Error", section=INITIALIZE_FROM_ROM, unit="mm",
        min=0.0, max=100.0,
        help="Points further than this from where their ROM neighbours predict are "
             "dropped (needs Remove Bad 3D Points). Range is our choice.")

    def __post_init__(self) -> None:
        validate(self)


#: Per ROM point, its match in the new frame: the shared point-array record
#: (:class:`carapost.algorithms.codes.PointArrays`) for one frame, so without the frame
#: axis, with ``structure`` the ROM positions (the brim model for brim points) and
#: ``R, t`` (C, 3, 3), (C, 3) the cameras of the new frame.
RomResult = PointArrays


def initialize_from_rom(
    detections: FrameDetections,
    rom_positions: ArrayLike,
    rom_kind: ArrayLike,
    rom_R: ArrayLike,
    rom_t: ArrayLike,
    intr: CameraIntrinsics,
    rom_params: RomParameters | None = None,
    params: TrackingParameters | None = None,
    *,
    brim_only: bool = False,
) -> RomResult:
    """Match ROM points to one frame's detections.

    Parameters
    ----------
    detections : sequence
        One ``(centre [N, 2], axes [N, 2] or None)`` per camera of the new frame.
    rom_positions : array_like, shape (P, 3)
        ROM points at the ROM frame (mm).
    rom_kind : array_like, shape (P,)
        ``KIND_FACE`` / ``KIND_BRIM``.
    rom_R, rom_t : array_like
        ROM cameras at the ROM frame, the starting guess for the new frame.
    intr : CameraIntrinsics
    rom_params : RomParameters, optional
    params : TrackingParameters, optional
        Tracking parameters (elastic radius, 2D error, single sensor...).
    brim_only : bool
        Match the brim only.

    Returns
    -------
    RomResult
    """
    rp = RomParameters() if rom_params is None else rom_params
    tp = TrackingParameters() if params is None else params
    X = np.asarray(rom_positions, np.float64)
    kind = np.asarray(rom_kind, np.int8).reshape(-1)
    C = intr.n_cameras
    P = X.shape[0]
    R = np.asarray(rom_R, np.float64).copy()
    t = np.asarray(rom_t, np.float64).copy()
    fr = tracking.pack_detections(detections, C)
    no_axes = np.full((P, C, 2), np.nan)
    matcher = tracking.FrameMatcher(intr, kind, X, tp)
    brim = kind == KIND_BRIM
    has_brim = bool((brim & np.isfinite(X).all(-1)).any())

    out = None
    if has_brim:
        Xb = np.where(brim[:, None], X, np.nan)
        for radius in (rp.rom_brim_point_tracking_distance, tp.brim_point_tracking_distance):
            out = matcher.match_frame(fr, Xb, R, t, no_axes, brim_radius=radius,
                                      resolve_cameras=True)
            R, t = out["R"], out["t"]
    if not brim_only:
        Xf = X.copy()
        Xf[brim] = np.where(has_brim, X[brim], np.nan)
        pred = Xf
        for round_ in range(2):
            out = matcher.match_frame(
                fr, pred, R, t, no_axes,
                face_radius=rp.rom_face_point_tracking_distance if round_ == 0
                else tp.face_point_max_elastic_prediction_distance,
                max_3d=rp.rom_max_3d_point_error, passes=3, resolve_cameras=False)
            got = np.isfinite(out["positions"]).all(-1)
            pred = np.where(got[:, None], out["positions"], out["X_elastic"])
            pred[brim] = Xf[brim]
    if out is None:
        raise ValueError("nothing to match: no brim points and brim_only is set")
    pos = out["positions"]
    return RomResult(pos.astype(np.float32), out["recon"].astype(np.int8),
                     out["residual"].astype(np.float32), out["obs"].astype(np.float32),
                     out["source"].astype(np.int8), out["detection"].astype(np.int32),
                     out["quality"].astype(np.float16), R, t, structure=X.copy())

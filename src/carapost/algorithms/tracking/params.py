"""The Tracking Parameters section (:class:`TrackingParameters`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from carapost.algorithms.params import TRACKING, from_mapping, param, validate


@dataclass(frozen=True)
class TrackingParameters:
    """The Tracking Parameters section, plus a few settings of our own.

    The first twelve fields are the properties of the Tracking Parameters section
    (declared with :func:`~carapost.algorithms.params.param`), so
    ``TrackingParameters(**props.section("Tracking Parameters"))`` works.

    Attributes
    ----------
    patch_match_threshold : float
        Minimum normalised cross-correlation (0-1) for a patch-tracked observation.
    face_point_tracking_distance : float
        Search radius (px) for face points without elastic support.
    face_point_max_elastic_prediction_distance : float
        Search radius (px) around the elastic prediction once neighbours are matched.
    brim_point_tracking_distance : float
        Search radius (px) for brim points.
    patch_match_size : int
        Side (px) of the square grey-level patch.
    remove_bad_2d_projections : bool
        Detach observations further than ``max_2d_projection_error`` from their point's
        projection. Off or on, the cameras the robust triangulation leaves out of a
        point are detached (they are wrong matches).
    max_2d_projection_error : float
        Observations further (px) than this from their point's projection are detached.
    remove_bad_3d_points : bool
    max_3d_point_error : float
        Points further (mm) than this from their neighbour-based prediction are dropped.
    allow_single_sensor_tracking : bool
    single_sensor_tracking_threshold : float
        Largest distance (mm) between a single-camera ray and the prediction.
    blob_size_difference_threshold : float
        Allowed relative change (0-1) of a blob's axes between frames (1 = any).
    velocity_weight : float
        Fraction of the last frame-to-frame motion added to the prediction (ours).
    neighbours : int
        Neighbours per point for the elastic prediction (ours).
    min_elastic_support : float
        Summed neighbour weight needed to use the elastic radius (ours; one full-weight
        neighbour = 1).
    bundle_frames : bool
        Bundle adjust each tracked frame (cameras and points; slower; ours).
    max_patch_frames : int
        Longest run of consecutive patch-tracked frames in one camera (ours).
    elastic_passes : int
        Most elastic matching passes per frame (ours): each pass predicts the points not
        yet matched from the neighbours matched in the previous one, so a region moving
        faster than the search radius is picked up from its edges inwards.
    consensus_radius_factor : float
        Points the anchor pass leaves without an anchor vote, with their neighbours, over
        candidate displacements up to this multiple of Face Point Tracking Distance
        (ours; >= 1; 1 keeps the candidates within that distance): a region moving
        further than the radius between two frames is matched as a whole around the
        displacement its markers agree on (the elastic prediction of the reference
        guide, found before any neighbour is matched).
    """

    patch_match_threshold: float = param(
        0.8, label="Patch Match Threshold", section=TRACKING, unit="0-1", min=0.0, max=1.0,
        help="Minimum patch similarity for two detections in consecutive frames to count "
             "as the same marker (1 = identical).")
    face_point_tracking_distance: float = param(
        35.0, label="Face Point Tracking Distance", section=TRACKING, unit="px",
        min=0.0, max=1000.0,
        help="Frame-to-frame search radius for face markers; larger follows faster motion "
             "but mismatches more. Range is our choice.")
    face_point_max_elastic_prediction_distance: float = param(
        15.0, label="Face Point Max Elastic Prediction Distance", section=TRACKING, unit="px",
        min=0.0, max=1000.0,
        help="Search radius for face markers once neighbour-based (elastic) prediction is "
             "available; keep it below Face Point Tracking Distance. Range is our choice.")
    brim_point_tracking_distance: float = param(
        15.0, label="Brim Point Tracking Distance", section=TRACKING, unit="px",
        min=0.0, max=1000.0,
        help="Frame-to-frame search radius for brim markers, small because the brim barely "
             "moves. Range is our choice.")
    patch_match_size: int = param(
        15, label="Patch Match Size", section=TRACKING, unit="px", min=3, max=101,
        help="Side of the square grey-level patch compared around each detection; larger "
             "rejects more outliers but finds fewer matches. Range is our choice.")
    remove_bad_2d_projections: bool = param(
        True, label="Remove Bad 2D Projections", section=TRACKING,
        help="Detach detections whose reprojection error exceeds Max Allowed 2D Projection "
             "Error.")
    max_2d_projection_error: float = param(
        5.0, label="Max Allowed 2D Projection Error", section=TRACKING, unit="px",
        min=0.0, max=100.0,
        help="Largest distance between a detection and its point's projection before the "
             "detection is detached. Range is our choice.")
    remove_bad_3d_points: bool = param(
        True, label="Remove Bad 3D Points", section=TRACKING,
        help="Detach detections that put a point somewhere its neighbours say it cannot "
             "be (slightly slower, cleaner).")
    max_3d_point_error: float = param(
        5.0, label="Max Allowed 3D Point Error", section=TRACKING, unit="mm",
        min=0.0, max=100.0,
        help="Distance from the neighbour-predicted position beyond which a point is "
             "treated as bad. Range is our choice.")
    allow_single_sensor_tracking: bool = param(
        True, label="Allow Single Sensor Tracking", section=TRACKING,
        help="Keep tracking a point seen by one camera only, placing it on that camera's "
             "ray near its predicted position.")
    single_sensor_tracking_threshold: float = param(
        0.5, label="Single Sensor Tracking Threshold", section=TRACKING, unit="mm",
        min=0.0, max=100.0,
        help="A single-camera result further than this from its predicted position is "
             "rejected. Range is our choice.")
    blob_size_difference_threshold: float = param(
        0.75, label="Blob Size Difference Threshold", section=TRACKING, unit="0-1",
        min=0.0, max=1.0,
        help="How much a blob's width and height may change between frames and still "
             "match (0 = none, 1 = any); lower it to reject merged blobs.")
    # internal tunables (not in the Properties pane)
    velocity_weight: float = param(0.0, min=0.0, max=1.0)
    neighbours: int = param(8, min=1)
    min_elastic_support: float = 1.5
    bundle_frames: bool = False
    max_patch_frames: int = 5
    elastic_passes: int = param(5, min=1)
    consensus_radius_factor: float = param(2.0, min=1.0)
    #: Frames of the camera pose fit after tracking a take (`track_take`; below 5: off),
    #: see :func:`carapost.algorithms.uncertainty.smooth_camera_poses`.
    pose_smoothing_frames: int = param(11, min=0)
    #: Frames of the depth prior from time after tracking a take (`track_take`; below 5:
    #: off), see :func:`carapost.algorithms.depth_prior.smooth_along_uncertainty`.
    depth_smoothing_frames: int = param(9, min=0)
    #: Before the pose fit, solve every frame's cameras again from the brim centroids
    #: less each tilted dot's image offset (`track_take`, needs the blobs' axes; see
    #: :mod:`carapost.algorithms.brim_discs`). Off only for detections whose centres are
    #: already the projections of the dots' centres (truth-derived synthetic ones).
    brim_dot_offsets: bool = True

    def __post_init__(self) -> None:
        validate(self)

    @classmethod
    def from_mapping(cls, values: dict[str, Any], **overrides: Any) -> TrackingParameters:
        """Build from properties (see :func:`carapost.algorithms.params.from_mapping`)."""
        return from_mapping(cls, values, **overrides)

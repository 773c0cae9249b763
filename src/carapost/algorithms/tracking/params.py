"""The Tracking Parameters section (:class:`TrackingParameters`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any


@dataclass(frozen=True)
class TrackingParameters:
    """The Tracking Parameters section, plus a few settings of our own.

    The first twelve fields have the keys and defaults of the properties registry, so
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

    patch_match_threshold: float = 0.8
    face_point_tracking_distance: float = 35.0
    face_point_max_elastic_prediction_distance: float = 15.0
    brim_point_tracking_distance: float = 15.0
    patch_match_size: int = 15
    remove_bad_2d_projections: bool = True
    max_2d_projection_error: float = 5.0
    remove_bad_3d_points: bool = True
    max_3d_point_error: float = 5.0
    allow_single_sensor_tracking: bool = True
    single_sensor_tracking_threshold: float = 0.5
    blob_size_difference_threshold: float = 0.75
    velocity_weight: float = 0.0
    neighbours: int = 8
    min_elastic_support: float = 1.5
    bundle_frames: bool = False
    max_patch_frames: int = 5
    elastic_passes: int = 5
    consensus_radius_factor: float = 2.0

    def __post_init__(self) -> None:
        for name in ("face_point_tracking_distance", "face_point_max_elastic_prediction_distance",
                     "brim_point_tracking_distance", "max_2d_projection_error",
                     "max_3d_point_error", "single_sensor_tracking_threshold"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v >= 0):
                raise ValueError(f"TrackingParameters.{name} must be a number >= 0, got {v!r}")
        for name in ("patch_match_threshold", "blob_size_difference_threshold",
                     "velocity_weight"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and 0.0 <= v <= 1.0):
                raise ValueError(f"TrackingParameters.{name} must be in 0-1, got {v!r}")
        if int(self.patch_match_size) < 3:
            raise ValueError(f"TrackingParameters.patch_match_size must be >= 3 px, got "
                             f"{self.patch_match_size!r}")
        if int(self.elastic_passes) < 1:
            raise ValueError(f"TrackingParameters.elastic_passes must be >= 1, got "
                             f"{self.elastic_passes!r}")
        v = self.consensus_radius_factor
        if not (isinstance(v, int | float) and math.isfinite(v) and v >= 1.0):
            raise ValueError(f"TrackingParameters.consensus_radius_factor must be >= 1, got "
                             f"{v!r}")
        if int(self.neighbours) < 1:
            raise ValueError(f"TrackingParameters.neighbours must be >= 1, got "
                             f"{self.neighbours!r}")

    @classmethod
    def from_mapping(cls, values: dict[str, Any], **overrides: Any) -> TrackingParameters:
        """Build from a properties section (unknown keys are ignored)."""
        names = {f.name for f in fields(cls)}
        kw = {k: v for k, v in values.items() if k in names}
        kw.update(overrides)
        return cls(**kw)

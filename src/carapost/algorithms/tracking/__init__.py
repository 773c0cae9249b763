"""Automatic frame-to-frame tracking of 3D markers through a take.

For every point that has a 3D position in the start frame, and for every following frame
(forwards or backwards), :func:`track`:

1. Predicts the point in the new frame: its last estimate plus a damped velocity, then
   corrected elastically by how its matched neighbours moved (the neighbours are the
   nearest points in 3D in the start frame, weighted by a Gaussian of that distance).
2. Matches blob detections camera by camera. A first pass takes only matches its
   neighbours agree on (candidate displacements within Face / Brim Point Tracking
   Distance supported by the neighbours' candidates; points left out vote again over a
   wider radius, so a region moving further than the search radius in one frame is
   matched around the displacement its markers share); those anchor the elastic
   prediction, and the following passes match every point within Face Point Max Elastic
   Prediction Distance of its elastic prediction (the full Face Point Tracking Distance
   where too few neighbours are matched). Conflicts are resolved by an optimal assignment per camera
   (:func:`scipy.optimize.linear_sum_assignment` with a "no match" option for each point
   costing as much as a match at the search radius), so one detection never feeds two
   points. A blob whose width or height changed by more than Blob Size Difference
   Threshold is not a candidate. Where no blob matches and images are available, a grey
   patch around the last observation is searched by normalised cross-correlation
   (accepted at Patch Match Threshold and recorded as patch-tracked).
3. Re-solves the cameras of the new frame from the brim points (known 3D structure) by a
   few Gauss-Newton steps per camera, then triangulates the face points robustly
   (:func:`carapost.algorithms.triangulation.triangulate`, outlier rejection on).
4. Rejects bad matches: observations whose reprojection error exceeds Max Allowed 2D
   Projection Error, and points further than Max Allowed 3D Point Error from where their
   neighbours predict them (neighbours moving unlike the others left out). A point left
   with one camera is placed on that camera's ray at the neighbour-predicted depth when
   the ray passes within Single Sensor Tracking Threshold of the prediction (Allow Single
   Sensor Tracking).

A point that loses every camera keeps a predicted position carried along by its
neighbours, so it is picked up again as soon as its blob reappears near that prediction
(markers coming back after a blink) - from two cameras agreeing in 3D, or from one whose
ray passes within Single Sensor Tracking Threshold of the prediction.

Everything is vectorised per frame over points x cameras; there is no Python loop per
point-frame except for patch tracking of the few point-cameras that found no blob.

The package is split by stage: :mod:`.params` (:class:`TrackingParameters`),
:mod:`.records` (inputs and the result), :mod:`.neighbours` (the neighbour graph),
:mod:`.matching` (:class:`FrameMatcher`, one frame), :mod:`.sequence` (:func:`track`, one
direction), :mod:`.take` (:func:`track_take`, two passes, and the spawner) and
:mod:`.identity` (identity repair). Camera resection is
:func:`carapost.algorithms.pose.refine_poses`, the patch search
:func:`carapost.algorithms.patch.patch_search`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from carapost.algorithms._lazy import lazy_names
from carapost.algorithms.tracking.params import TrackingParameters
from carapost.algorithms.tracking.records import (
    FrameDetections,
    InitialState,
    RaggedDetections,
    TrackResult,
)

# The stages (matcher, sequence, take, identity) are imported on first use, so that
# importing the parameters and records (the properties registry, the window at
# start-up) does not load the whole tracker.
_LAZY = {
    "PackedFrame": "assignment", "pack_detections": "assignment",
    "hop_segments": "identity", "FrameMatcher": "matching", "resect_cameras": "matching",
    "neighbour_graph": "neighbours", "PROBATION_FRAMES": "sequence", "Spawner": "sequence",
    "track": "sequence", "make_spawner": "take", "track_take": "take",
}

if TYPE_CHECKING:
    from carapost.algorithms.tracking.assignment import PackedFrame, pack_detections
    from carapost.algorithms.tracking.identity import hop_segments
    from carapost.algorithms.tracking.matching import FrameMatcher, resect_cameras
    from carapost.algorithms.tracking.neighbours import neighbour_graph
    from carapost.algorithms.tracking.sequence import PROBATION_FRAMES, Spawner, track
    from carapost.algorithms.tracking.take import make_spawner, track_take


__getattr__, __dir__ = lazy_names(__name__, _LAZY, globals())

__all__ = [
    "PROBATION_FRAMES",
    "FrameDetections",
    "FrameMatcher",
    "InitialState",
    "PackedFrame",
    "RaggedDetections",
    "Spawner",
    "TrackResult",
    "TrackingParameters",
    "hop_segments",
    "make_spawner",
    "neighbour_graph",
    "pack_detections",
    "resect_cameras",
    "track",
    "track_take",
]

"""The Blob Parameters section of the properties (:class:`BlobParameters`)."""

from __future__ import annotations

from dataclasses import dataclass

from carapost.algorithms.params import BLOB, param, validate

__all__ = ["BlobParameters"]


@dataclass(frozen=True)
class BlobParameters:
    """The Blob Parameters section of the properties (names and defaults of the guide).

    Attributes
    ----------
    find_black_blobs, find_white_blobs : bool
        Which marker colours to search for (default black only).
    black_min_radius, black_max_radius, white_min_radius, white_max_radius : float
        Accepted range of the length of the longest ellipse axis (the full major axis,
        twice the semi-major axis ``a`` of :class:`BlobDetections`) in px (default 4-50),
        as in the guide: what its measuring tool gives when dragged across a blob.
    black_threshold, white_threshold : float
        Minimum probability (0-1) that a candidate is a blob centre (default 0.4):
        0 accepts almost anything, 1 only perfect blobs.

    Raises
    ------
    ValueError
        If a radius is not positive and finite, min > max, or a threshold is
        outside 0-1 (the message names the parameter).
    """

    # in the guide's order (the Properties pane shows them so)
    white_min_radius: float = param(
        4.0, label="White Min Radius", section=BLOB, unit="px",
        min=0.0, min_exclusive=True, max=1000.0,
        help="Smallest length of the longest axis of the ellipse (measured across the "
             "blob, as the measuring tool shows it) accepted as a white blob; lower finds "
             "tiny blobs but also noise. Range is our choice.")
    white_max_radius: float = param(
        50.0, label="White Max Radius", section=BLOB, unit="px",
        min=0.0, min_exclusive=True, max=1000.0,
        help="Largest length of the longest axis of the ellipse (measured across the blob) "
             "accepted as a white blob; larger is slower and admits clutter. Range is our "
             "choice.")
    black_min_radius: float = param(
        4.0, label="Black Min Radius", section=BLOB, unit="px",
        min=0.0, min_exclusive=True, max=1000.0,
        help="Smallest length of the longest axis of the ellipse (measured across the "
             "blob, as the measuring tool shows it) accepted as a black blob. Range is our "
             "choice.")
    black_max_radius: float = param(
        50.0, label="Black Max Radius", section=BLOB, unit="px",
        min=0.0, min_exclusive=True, max=1000.0,
        help="Largest length of the longest axis of the ellipse (measured across the blob) "
             "accepted as a black blob. Range is our choice.")
    find_black_blobs: bool = param(
        True, label="Find Black Blobs", section=BLOB,
        help="Look for dark markers on lighter skin.")
    find_white_blobs: bool = param(
        False, label="Find White Blobs", section=BLOB,
        help="Look for bright markers on darker skin.")
    black_threshold: float = param(
        0.4, label="Black Threshold", section=BLOB, unit="0-1", min=0.0, max=1.0,
        help="How closely a dark candidate must resemble a model blob: 0 accepts nearly "
             "anything, 1 only near-perfect blobs.")
    white_threshold: float = param(
        0.4, label="White Threshold", section=BLOB, unit="0-1", min=0.0, max=1.0,
        help="How closely a bright candidate must resemble a model blob: 0 accepts nearly "
             "anything, 1 only near-perfect blobs.")

    def __post_init__(self) -> None:
        validate(self)
        for colour in ("black", "white"):
            lo = getattr(self, f"{colour}_min_radius")
            hi = getattr(self, f"{colour}_max_radius")
            if lo > hi:
                raise ValueError(f"BlobParameters.{colour}_min_radius ({lo}) must not exceed "
                                 f"{colour}_max_radius ({hi})")

"""carapost: post-processing of head-mounted facial motion capture."""

__version__ = "0.1.0"

"""carapost: post-processing of head-mounted facial motion capture.

``from carapost import Session`` gives the scripting session (`carapost.session`); it
is imported on first use, so ``import carapost`` stays instant.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"

__all__ = ["Session", "__version__"]

if TYPE_CHECKING:
    from carapost.session import Session


def __getattr__(name: str) -> Any:
    if name == "Session":
        from carapost.session import Session

        return Session
    raise AttributeError(f"module 'carapost' has no attribute {name!r}")

"""Work around a reference-count bug of PySide6 6.12 on Python 3.11.

In PySide6 6.12.0 on Python 3.11, ``Signal.emit()`` drops a reference to ``True`` and
many wrapped methods returning nothing (``QLabel.setText``...) drop one to ``None``,
references they never took. On Python 3.12+ these singletons are immortal and nothing
happens; on 3.11 their counts fall with every call until the interpreter aborts with
"Fatal Python error: bool_dealloc" / "none_dealloc" (a scrubbed frame makes hundreds
of such calls, inside pyqtgraph too). The singletons are static objects that are
never freed, so adding a very large number to their reference counts (what 3.12 does
for every immortal object) makes the bug harmless. Pinning PySide6 to a release
without the bug is the real fix; this keeps the application alive meanwhile.
"""

from __future__ import annotations

import ctypes
import sys

_BOOST = 1 << 40  # more emits than a session can make


def _affected() -> bool:
    if sys.version_info >= (3, 12) or sys.implementation.name != "cpython":
        return False
    try:
        import PySide6
    except ImportError:
        return False
    return str(getattr(PySide6, "__version__", "")).startswith("6.12.")


def protect_true() -> bool:
    """Make ``None``, ``True`` and ``False`` effectively immortal when PySide6 needs it.

    Returns
    -------
    bool
        Whether the workaround was applied (once per process).
    """
    if not _affected() or getattr(protect_true, "applied", False):
        return False
    for obj in (None, True, False):
        count = ctypes.c_ssize_t.from_address(id(obj))
        count.value += _BOOST
    protect_true.applied = True  # type: ignore[attr-defined]
    return True

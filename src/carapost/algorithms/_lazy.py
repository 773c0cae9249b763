"""Lazy public names of an algorithm package: its stages are imported on first use.

The properties registry and the window need only the parameter dataclasses of the
``blobs`` and ``tracking`` packages at start-up; importing every stage would load numba,
the compiled kernels and the whole tracker (~1 s). A package lists which submodule
defines each of its other public names, and :func:`lazy_names` gives it the module
``__getattr__`` and ``__dir__`` (PEP 562) that import that submodule when the name is
first used.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from typing import Any


def lazy_names(package: str, where: Mapping[str, str], namespace: dict[str, Any]
               ) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """Module ``__getattr__`` and ``__dir__`` for ``package``.

    Parameters
    ----------
    package : str
        The package's ``__name__``.
    where : mapping of str to str
        Public name -> submodule (relative to the package) that defines it.
    namespace : dict
        The package's ``globals()``: a name, once imported, is stored there so later
        lookups are plain attribute reads.

    Examples
    --------
    >>> ns = {}
    >>> getattr_, dir_ = lazy_names("os", {"join": "path"}, ns)
    >>> getattr_("join").__name__, "join" in ns, "join" in dir_()
    ('join', True, True)
    """

    def __getattr__(name: str) -> Any:
        module = where.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(f"{package}.{module}"), name)
        namespace[name] = value
        return value

    def __dir__() -> list[str]:
        return sorted(set(namespace) | set(where))

    return __getattr__, __dir__

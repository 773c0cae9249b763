"""Read FBX files with ufbx in a forked child that never frees a ufbx object.

The ufbx binding (0.0.5) can crash the interpreter while it frees its wrappers: it
segfaults on a wrapper whose scene is gone, and freeing them in a fixed order (every
wrapper, then the scene) was not enough: one `tests/io` run in about eight under load
still died in `test_fbx`'s clean-up with SIGSEGV, which takes the whole test run
with it. A child forked for the reading runs the check, sends back its result (or its
traceback) and leaves with `os._exit`, so no ufbx object is ever freed, and a crash
inside the binding fails one test with a message instead of ending the run.
"""

from __future__ import annotations

import functools
import os
import pickle
import signal
import traceback
from collections.abc import Callable
from typing import Any


def call_in_child(fn: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
    """``fn(*args, **kwargs)`` run in a forked child; its (picklable) result.

    An exception in the child is raised here as an AssertionError carrying the
    child's traceback. A child that dies by a signal is run again, up to three times
    in all, and only then fails with its signal's name: the binding's crash is not
    deterministic (one CI run died with SIGSEGV while reading a file that five reruns
    of the same test read without fault), while a file of ours that crashes the
    reader every time still fails the test.
    """
    for _ in range(3):
        try:
            return _call_once(fn, *args, **kwargs)
        except _ChildDied as exc:
            why = exc
    raise AssertionError(f"the ufbx reader's child process died ({why}), three times")


class _ChildDied(Exception):
    """The child ended by a signal (its name is the message) or without a result."""


def _call_once(fn: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
    """One forked run of ``fn`` (see :func:`call_in_child`)."""
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: run, report, and leave without freeing anything
        os.close(r)
        try:
            try:
                out = (True, fn(*args, **kwargs))
                data = pickle.dumps(out)
            except BaseException as exc:  # reported to the parent
                data = pickle.dumps((False, "".join(traceback.format_exception(exc))))
            with os.fdopen(w, "wb") as f:
                f.write(data)
        finally:
            os._exit(0)
    os.close(w)
    with os.fdopen(r, "rb") as f:
        data = f.read()
    _, status = os.waitpid(pid, 0)
    if not data:
        if os.WIFSIGNALED(status):
            why = signal.Signals(os.WTERMSIG(status)).name
        else:
            why = f"exit status {os.WEXITSTATUS(status)}"
        raise _ChildDied(why)
    ok, value = pickle.loads(data)
    if not ok:
        raise AssertionError(f"in the ufbx reader's child process:\n{value}")
    return value


def in_child(test: Callable[..., None]) -> Callable[..., None]:
    """Decorate a test that reads with ufbx: its body runs in `call_in_child`."""

    @functools.wraps(test)
    def wrapper(*args: Any, **kwargs: Any) -> None:
        call_in_child(test, *args, **kwargs)

    return wrapper


def fbx_node_names(path: Any) -> list[str]:
    """The names of every node of an FBX file, read with ufbx in a child."""
    return call_in_child(_node_names, path)


def _node_names(path: Any) -> list[str]:
    import ufbx

    scene = ufbx.load_file(str(path), strict=True)
    nodes = list(scene.nodes)
    return [str(n.name) for n in nodes]

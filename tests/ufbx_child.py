"""Read FBX files with ufbx in a child process that never frees a ufbx object.

The ufbx binding (0.0.5) can crash the interpreter while it frees its wrappers: it
segfaults on a wrapper whose scene is gone, and freeing them in a fixed order (every
wrapper, then the scene) was not enough: one `tests/io` run in about eight under load
still died in `test_fbx`'s clean-up with SIGSEGV, which takes the whole test run
with it. A child made for the reading runs the check, sends back its result (or its
traceback) and leaves with `os._exit`, so no ufbx object is ever freed, and a crash
inside the binding fails one test with a message instead of ending the run.

The child comes from a fork server (``multiprocessing``'s "forkserver": a fresh
single-threaded interpreter that forks the children), not from a fork of the test
process: under load, children forked from the full test run (its BLAS, numba and
decoder threads gone in the child, their state not) died with SIGSEGV three times in
a row in one test that passes alone.
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


_CONTEXT: Any = None


def _context() -> Any:
    """The fork server's context (started on first use, numpy and ufbx preloaded)."""
    global _CONTEXT
    if _CONTEXT is None:
        import multiprocessing

        _CONTEXT = multiprocessing.get_context("forkserver")
        _CONTEXT.set_forkserver_preload(["numpy", "ufbx"])
    return _CONTEXT


def _reference(fn: Callable[..., Any]) -> tuple[str, str]:
    """(module, qualified name) of ``fn``: a test decorated by `in_child` is found
    under its name as the wrapper, and unwrapped in the child."""
    return fn.__module__, fn.__qualname__


def _child(conn: Any, ref: tuple[str, str], args: tuple, kwargs: dict) -> None:
    """The child's body: run, report, and leave without freeing anything."""
    try:
        try:
            import importlib
            import inspect

            obj: Any = importlib.import_module(ref[0])
            for part in ref[1].split("."):
                obj = getattr(obj, part)
            out = (True, inspect.unwrap(obj)(*args, **kwargs))
            data = pickle.dumps(out)
        except BaseException as exc:  # reported to the parent
            data = pickle.dumps((False, "".join(traceback.format_exception(exc))))
        conn.send_bytes(data)
        conn.close()
    finally:
        os._exit(0)


def _call_once(fn: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
    """One run of ``fn`` in a child of the fork server (see :func:`call_in_child`)."""
    ctx = _context()
    recv, send = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_child, args=(send, _reference(fn), args, kwargs))
    proc.start()
    send.close()
    try:
        data = recv.recv_bytes()
    except EOFError:
        data = b""
    proc.join()
    if not data:
        code = proc.exitcode
        if code is not None and code < 0:
            why = signal.Signals(-code).name
        else:
            why = f"exit status {code}"
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

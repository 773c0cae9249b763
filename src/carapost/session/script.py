"""History as a script: the Session calls that made a project, saved with it and replayed.

Every History entry a `carapost.Session` makes is recorded with the call that made it
(method and arguments, as plain JSON values) and with the current frame and selection it
was made at (a menu action without arguments works on those). The record is saved in the
``.cara`` (``script`` in its manifest) and kept across sessions: a project opened again
continues its record. Undone entries are not part of it; Edit > Clear History keeps the
cleared entries' calls (their effect is still in the project).

`to_python` writes the record as a Python script of Session calls (``carapost history
PROJECT.cara --python``); `replay` runs such a script on a take (``carapost replay
SCRIPT.py TAKE -o OUT.cara``). Processing is deterministic, so replaying a project's own
record on its own take reproduces the project array for array.

Examples
--------
>>> from carapost.session.script import to_python
>>> steps = [{"import": {"take_brim": True}},
...          {"call": "set_active_range", "args": [2, 5]}]
>>> print(to_python(steps, name="Demo").split("def replay", 1)[1].splitlines()[2])
    s.set_active_range(2, 5)
"""

from __future__ import annotations

import functools
import inspect
import math
import os
import runpy
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["NOT_RECORDED", "ScriptActions", "literal", "replay", "to_python", "to_plain"]

#: Public Session methods that are not History actions (navigation, queries, files
#: written, the two-step processing machinery, undo itself): never recorded as steps.
NOT_RECORDED = frozenset({
    "open", "import_take", "save", "close", "set_image_source", "get_image",
    "image_source", "push", "group", "undo", "redo", "goto", "history", "clear_history",
    "select", "frame_range", "prepare", "apply", "run", "export_options", "export_c3d",
    "export_fbx", "export_xcp", "missing_files", "script_steps", "has_images", "caddies",
    "current_frame",
})
#: Arguments that are callbacks, live objects or choices of how to compute (the same
#: result either way), not settings: left out of the record.
_DROPPED = frozenset({"progress", "get_image", "images", "relocate", "processes"})


def to_plain(value: Any) -> Any:
    """A JSON-able copy of an argument (arrays and tuples as lists, paths as absolute
    strings, ranges and sets as lists)."""
    if isinstance(value, np.ndarray):
        return to_plain(value.tolist())
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, os.PathLike):
        return str(Path(value).absolute())
    if isinstance(value, dict):
        return {str(k): to_plain(v) for k, v in value.items()}
    if isinstance(value, set | frozenset):
        return [to_plain(v) for v in sorted(value)]
    if isinstance(value, list | tuple | range):
        return [to_plain(v) for v in value]
    if value is None or isinstance(value, bool | int | float | str):
        return value
    raise TypeError(f"cannot record an argument of type {type(value).__name__}")


def literal(value: Any) -> str:
    """Python source for a plain value (NaN and infinities included).

    Examples
    --------
    >>> literal([1.5, float("nan"), {"a": None}])
    "[1.5, float('nan'), {'a': None}]"
    """
    if isinstance(value, float) and not math.isfinite(value):
        return f"float({str(value)!r})"
    if isinstance(value, list):
        return "[" + ", ".join(literal(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k!r}: {literal(v)}" for k, v in value.items()) + "}"
    return repr(value)


def _state(project: Any) -> dict[str, Any]:
    sel = project.selection
    return {"frame": int(project.current_frame), "points": sorted(int(p) for p in sel.points),
            "detections": sorted([int(v) for v in d] for d in sel.detections),
            "cameras": sorted(int(c) for c in sel.cameras)}


class ScriptActions:
    """Mixin of `carapost.Session`: records each History entry's call (see the module).

    Subclassing wraps every public method not in `NOT_RECORDED`: the outermost call
    of an action that adds a History entry is recorded with its arguments.
    """

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        for name, member in list(vars(cls).items()) + [
                (n, m) for base in cls.__mro__[1:] for n, m in vars(base).items()]:
            if name.startswith("_") or name in NOT_RECORDED or name in vars(ScriptActions):
                continue
            if not inspect.isfunction(member) or getattr(member, "_recorded", False):
                continue
            if getattr(cls, name) is not member:  # overridden lower in the MRO
                continue
            setattr(cls, name, _recording(name, member))
        for name in _SPECIAL:
            setattr(cls, name, _SPECIAL[name](getattr(cls, name)))
        original_init = cls.__init__

        @functools.wraps(original_init)
        def __init__(self: Any, *args: Any, **kw: Any) -> None:
            original_init(self, *args, **kw)
            # the steps before this session: those saved with the project, or its import
            script = self.project.script
            self.__dict__["_script_base"] = None if script is None else list(script)

        cls.__init__ = __init__  # type: ignore[method-assign]

    # the record ---------------------------------------------------------------------
    def _script(self) -> dict[str, Any]:
        rec = self.__dict__.get("_script_rec")
        if rec is None:
            rec = {"entries": [], "depth": 0, "prepared": None, "groups": []}
            self.__dict__["_script_rec"] = rec
        return rec

    def script_steps(self) -> list[dict[str, Any]] | None:
        """The record of this project: the steps before this session, then the call of
        every applied History entry; None when the project's origin was not recorded
        (a project made in memory, or saved by a version that did not record)."""
        base = self.__dict__.get("_script_base")  # set by __init__
        if base is None:
            return None
        rec = self._script()
        applied = rec["entries"][: self.stack.position]
        return [*base, *(step for entry in applied for step in entry)]

    def _note(self, name: str, args: list[Any], kwargs: dict[str, Any],
              before: dict[str, Any], position: int) -> None:
        """Record one finished action that started at stack ``position``."""
        rec = self._script()
        step = {"call": name, "args": args, "kwargs": kwargs, "state": before}
        if rec["groups"]:  # inside `with s.group(...)`: part of the group's entry
            rec["groups"][-1]["steps"].append(step)
            return
        if self.stack.position == position + 1:
            del rec["entries"][position:]
            rec["entries"].append([step])


def _bind(func: Callable[..., Any], self: Any, args: tuple, kwargs: dict
          ) -> tuple[list[Any], dict[str, Any]] | None:
    """The arguments as recorded (positional, keyword), or None when unrecordable."""
    try:
        bound = inspect.signature(func).bind(self, *args, **kwargs)
    except TypeError:
        return None
    pos: list[Any] = []
    kw: dict[str, Any] = {}
    params = inspect.signature(func).parameters
    try:
        for name, value in list(bound.arguments.items())[1:]:
            if name in _DROPPED:
                continue
            kind = params[name].kind
            if kind is inspect.Parameter.VAR_POSITIONAL:
                pos.extend(to_plain(v) for v in value)
            elif kind is inspect.Parameter.VAR_KEYWORD:
                kw.update({k: to_plain(v) for k, v in value.items() if k not in _DROPPED})
            elif kind is inspect.Parameter.POSITIONAL_ONLY:
                pos.append(to_plain(value))
            else:
                kw[name] = to_plain(value)
    except TypeError:
        return None
    return pos, kw


def _recording(name: str, func: Callable[..., Any]) -> Callable[..., Any]:
    @functools.wraps(func)
    def wrapper(self: Any, *args: Any, **kwargs: Any) -> Any:
        rec = self._script()
        if rec["depth"]:
            return func(self, *args, **kwargs)
        before = _state(self.project)
        position = self.stack.position
        bound = _bind(func, self, args, kwargs)
        rec["depth"] += 1
        try:
            result = func(self, *args, **kwargs)
        finally:
            rec["depth"] -= 1
        if name.startswith("prepare_"):  # the window's first step: kept until apply
            if bound is not None:
                rec["prepared"] = (name[len("prepare_"):], bound, before)
            return result
        if bound is None:
            bound = ([], {"unrecordable": f"{name}: arguments that cannot be recorded"})
        self._note(name, bound[0], bound[1], before, position)
        return result

    wrapper._recorded = True  # type: ignore[attr-defined]
    return wrapper


def _wrap_prepare(func: Callable[..., Any]) -> Callable[..., Any]:
    @functools.wraps(func)
    def prepare(self: Any, action: str, /, **options: Any) -> Any:
        rec = self._script()
        before = _state(self.project)
        rec["depth"] += 1
        try:
            job = func(self, action, **options)
        finally:
            rec["depth"] -= 1
        if not rec["depth"]:
            try:
                kw = {k: to_plain(v) for k, v in options.items() if k not in _DROPPED}
                rec["prepared"] = (action, ([], kw), before)
            except TypeError:
                rec["prepared"] = (action, ([], {"unrecordable": action}), before)
        return job
    return prepare


def _wrap_apply(func: Callable[..., Any]) -> Callable[..., Any]:
    @functools.wraps(func)
    def apply(self: Any, result: Any) -> Any:
        rec = self._script()
        position = self.stack.position
        outer = not rec["depth"]
        rec["depth"] += 1
        try:
            out = func(self, result)
        finally:
            rec["depth"] -= 1
        if outer and rec["prepared"] is not None:
            action, (args, kw), before = rec["prepared"]
            rec["prepared"] = None
            self._note(action, args, kw, before, position)
        return out
    return apply


def _wrap_group(func: Callable[..., Any]) -> Callable[..., Any]:
    @functools.wraps(func)
    def group(self: Any, description: str) -> Any:
        return _recorded_group(self, func, description)
    return group


@contextmanager
def _recorded_group(self: Any, func: Callable[..., Any], description: str) -> Iterator[Any]:
    rec = self._script()
    position = self.stack.position
    frame = {"group": str(description), "steps": [], "state": _state(self.project)}
    rec["groups"].append(frame)
    try:
        with func(self, description) as grp:
            yield grp
    finally:
        rec["groups"].pop()
    if rec["groups"]:
        rec["groups"][-1]["steps"].append(frame)
    elif self.stack.position == position + 1:
        del rec["entries"][position:]
        rec["entries"].append([frame])


def _wrap_clear(func: Callable[..., Any]) -> Callable[..., Any]:
    @functools.wraps(func)
    def clear_history(self: Any) -> int:
        steps = self.script_steps()
        freed = func(self)
        if steps is not None:  # the cleared entries' effect stays in the project
            self.__dict__["_script_base"] = steps
        self._script()["entries"] = []
        return freed
    return clear_history


def _wrap_save(func: Callable[..., Any]) -> Callable[..., Any]:
    @functools.wraps(func)
    def save(self: Any, *args: Any, **kwargs: Any) -> Any:
        self.project.script = self.script_steps()
        return func(self, *args, **kwargs)
    return save


def _wrap_push(func: Callable[..., Any]) -> Callable[..., Any]:
    @functools.wraps(func)
    def push(self: Any, command: Any) -> Any:
        rec = self._script()
        if rec["depth"]:
            return func(self, command)
        before = _state(self.project)
        position = self.stack.position
        rec["depth"] += 1
        try:
            out = func(self, command)
        finally:
            rec["depth"] -= 1
        # a command built by hand has no call to replay: the script says so
        what = getattr(command, "description", type(command).__name__)
        self._note("push", [], {"unrecordable": f"push({what!r})"}, before, position)
        return out
    return push


_SPECIAL = {"prepare": _wrap_prepare, "apply": _wrap_apply, "group": _wrap_group,
            "clear_history": _wrap_clear, "save": _wrap_save, "push": _wrap_push}


# ======================================================================================
# the script
# ======================================================================================
def _state_lines(state: dict[str, Any], last: dict[str, Any], indent: str) -> list[str]:
    lines = []
    if state["frame"] != last.get("frame"):
        lines.append(f"{indent}s.current_frame = {state['frame']}")
    sel = {k: state[k] for k in ("points", "detections", "cameras")}
    if sel != {k: last.get(k) for k in sel}:
        lines.append(f"{indent}s.select(points={literal(sel['points'])}, "
                     f"detections={literal(sel['detections'])}, "
                     f"cameras={literal(sel['cameras'])})")
    last.update(state)
    return lines


def _step_lines(step: dict[str, Any], last: dict[str, Any], indent: str) -> list[str]:
    lines = _state_lines(step["state"], last, indent) if "state" in step else []
    if "group" in step:
        lines.append(f"{indent}with s.group({step['group']!r}):")
        inner = [ln for sub in step["steps"] for ln in _step_lines(sub, last, indent + "    ")]
        return lines + (inner or [f"{indent}    pass"])
    kw = step.get("kwargs", {})
    if "unrecordable" in kw:
        return lines + [f"{indent}# not replayable: {kw['unrecordable']}"]
    parts = [literal(a) for a in step.get("args", [])]
    parts += [f"{k}={literal(v)}" for k, v in kw.items()]
    return lines + [f"{indent}s.{step['call']}({', '.join(parts)})"]


def to_python(steps: list[dict[str, Any]], *, name: str = "project") -> str:
    """The record of a project as a Python script of Session calls.

    The script defines ``IMPORT`` (the options its take was imported with) and
    ``replay(s)``, the calls in order; run as a program (``python SCRIPT.py TAKE
    OUT.cara``) or by ``carapost replay`` it imports a take, replays and saves.
    """
    from carapost import __version__

    head = steps[0] if steps and "import" in steps[0] else None
    body_steps = steps[1:] if head else steps
    last: dict[str, Any] = {"frame": 0, "points": [], "detections": [], "cameras": []}
    body = [ln for step in body_steps for ln in _step_lines(step, last, "    ")]
    imp = head["import"] if head else {"take_brim": True}
    return "\n".join([
        f'"""History of {name} as carapost Session calls (carapost {__version__}).',
        "",
        "Replay it on another take of the same rig:",
        "",
        "    carapost replay THIS_SCRIPT.py TAKE -o OUT.cara",
        '"""',
        "",
        "from carapost import Session",
        "",
        "#: Session.import_take options of the take this history starts from",
        f"IMPORT = {literal(imp)}",
        "",
        "",
        "def replay(s: Session) -> None:",
        '    """Every History step, with the frame and selection it was made at."""',
        *(body or ["    pass"]),
        "",
        "",
        'if __name__ == "__main__":',
        "    import sys",
        "",
        "    with Session.import_take(sys.argv[1], **IMPORT) as session:",
        "        replay(session)",
        "    session.save(sys.argv[2])",
        "",
    ])


def replay(script: str | os.PathLike[str], take: str | os.PathLike[str],
           output: str | os.PathLike[str]) -> Path:
    """Run a history script (`to_python`) on a take and save the project.

    Raises
    ------
    CaraFileError
        The take cannot be imported or the project not saved.
    ValueError
        The script defines no ``replay(s)``.
    """
    from carapost.export import check_output
    from carapost.session import Session

    out = check_output(output, ".cara")
    ns = runpy.run_path(os.fspath(script), run_name="carapost_replay")
    fn = ns.get("replay")
    if not callable(fn):
        raise ValueError(f"{script}: defines no replay(s) function (write it with "
                         "carapost history PROJECT.cara --python)")
    with Session.import_take(take, **dict(ns.get("IMPORT") or {})) as session:
        fn(session)
    return session.save(out)

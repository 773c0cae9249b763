"""The action table covers every menu item and keyboard shortcut of the reference guide."""

from __future__ import annotations

import inspect
import re
import sys
import types
from functools import partial
from pathlib import Path

import pytest
from PySide6.QtGui import QKeySequence

from carapost.session import PROCESS_ACTIONS, Session
from carapost.ui import actions as table
from carapost.ui.context import ActionContext
from carapost.ui.docks import pane_names

# beside the checkout (``<root>/../shared``), also from a worktree one level deeper
GUIDE = next((p for p in (Path(__file__).resolve().parents[k] / "shared" / "seeds"
                          / "carapost-reference-guide.txt" for k in (3, 4)) if p.exists()),
             Path(__file__).resolve().parents[3] / "shared" / "seeds"
             / "carapost-reference-guide.txt")
MENU_SECTIONS = ("File menu", "Edit menu", "View menu", "Process menu", "Help menu")


@pytest.fixture(scope="module")
def guide_lines() -> list[str]:
    if not GUIDE.exists():
        pytest.skip(f"reference guide not found at {GUIDE}")
    return GUIDE.read_text(encoding="utf-8").splitlines()


def _section(lines: list[str], start: str, end: str) -> list[str]:
    # the second occurrence is the body (the first is the table of contents)
    idx = [i for i, ln in enumerate(lines) if ln.strip() == start]
    i = idx[-1] if len(idx) > 1 else idx[0]
    j = next(k for k in range(i + 1, len(lines)) if lines[k].strip() == end)
    return lines[i + 1:j]


def guide_menu_items(lines: list[str]) -> list[tuple[str, str, str]]:
    """(menu, title, shortcut) of every row of the five menu tables."""
    items = []
    bounds = list(MENU_SECTIONS) + ["Labelling pane"]
    for menu, nxt in zip(bounds[:-1], bounds[1:], strict=True):
        for ln in _section(lines, menu, nxt):
            if "\t" not in ln or ln.startswith("Option\t"):
                continue
            cell = ln.split("\t")[0].strip()
            m = re.match(r"^(.*?)\s*\(([^()]*)\)\s*$", cell)
            title, key = (m.group(1), m.group(2)) if m else (cell, "")
            if title.endswith("]") and "[" not in title:
                title = title[:-1]  # a typo in the guide: "Prev Key Frame]"
            items.append((menu.split()[0], title.strip(), key.strip()))
    return items


def normalise_key(text: str) -> str:
    """'Ctrl + right arrow key' -> the portable QKeySequence text 'Ctrl+Right'."""
    t = re.sub(r"\s*\+\s*", "+", text.strip())
    t = re.sub(r"\b(arrow|key)\b", "", t, flags=re.I).strip()
    t = t.replace("Spacebar", "Space")
    parts = [p.strip() for p in t.split("+")]
    parts = [p[:1].upper() + p[1:] if len(p) > 1 else p.upper() for p in parts]
    return QKeySequence("+".join(parts)).toString()


def guide_shortcuts(lines: list[str]) -> list[tuple[str, str]]:
    """(action, key) of every keyboard-only row of the shortcut tables."""
    rows = []
    for ln in _section(lines, "File management shortcuts", "Supported file formats and standards"):
        if "\t" not in ln:
            continue
        action, key = [c.strip() for c in ln.split("\t")[:2]]
        if action in ("Action", "Viewing option", "Camera view option", "View option",
                      "Navigation option", "Selection option", "Points option"):
            continue
        if re.search(r"click|drag|mouse|wheel|button", key, re.I) or not key:
            continue
        rows.append((action, key))
    return rows


def _norm_title(t: str) -> str:
    return t.replace("...", "").strip().lower()


def test_every_guide_menu_item_is_in_the_table(guide_lines):
    items = guide_menu_items(guide_lines)
    assert len(items) > 90  # the parser found the tables
    ours = {(_norm_title(a.title), a.menu.split("/")[0]) for a in table.ACTIONS if a.title}
    submenus = {a.menu for a in table.ACTIONS}
    missing = []
    for menu, title, _ in items:
        alias = table.GUIDE_ALIASES.get(title, title)
        if "/" in alias:
            if alias not in submenus:
                missing.append(title)
        elif (_norm_title(alias), menu) not in ours:
            missing.append(f"{menu}: {title}")
    assert not missing, f"guide items without an action: {missing}"


def test_every_guide_menu_shortcut_matches(guide_lines):
    by_title = {_norm_title(a.title): a for a in table.ACTIONS if a.title}
    checked = 0
    for _menu, title, key in guide_menu_items(guide_lines):
        if not key:
            continue
        spec = by_title[_norm_title(table.GUIDE_ALIASES.get(title, title))]
        assert QKeySequence(spec.shortcut).toString() == normalise_key(key), title
        checked += 1
    assert checked >= 25


def test_every_keyboard_shortcut_of_the_guide_exists(guide_lines):
    ours = {QKeySequence(a.shortcut).toString() for a in table.ACTIONS if a.shortcut}
    rows = guide_shortcuts(guide_lines)
    assert len(rows) >= 20
    missing = [(action, key) for action, key in rows if normalise_key(key) not in ours]
    assert not missing, f"shortcuts without an action: {missing}"


def test_shortcuts_are_unique_and_ids_unique():
    keys = [QKeySequence(a.shortcut).toString() for a in table.ACTIONS if a.shortcut]
    assert len(keys) == len(set(keys))
    ids = [a.id for a in table.ACTIONS]
    assert len(ids) == len(set(ids))


def test_requirement_check(tmp_path, monkeypatch):
    assert table.requirement_met("")
    assert table.requirement_met("carapost.model.queries:gaps")
    assert not table.requirement_met("carapost.model.queries:no_such_function")
    assert not table.requirement_met("carapost.no_such_module")
    assert not table.requirement_met("carapost.no_such_package.module:thing")
    # a module that exists but is broken fails loudly, it is not "not available"
    (tmp_path / "carapost_broken_module.py").write_text("import carapost_no_such_dependency\n")
    (tmp_path / "carapost_raising_module.py").write_text("raise RuntimeError('broken')\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.raises(ModuleNotFoundError):
        table.requirement_met("carapost_broken_module")
    with pytest.raises(RuntimeError):
        table.requirement_met("carapost_raising_module:x")
    for name in ("carapost_broken_module", "carapost_raising_module"):
        sys.modules.pop(name, None)


def _target(callback):
    """The function a table callback ends in, and the arguments bound to it."""
    args, kwargs = (), {}
    while isinstance(callback, partial):
        args, kwargs = callback.args + args, {**callback.keywords, **kwargs}
        callback = callback.func
    return callback, args, kwargs


def test_every_enabled_entry_has_a_real_callable():
    """Each available item ends in a handler function of carapost.ui.handlers taking the
    ActionContext (and the checked state for toggles), with its bound arguments real."""
    for spec in table.ACTIONS:
        if not spec.title:
            assert spec.callback is None, spec.id  # submenu placeholders do nothing
            continue
        if not spec.available:
            continue
        fn, args, kwargs = _target(spec.callback)
        assert isinstance(fn, types.FunctionType), spec.id
        assert fn.__module__.startswith("carapost.ui.handlers."), (spec.id, fn.__module__)
        sig = inspect.signature(fn)
        extra = ("checked",) if spec.checkable else ()
        bound = sig.bind(*args, "ctx", *extra, **kwargs)  # TypeError if it cannot be called
        ctx_param = next(name for name, value in bound.arguments.items() if value == "ctx")
        assert sig.parameters[ctx_param].annotation in (ActionContext, "ActionContext"), spec.id
        if fn.__name__ == "session_action":
            # a real (unbound) Session method, and options it accepts
            method = args[0]
            assert method.__qualname__ == f"Session.{method.__name__}", spec.id
            assert getattr(Session, method.__name__) is method
            inspect.signature(method).bind("session", **kwargs)
        elif fn.__name__ == "run":
            # a Session Process action whose prepare step takes the bound options
            assert fn.__module__ == "carapost.ui.handlers.process"
            assert kwargs["action"] in PROCESS_ACTIONS and kwargs["title"] == spec.title
            options = {k: v for k, v in kwargs.items() if k not in ("action", "title",
                                                                      "images")}
            if kwargs["images"]:
                options["get_image"] = None
            prepare = getattr(Session, f"prepare_{kwargs['action']}")
            inspect.signature(prepare).bind("session", **options)
        else:
            for value in (*args, *kwargs.values()):  # no method looked up by name
                assert not isinstance(value, str) or spec.id.startswith(
                    ("file.", "edit.detach", "edit.stop", "edit.add_target", "edit.edit_target",
                     "process.brim")), (spec.id, value)


def test_unimplemented_guide_items_are_listed_disabled(make_window):
    missing = {a.id for a in table.menu_items() if not a.available}
    # the features that are still to come (Target Tracker, stabilisation, ...)
    assert missing == {"help.updates"}
    w = make_window()
    for id_ in missing:
        assert not w.action(id_).isEnabled()
        assert w.action(id_).toolTip() == table.NOT_AVAILABLE


#: Items that leave the window, open a browser or start a worker job.
_NOT_TRIGGERED = {"file.exit", "help.online", "help.installed", "view.full_screen",
                  "view.floating", "view.play"}


@pytest.mark.parametrize("with_project", [False, True])
def test_every_item_runs_on_an_empty_and_a_demo_project(make_window, demo, qtbot,
                                                        with_project):
    """Trigger every available item with every dialog cancelled: none may raise (the
    window is strict in tests), refusals are reported instead."""
    w = make_window(*demo) if with_project else make_window()
    if with_project:
        w.project.set_selection(points=[int(w.project.points.ids[0])])
    for spec in table.menu_items():
        if not spec.available or spec.id in _NOT_TRIGGERED:
            continue
        w.action(spec.id).trigger()
        qtbot.waitUntil(lambda: not w.runner.busy, timeout=30_000)
        w.flush()


def test_menus_built_from_the_table(make_window):
    w = make_window()
    for spec in table.menu_items():
        act = w.action(spec.id)
        assert act.text().startswith(spec.title.split("...")[0].strip()) or spec.id in (
            "edit.undo", "edit.redo")
        if spec.shortcut:
            assert act.shortcut().toString() == QKeySequence(spec.shortcut).toString()
        assert act.isEnabled() == spec.available or spec.id in ("edit.undo", "edit.redo")
        if not spec.available:
            assert act.toolTip() == table.NOT_AVAILABLE
    # the unavailable processing items are listed in the Process menu, disabled
    titles = [a.text() for a in w.menus["Process"].actions() if a.text()]
    assert "Interpolate Gaps" in titles and "Track Forwards [Sequence]" in titles
    panels = [a.text() for a in w.menus["View/Panels"].actions()]
    assert panels == pane_names()


def test_third_party_licences_list_the_runtime_dependencies():
    """Help > Show 3rd Party Licenses names what pyproject ships, not test packages."""
    import tomllib

    from carapost.ui.handlers.help import THIRD_PARTY

    root = Path(__file__).resolve().parents[2]
    deps = tomllib.loads((root / "pyproject.toml").read_text())["project"]["dependencies"]
    shipped = {re.split(r"[<>=!~ \[]", d, maxsplit=1)[0].lower() for d in deps}  # no extras
    listed = {name.split(" ")[0].lower() for name, _ in THIRD_PARTY}
    assert listed == shipped and "ezc3d" not in listed

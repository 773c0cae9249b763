"""Opening a take draws the window in slices, one per event-loop turn.

A take that opens changes everything the window shows: four camera views, the panes,
the timebar. Redrawn and painted at once, that was one 100-130 ms turn of the GUI
thread on a quiet 2-core machine (and 200-400 ms under load), in which the window
froze and the decoders' first images could not be shown. `OpenSlices` spreads it out:
while a take opens, each view and pane that would redraw for it *defers* its redraw
(`OpenSlices.defer`), and the deferred redraws then run one per event-loop turn, the
camera views first (so each view is drawn and painted in a turn of its own, as its
image arrives), then the panes. Between two slices the event loop paints what the
last slice changed and delivers the decoders' images.

The window never shows a mix that could be acted on: every user input (mouse, key,
wheel) and every later model change runs the pending slices first, in order, so a
click or a step after opening acts on a window drawn entirely from the new take. A
change of the current frame alone (a jump made by a script, playback) is the one
exception: a view or pane whose redraw is still pending skips it (`covers`), because
that redraw reads the model when it runs and shows the new frame anyway; the others
follow it at once. A hidden window (tests, scripts) paints nothing, so it redraws at
once as before.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable

from PySide6.QtCore import QEvent, QObject, QTimer
from PySide6.QtWidgets import QApplication

from carapost.model.events import Change

__all__ = ["OpenSlices", "defer_while_opening"]

#: A change of these parts alone is shown by a pending redraw (`OpenSlices.covers`).
_FRAME_ONLY = frozenset({"current_frame"})

#: Input events that run every pending slice before they are delivered.
_INPUT_EVENTS = frozenset({
    QEvent.Type.MouseButtonPress, QEvent.Type.MouseButtonDblClick,
    QEvent.Type.KeyPress, QEvent.Type.ShortcutOverride, QEvent.Type.Wheel,
    QEvent.Type.ContextMenu,
})


class OpenSlices(QObject):
    """Redraws deferred while a take opens, run one per event-loop turn.

    Usage (what `ActionContext.set_session` does)::

        slices.begin(visible=window.isVisible())
        ...  # switch the project, emit the changes: listeners call `defer`
        slices.start()  # the deferred redraws run one per turn from now

    Attributes
    ----------
    ran : list of list
        Keys of the slices run, one list per event-loop turn, since `begin` (tests
        check that each view and pane had a turn of its own).
    """

    def __init__(self, parent: QObject | None = None) -> None:
        super().__init__(parent)
        # key -> {part: fn}, in the order the keys were first deferred; a part deferred
        # again replaces the earlier call (the newer change includes it)
        self._steps: dict[Hashable, dict[str, Callable[[], None]]] = {}
        self._collecting = False
        self._filtering = False
        # views whose first image of the take is yet to land (`deliver`)
        self._expected: set[Hashable] = set()
        self._shown_first: set[Hashable] = set()  # their first image is queued or shown
        self.ran: list[list[Hashable]] = []
        self._timer = QTimer(self)
        self._timer.setSingleShot(True)
        self._timer.setInterval(0)
        self._timer.timeout.connect(self._next)

    # -- the opening -----------------------------------------------------------------------
    @property
    def collecting(self) -> bool:
        """A take is being switched to: listeners defer their redraw."""
        return self._collecting

    @property
    def pending(self) -> int:
        """Number of views and panes whose redraw has not run yet."""
        return len(self._steps)

    def begin(self, *, visible: bool) -> None:
        """A take opens: from now on `defer` collects redraws (only when ``visible``:
        a hidden window redraws at once). Slices still pending from an earlier opening
        are dropped: every view and pane redraws for this take anyway."""
        self._steps.clear()
        self._stop_if_done()
        self.ran = []
        self._collecting = bool(visible)
        self._expected = set()
        self._shown_first = set()

    def start(self, images: list[Hashable] | tuple[Hashable, ...] = ()) -> None:
        """The switch is done: run the deferred redraws one per turn from the next.

        ``images`` are the camera views whose first image of the take is awaited:
        each is shown in a turn of its own too (`deliver`), even when the decoders
        deliver all four at once.
        """
        if self._collecting and self._steps:
            self._expected = set(images)
        self._collecting = False
        if self._steps:
            self._watch_input(True)
            self._timer.start()

    def deliver(self, key: Hashable, fn: Callable[[], None]) -> bool:
        """The first image of the camera view ``key`` landed: show it in the next
        turn (``fn``), ahead of the slices of views still without an image; when the
        view's redraw is still pending, that redraw shows the image instead. False
        when this is not the view's first image of an opening: show it now."""
        if key not in self._expected:
            return False
        self._expected.discard(key)
        parts = self._steps.pop(key, None)
        if parts is None:
            parts = {"image": fn}
        # first in line after the views already given their image
        items = list(self._steps.items())
        head = [kv for kv in items if kv[0] in self._shown_first]
        tail = [kv for kv in items if kv[0] not in self._shown_first]
        self._steps = dict(head + [(key, parts)] + tail)
        self._shown_first.add(key)
        if not self._timer.isActive():
            self._watch_input(True)
            self._timer.start()
        return True

    def defer(self, key: Hashable, fn: Callable[[], None], part: str = "refresh") -> bool:
        """Defer ``fn`` to the slice of ``key`` (a view or pane) while collecting.

        Returns False when not collecting: the caller then runs its redraw now.
        Several parts of one key (a view's fit, then its refresh) run in one slice,
        in the order first deferred.
        """
        if not self._collecting:
            return False
        self._steps.setdefault(key, {})[part] = fn
        return True

    def run(self, key: Hashable) -> bool:
        """Run the slice of ``key`` now, out of turn (its camera's image arrived);
        False when it has none pending."""
        parts = self._steps.pop(key, None)
        if parts is None:
            return False
        self.ran.append([key])
        self._run_parts(parts)
        self._stop_if_done()
        return True

    def flush(self) -> None:
        """Run every pending slice now, in order (user input, a later change, a
        benchmark or test that waits for the window to be drawn)."""
        if self._collecting:
            return
        self._expected.clear()  # after input or a change, images show as they land
        if not self._steps:
            return
        keys = list(self._steps)
        self.ran.append(keys)
        while self._steps:
            key = next(iter(self._steps))
            self._run_parts(self._steps.pop(key))
        self._stop_if_done()

    def covers(self, key: Hashable, change: Change | None) -> bool:
        """Whether the pending redraw of ``key`` will show ``change`` (a change of the
        current frame alone): the listener skips it."""
        return (key in self._steps and change is not None and change.parts is not None
                and change.parts <= _FRAME_ONLY)

    def hold(self, key: Hashable, change: Change | None, fn: Callable[[], None]) -> bool:
        """The rule every listener follows while a take opens: a change of the file
        defers ``fn`` (the redraw of ``key``) to its slice, and a change of the
        current frame alone is skipped when ``key``'s pending redraw will show it.

        Returns True when the listener must not redraw now.
        """
        if (change is not None and change.parts is not None and "file" in change.parts
                and self.defer(key, fn)):
            return True
        return self.covers(key, change)

    def change_arrived(self, change: Change) -> None:
        """Slot for the views' ``changed`` (connected before every listener): a change
        after the opening's own is shown on a window drawn from the new take (a frame
        change alone is left to the pending redraws, see `covers`)."""
        if self._collecting:
            return
        if change is not None and change.parts is not None and change.parts <= _FRAME_ONLY:
            return
        self.flush()

    # -- running ---------------------------------------------------------------------------
    def _next(self) -> None:
        if not self._steps:
            self._stop_if_done()
            return
        key = next(iter(self._steps))
        self.ran.append([key])
        self._run_parts(self._steps.pop(key))
        if self._steps:
            self._timer.start()  # the next slice in the next turn, after this one's paint
        else:
            self._stop_if_done()

    @staticmethod
    def _run_parts(parts: dict[str, Callable[[], None]]) -> None:
        for fn in parts.values():
            try:
                fn()
            except RuntimeError:  # the widget is gone already (its window closed)
                pass

    def _stop_if_done(self) -> None:
        if not self._steps:
            self._timer.stop()
            self._watch_input(False)

    def _watch_input(self, on: bool) -> None:
        app = QApplication.instance()
        if app is None or on == self._filtering:
            return
        if on:
            app.installEventFilter(self)
        else:
            app.removeEventFilter(self)
        self._filtering = on

    def eventFilter(self, watched: QObject, event: QEvent) -> bool:
        if event.type() in _INPUT_EVENTS and self._steps:
            self.flush()
        return False


def defer_while_opening(slot: Callable[..., None]) -> Callable[..., None]:
    """Decorate a pane's ``changed`` slot: a take opening defers it to a slice of its
    own (see the module docstring). The pane's ``ctx`` is the window's context
    (``ctx.view.opening``) or the views' context (``ctx.opening``)."""

    def wrapper(self, change: Change | None, *args, **kwargs) -> None:
        ctx = getattr(self.ctx, "view", self.ctx)
        slices: OpenSlices | None = getattr(ctx, "opening", None)
        if slices is not None and slices.hold(
                self, change, lambda: slot(self, change, *args, **kwargs)):
            return
        slot(self, change, *args, **kwargs)

    wrapper.__name__ = slot.__name__
    wrapper.__qualname__ = slot.__qualname__
    wrapper.__doc__ = slot.__doc__
    wrapper.__wrapped__ = slot  # type: ignore[attr-defined]
    return wrapper

"""Console progress of the command line: one bar per stage on a terminal, plain lines
otherwise (a log file, a pipe, a batch system's output).

``rich`` draws the bars when it is installed and the stream is a terminal; without it,
or when the output is redirected, each stage prints a line every 10 % (at most one every
two seconds) and one when it ends, so a log stays short and readable::

    with ConsoleProgress() as bars:
        detect_all(session, bars.stage("Detect blobs"))
        track_all(session, progress=bars.stage("Track"))
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from typing import IO, Any

__all__ = ["ConsoleProgress", "ProgressCallback", "format_progress", "terminal_progress"]

#: ``progress(done, total) -> bool``: False cancels.
ProgressCallback = Callable[[int, int], bool]


class ConsoleProgress:
    """Progress bars of the stages of one command.

    Parameters
    ----------
    stream : file, optional
        Where to draw (default ``sys.stderr``: stdout stays for results).
    bars : bool, optional
        Force bars (True) or plain lines (False); default: bars on a terminal when
        ``rich`` is available.
    quiet : bool
        Print nothing.
    """

    def __init__(self, stream: IO[str] | None = None, *, bars: bool | None = None,
                 quiet: bool = False) -> None:
        self.stream = stream if stream is not None else sys.stderr
        self.quiet = quiet
        if bars is None:
            isatty = getattr(self.stream, "isatty", None)
            bars = bool(isatty and isatty())
        self._rich: Any = None
        if bars and not quiet:
            try:
                from rich.console import Console
                from rich.progress import (
                    BarColumn,
                    MofNCompleteColumn,
                    Progress,
                    TextColumn,
                    TimeElapsedColumn,
                    TimeRemainingColumn,
                )
            except ImportError:
                pass
            else:
                self._rich = Progress(
                    TextColumn("{task.description:<22}"), BarColumn(), MofNCompleteColumn(),
                    TimeElapsedColumn(), TimeRemainingColumn(),
                    console=Console(file=self.stream), transient=False)
        self._task: Any = None
        self._started = 0.0
        self._name = ""
        self._last_line = (-1, 0.0)

    # -- context ---------------------------------------------------------------------------
    def __enter__(self) -> ConsoleProgress:
        if self._rich is not None:
            self._rich.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """End the current stage and stop drawing."""
        self._finish()
        if self._rich is not None:
            self._rich.stop()

    def say(self, text: str) -> None:
        """Print a line above the bars."""
        if self.quiet:
            return
        if self._rich is not None:
            self._rich.console.print(text, markup=False, highlight=False)
        else:
            print(text, file=self.stream, flush=True)

    # -- stages ----------------------------------------------------------------------------
    def stage(self, name: str, total: int | None = None) -> ProgressCallback:
        """Start a stage (ending the previous one); returns its ``progress(done, total)``."""
        self._finish()
        self._name = name
        self._started = time.monotonic()
        self._last_line = (-1, 0.0)
        if self._rich is not None:
            self._task = self._rich.add_task(name, total=total)
        return self._update

    def _update(self, done: int, total: int) -> bool:
        if self.quiet:
            return True
        if self._rich is not None:
            self._rich.update(self._task, completed=done, total=max(total, 1))
            return True
        tenth = 10 * done // max(total, 1)
        now = time.monotonic()
        last_tenth, last_time = self._last_line
        if tenth != last_tenth and (now - last_time >= 2.0 or done >= total):
            self._last_line = (tenth, now)
            if done < total:
                print(f"{self._name}: {done}/{total} ({10 * tenth} %)", file=self.stream,
                      flush=True)
        return True

    def _finish(self) -> None:
        if not self._name:
            return
        seconds = time.monotonic() - self._started
        if self._rich is not None and self._task is not None:
            task = self._rich.tasks[-1]
            self._rich.update(self._task, completed=task.total or 1, total=task.total or 1)
        elif not self.quiet:
            print(f"{self._name}: done in {seconds:.1f} s", file=self.stream, flush=True)
        self._name = ""
        self._task = None


def format_progress(state: dict[str, Any], width: int = 30) -> str:
    """One terminal line of ``carapost batch``: a bar of finished takes, the counts and
    the ETA.

    Examples
    --------
    >>> format_progress({"total": 8, "done": 3, "failed": 1, "skipped": 0, "running": 2,
    ...                  "elapsed_s": 12.0, "eta_s": 12.0}, width=8)
    '[####----] 4/8 takes  3 done  1 failed  0 skipped  ETA 0:12'
    """
    total = max(int(state["total"]), 1)
    ended = state["done"] + state["failed"] + state["skipped"]
    fill = int(round(width * ended / total))
    eta = state.get("eta_s")
    eta_text = "--:--" if eta is None else f"{int(eta) // 60}:{int(eta) % 60:02d}"
    return (f"[{'#' * fill}{'-' * (width - fill)}] {ended}/{state['total']} takes  "
            f"{state['done']} done  {state['failed']} failed  {state['skipped']} skipped  "
            f"ETA {eta_text}")


def terminal_progress(stream: Any = None) -> Callable[[dict[str, Any]], None]:
    """A `carapost.batch.BatchProgress` that draws `format_progress` on a terminal (one
    line redrawn) or, when ``stream`` is not a terminal, writes a line per finished
    take."""
    stream = stream or sys.stderr
    tty = hasattr(stream, "isatty") and stream.isatty()

    def show(state: dict[str, Any]) -> None:
        line = format_progress(state)
        stream.write(("\r" + line) if tty else line + "\n")
        if tty and state["done"] + state["failed"] + state["skipped"] >= state["total"]:
            stream.write("\n")
        stream.flush()

    return show

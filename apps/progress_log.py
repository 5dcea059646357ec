"""Progress bars in a log: when stderr is not a terminal (a file, a pipe, a CI log), a bar's carriage-return
updates become whole lines, at most one every few seconds, so that one command's log stays readable and small.

tqdm redraws a bar by writing ``"\\r" + text`` many times a second; a terminal overwrites the line, a log file keeps
every redraw. :class:`LineProgress` wraps the stream: text that ends with a newline passes through at once (log
messages, printed lines), and a redrawn line is written as its own line only when ``every`` seconds have passed
since the last one, and once more when the bar ends (its last state), so the log shows where the work stood.

Example::

    with line_progress():  # in the CLI's main, around the command
        run_command(args)
"""

from __future__ import annotations

import contextlib
import io
import os
import re
import sys
import time
from collections.abc import Callable, Iterator

EVERY_S = 5.0  # seconds between two progress lines in a log (FLUIDGS_PROGRESS_SECONDS)
_TERMINATORS = re.compile(r"(\r|\n)")


class LineProgress(io.TextIOBase):
    """A text stream over ``stream`` that turns carriage-return redraws into lines, one per ``every`` seconds.

    Args:
        stream: where the lines go (the real stderr).
        every: the least seconds between two progress lines (the bar's last state is written whatever the time).
        clock: seconds, monotonic (for the tests).
    """

    def __init__(self, stream, every: float = EVERY_S, clock: Callable[[], float] = time.monotonic):
        super().__init__()
        self.stream, self.every, self.clock = stream, float(every), clock
        self.line = ""  # the text since the last terminator
        self.redrawn = False  # the current line started with a carriage return: a bar's redraw
        self.pending = ""  # the last redraw not yet written
        self.last = -float("inf")  # when the last progress line was written
        self.emitted = ""  # and what it said

    def writable(self) -> bool:
        return True

    def isatty(self) -> bool:
        return False

    def write(self, text: str) -> int:
        for piece in _TERMINATORS.split(text):
            if piece == "\n":
                self._end_line()
            elif piece == "\r":
                self._redraw()
            else:
                self.line += piece
        if self.redrawn and self.line.strip():
            self.pending = self.line.strip()
            if self.clock() - self.last >= self.every:
                self._emit_pending()
        self.stream.flush()
        return len(text)

    def flush(self) -> None:
        self.stream.flush()

    def close_bars(self) -> None:
        """Write the last redraw that was held back (the end of the command)."""
        self._emit_pending()
        self.stream.flush()

    # ---- the line state ------------------------------------------------------------------------------------------
    def _emit_pending(self) -> None:
        if self.pending and self.pending != self.emitted:
            self.stream.write(self.pending + "\n")
            self.emitted, self.last = self.pending, self.clock()
        self.pending = ""

    def _redraw(self) -> None:
        if not self.redrawn and self.line:  # plain text overwritten by a bar: keep it as its own line
            self.stream.write(self.line + "\n")
        elif self.redrawn and not self.line.strip():  # a bar cleared its line (leave=False): its last state stays
            self._emit_pending()
        self.line, self.redrawn = "", True

    def _end_line(self) -> None:
        if self.redrawn:  # a bar that ends its line (leave=True): its final state, unless it was just written
            self.pending = self.line.strip() or self.pending
            self._emit_pending()
        else:
            self.stream.write(self.line + "\n")
        self.line, self.redrawn = "", False


def progress_every() -> float:
    """Seconds between two progress lines in a log: ``FLUIDGS_PROGRESS_SECONDS`` (default 5)."""
    raw = os.environ.get("FLUIDGS_PROGRESS_SECONDS", "")
    try:
        value = float(raw) if raw else EVERY_S
    except ValueError:
        value = EVERY_S
    return value if value >= 0 else EVERY_S


@contextlib.contextmanager
def line_progress() -> Iterator[None]:
    """While stderr is not a terminal, route it through :class:`LineProgress` (progress bars made at that time
    write to it); a terminal keeps its redrawn bars."""
    real = sys.stderr
    if real is None or real.isatty():
        yield
        return
    wrapper = LineProgress(real, progress_every())
    sys.stderr = wrapper
    try:
        yield
    finally:
        wrapper.close_bars()
        sys.stderr = real

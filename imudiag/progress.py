"""A progress bar on standard error for long commands, drawn only on a terminal.

One line redrawn in place with ``\\r``: what the command is doing, a bar of the fraction
done (samples read of the log's samples, or the position in the file, or samples
simulated of those asked for), the percentage and the samples so far. Redraws are
rate-limited (:data:`MIN_REDRAW_S`), except the first of each phase (a new ``what``), which
is always drawn so that a short phase is named however fast the machine. The line is cleared
when the work ends, so the command's own output starts on a clean line. Nothing at all is
written when the stream is not a terminal (a pipe, a file) or when the user asked for
``--quiet``. Standard library only: the daemon's runtime dependencies stay numpy, pyserial
and pyyaml.
"""

from __future__ import annotations

import shutil
import sys
import time
from types import TracebackType
from typing import TextIO

#: Shortest time between two redraws, s.
MIN_REDRAW_S = 0.1
#: Characters of the bar itself (shrunk on a narrow terminal).
BAR_WIDTH = 30


def _count(n: int) -> str:
    """``n`` samples in a few characters: 950, 12.3k, 4.56M."""
    if n < 1000:
        return str(n)
    if n < 1_000_000:
        return f"{n / 1000:.1f}k"
    return f"{n / 1e6:.2f}M"


class Progress:
    """A progress line on ``stream`` (default standard error) for the command ``name``.

    ``enabled``: draw at all (default: when ``stream`` is a terminal). Call
    :meth:`update` as work proceeds (cheap when nothing is drawn) and :meth:`close` at the
    end (or use it as a context manager); the bar is then cleared.
    """

    def __init__(
        self,
        name: str,
        stream: TextIO | None = None,
        enabled: bool | None = None,
        min_redraw_s: float = MIN_REDRAW_S,
    ) -> None:
        self.name = name
        self.stream = stream if stream is not None else sys.stderr
        if enabled is None:
            try:
                enabled = self.stream.isatty()
            except (AttributeError, ValueError, OSError):
                enabled = False
        self.enabled = bool(enabled)
        self.min_redraw_s = min_redraw_s
        self.redraws = 0  #: lines drawn so far
        self._last = -float("inf")
        self._what: str | None = None  # the phase last drawn
        self._width = 0  # characters of the line on screen

    def update(self, what: str, fraction: float | None, done: int = 0) -> None:
        """Now doing ``what``, ``fraction`` (0..1, None when unknown) done, ``done`` samples.
        Drawn at most every ``min_redraw_s`` s within a phase, always when ``what`` changes."""
        if not self.enabled:
            return
        now = time.monotonic()
        if what == self._what and now - self._last < self.min_redraw_s:
            return
        self._last = now
        self._what = what
        columns = shutil.get_terminal_size((80, 24)).columns
        head = f"imudiag {self.name}: {what} "
        tail = f" {_count(done)} samples" if done else ""
        if fraction is not None:
            f = min(1.0, max(0.0, float(fraction)))
            width = max(10, min(BAR_WIDTH, columns - len(head) - len(tail) - 9))
            full = int(round(f * width))
            line = f"{head}[{'#' * full}{'.' * (width - full)}] {100 * f:3.0f}%{tail}"
        else:
            line = f"{head}...{tail}"
        line = line[: max(1, columns - 1)]
        self._write("\r" + line + " " * max(0, self._width - len(line)))
        self._width = len(line)
        self.redraws += 1

    def close(self) -> None:
        """Clear the line (if anything was drawn)."""
        if self.enabled and self._width:
            self._write("\r" + " " * self._width + "\r")
            self._width = 0

    def _write(self, text: str) -> None:
        try:
            self.stream.write(text)
            self.stream.flush()
        except (OSError, ValueError):  # the terminal went away: stop drawing
            self.enabled = False

    def __call__(self, what: str, fraction: float | None, done: int = 0) -> None:
        self.update(what, fraction, done)

    def __enter__(self) -> Progress:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


def for_command(name: str, quiet: bool = False) -> Progress:
    """The progress line of command ``name``: drawn on standard error when it is a terminal
    and ``quiet`` is false."""
    return Progress(name, enabled=False if quiet else None)


__all__ = ["BAR_WIDTH", "MIN_REDRAW_S", "Progress", "for_command"]

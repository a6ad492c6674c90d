"""A one-line progress bar on standard error, redrawn with carriage returns.

It draws only when standard error is a terminal (and the user did not ask for quiet), so
logs and pipes never fill with bar frames.
"""

from __future__ import annotations

import shutil
import sys
from typing import TextIO


class Progress:
    """A bar of `done` out of `total` units with a short label."""

    def __init__(self, total: int, *, quiet: bool = False, stream: TextIO | None = None):
        self.stream = stream or sys.stderr
        self.total = max(int(total), 1)
        self.enabled = not quiet and _isatty(self.stream)
        self._shown = False

    def update(self, done: int, label: str = "") -> None:
        """Redraw the bar at `done` units with `label` after it."""
        if not self.enabled:
            return
        width = shutil.get_terminal_size((80, 20)).columns
        done = min(max(done, 0), self.total)
        cells = 24
        filled = cells * done // self.total
        head = f"[{'#' * filled}{'.' * (cells - filled)}] {100 * done // self.total:3d}% "
        line = (head + label)[: width - 1]
        self.stream.write("\r" + line.ljust(width - 1))
        self.stream.flush()
        self._shown = True

    def clear(self) -> None:
        """Erase the bar so that the next message starts on a clean line."""
        if self._shown:
            width = shutil.get_terminal_size((80, 20)).columns
            self.stream.write("\r" + " " * (width - 1) + "\r")
            self.stream.flush()
            self._shown = False

    def message(self, text: str) -> None:
        """Print a line above the bar (the bar is redrawn by the next update)."""
        self.clear()
        print(text, file=self.stream, flush=True)


def _isatty(stream: TextIO) -> bool:
    try:
        return stream.isatty()
    except (AttributeError, ValueError):  # closed or not a real file
        return False

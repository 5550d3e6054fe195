"""A dependency-free, tqdm-style progress bar on standard error."""

from __future__ import annotations

import sys
import time
from typing import TextIO


class ProgressBar:
    """Text progress bar: ``label |#####.....| 12/40 [3.1s<7.2s]``.

    On a terminal the bar is redrawn in place at most 10 times a second; elsewhere (CI logs)
    a line is printed every 10 % so logs stay short.  Use as a context manager.

    Parameters
    ----------
    total : int
        Number of units of work.
    label : str
        Text in front of the bar.
    enabled : bool
        ``False`` prints nothing.
    stream : file-like, optional
        Where to write (standard error by default).
    """

    def __init__(self, total: int, label: str = "", enabled: bool = True, stream: TextIO | None = None):
        self.total = max(int(total), 1)
        self.label = label
        self.enabled = enabled
        self.stream = stream if stream is not None else sys.stderr
        self.count = 0
        self.postfix = ""
        self._start = time.perf_counter()
        self._last_draw = 0.0
        self._last_decile = -1
        self._interactive = bool(getattr(self.stream, "isatty", lambda: False)())

    def __enter__(self) -> ProgressBar:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def update(self, count: int = 1, postfix: str | None = None) -> None:
        """Advance by ``count`` units; ``postfix`` is shown after the timing."""
        self.count = min(self.count + count, self.total)
        if postfix is not None:
            self.postfix = postfix
        if not self.enabled:
            return
        now = time.perf_counter()
        if self._interactive:
            if now - self._last_draw >= 0.1 or self.count == self.total:
                self._last_draw = now
                self.stream.write("\r" + self._line(now))
                self.stream.flush()
        else:
            decile = int(10 * self.count / self.total)
            if decile != self._last_decile:
                self._last_decile = decile
                self.stream.write(self._line(now) + "\n")
                self.stream.flush()

    def _line(self, now: float) -> str:
        width = 30
        filled = int(width * self.count / self.total)
        elapsed = now - self._start
        remaining = elapsed / self.count * (self.total - self.count) if self.count else float("nan")
        bar = "#" * filled + "." * (width - filled)
        text = f"{self.label} |{bar}| {self.count}/{self.total} [{elapsed:.1f}s<{remaining:.1f}s]"
        return f"{text} {self.postfix}".rstrip()

    def close(self) -> None:
        """Finish the line on a terminal."""
        if self.enabled and self._interactive:
            self.stream.write("\n")
            self.stream.flush()

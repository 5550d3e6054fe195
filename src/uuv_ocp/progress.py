"""Progress bars of long runs (closed loops, campaigns), drawn by tqdm on standard error.

A bar is drawn where someone watches: on a terminal, or as a widget in a Jupyter notebook.
Elsewhere (a CI log, output redirected to a file) nothing is printed unless asked for, with
``force=True`` or the environment variable ``UUV_OCP_PROGRESS``:

``UUV_OCP_PROGRESS=always``
    draw bars even when standard error is not a terminal (one line at most every 30 s, no
    carriage returns, so logs stay short and readable);
``UUV_OCP_PROGRESS=never``
    draw no bar at all, whatever the callers ask for;
``UUV_OCP_PROGRESS=auto`` (or unset)
    the default just described.

tqdm is imported only when a bar is actually drawn, so ``import uuv_ocp`` does not pay for it.
"""

from __future__ import annotations

import os
import sys
import threading
import time
from typing import Any, TextIO

ENVIRONMENT_VARIABLE = "UUV_OCP_PROGRESS"
_MODES = ("auto", "always", "never")

__all__ = ["ENVIRONMENT_VARIABLE", "ProgressBar", "SlowNotice", "drawn"]


def _mode() -> str:
    mode = os.environ.get(ENVIRONMENT_VARIABLE, "auto").strip().lower() or "auto"
    return mode if mode in _MODES else "auto"


def _is_terminal(stream: object) -> bool:
    isatty = getattr(stream, "isatty", None)
    try:
        return bool(isatty()) if callable(isatty) else False
    except ValueError:  # a closed stream
        return False


def _in_notebook() -> bool:
    """Whether tqdm would draw a Jupyter widget (checked without importing tqdm otherwise)."""
    if "ipykernel" not in sys.modules:
        return False
    import tqdm.auto  # noqa: F401  (imports tqdm.autonotebook with its warning silenced)
    from tqdm.autonotebook import tqdm as notebook_tqdm
    from tqdm.std import tqdm as std_tqdm

    return notebook_tqdm is not std_tqdm


def drawn(enabled: bool = True, stream: TextIO | None = None, *, force: bool = False) -> bool:
    """Whether a :class:`ProgressBar` with these arguments would draw (module doc).

    For messages that belong with the bars, e.g. the command line's "building the
    controller" line before a run's bar: shown exactly where the bars are.
    """
    target = stream if stream is not None else sys.stderr
    interactive = (stream is None and _in_notebook()) or _is_terminal(target)
    mode = _mode()
    return bool(enabled) and mode != "never" and (interactive or force or mode == "always")


def _terminal_size(stream: object) -> os.terminal_size | None:
    """Size of the terminal behind ``stream`` (columns, lines), or ``None`` if it has none."""
    try:
        return os.get_terminal_size(stream.fileno())  # type: ignore[attr-defined]
    except (AttributeError, OSError, ValueError):
        return None


class _LogLines:
    """A log file as tqdm sees it: each redraw becomes a line of its own, carriage returns dropped."""

    def __init__(self, stream: TextIO) -> None:
        self.stream = stream
        self.encoding = getattr(stream, "encoding", None)

    def write(self, text: str) -> int:
        line = text.replace("\r", "").rstrip()
        if line:
            self.stream.write(line + "\n")
        return len(text)

    def flush(self) -> None:
        self.stream.flush()


class ProgressBar:
    """Progress of ``total`` units of work: ``label:  30%|███       | 12/40 [00:03<00:07, fail=0]``.

    Use as a context manager.  Where the bar is not drawn (``enabled=False``, or standard
    error is not a terminal and nothing asked for it) only :attr:`count` is kept.

    Parameters
    ----------
    total : int
        Number of units of work.
    label : str
        Text in front of the bar.
    enabled : bool
        ``False`` draws nothing.  ``True`` draws on a terminal or in a notebook.
    stream : file-like, optional
        Where to write (standard error by default).
    force : bool
        Draw even when ``stream`` is not a terminal (as ``UUV_OCP_PROGRESS=always`` does).
    initial : int
        Units already done before this run (e.g. resumed trials): they count towards the bar
        but not towards the rate, so the estimated time left is that of the work still to do.

    Notes
    -----
    The time left is the remaining units at the average rate of this run (tqdm's
    ``smoothing=0``).  Closed-loop steps and campaign trials cost roughly the same each, and
    trials of a process pool finish in bursts, so an average is steadier than tqdm's default
    moving average of recent rates.
    """

    def __init__(
        self,
        total: int,
        label: str = "",
        enabled: bool = True,
        stream: TextIO | None = None,
        *,
        force: bool = False,
        initial: int = 0,
    ) -> None:
        self.total = max(int(total), 1)
        self.label = label
        self.stream = stream if stream is not None else sys.stderr
        self.count = min(max(int(initial), 0), self.total)
        self.postfix = ""
        notebook = stream is None and _in_notebook()
        interactive = notebook or _is_terminal(self.stream)
        self.enabled = drawn(enabled, stream, force=force)
        self._bar: Any = None
        if not self.enabled:
            return
        options: dict[str, Any] = {
            "total": self.total,
            "initial": self.count,
            "desc": label or None,
            "smoothing": 0.0,
            "dynamic_ncols": True,
            "leave": True,
        }
        if notebook:
            from tqdm.auto import tqdm as notebook_tqdm

            self._bar = notebook_tqdm(**options)
            return
        from tqdm.std import tqdm

        if interactive:
            options.update(file=self.stream, mininterval=0.1)
            size = _terminal_size(self.stream)
            if size is not None and 0 in size:  # a pty of no size (script, some CI): tqdm drew nothing
                options.update(dynamic_ncols=False, ncols=size.columns or 80, nrows=size.lines or 20)
        else:
            options.update(
                file=_LogLines(self.stream),
                mininterval=30.0,
                maxinterval=float("inf"),  # tqdm's monitor must not force extra lines
                ncols=80,
                ascii=True,
            )
        self._bar = tqdm(**options)

    def __enter__(self) -> ProgressBar:
        """Return the bar itself."""
        return self

    def __exit__(self, *exc: object) -> None:
        """Close the bar, also when the block raised (e.g. ``KeyboardInterrupt``)."""
        self.close()

    def update(self, count: int = 1, postfix: str | None = None) -> None:
        """Advance by ``count`` units; ``postfix`` is shown after the timing."""
        step = min(int(count), self.total - self.count)
        self.count += step
        if postfix is not None:
            self.postfix = postfix
        if self._bar is None:
            return
        if postfix is not None:
            self._bar.set_postfix_str(postfix, refresh=False)
        self._bar.update(step)

    def close(self) -> None:
        """Finish the bar (idempotent)."""
        if self._bar is not None:
            self._bar.close()
            self._bar = None


class SlowNotice:
    """Say on standard error what is being done when it takes longer than ``delay`` seconds.

    Use as a context manager around work that is usually quick but can be slow (a C compile
    on first use, a warm-up that compiles): one line, the text once ``delay`` has passed, then
    ``done in <s> s`` when the work ends; nothing at all for quick work.  Drawn where the
    progress bars are (a terminal, a notebook, ``UUV_OCP_PROGRESS=always``; never with
    ``UUV_OCP_PROGRESS=never``).

    Parameters
    ----------
    text : str
        What is being done, e.g. ``"compiling uuv_ocp_rti (first use; cached afterwards)"``.
    delay : float
        Seconds before the line appears.
    stream : file-like, optional
        Where to write (standard error by default).
    """

    def __init__(self, text: str, delay: float = 1.0, stream: TextIO | None = None) -> None:
        self.text = text
        self.delay = float(delay)
        self.stream = stream if stream is not None else sys.stderr
        self.enabled = drawn(True, stream)
        self._timer: threading.Timer | None = None
        self._shown = threading.Event()
        self._start = 0.0

    def _show(self) -> None:
        self.stream.write(f"{self.text} ...")
        self.stream.flush()
        self._shown.set()

    def __enter__(self) -> SlowNotice:
        """Start the clock (and the timer of the line)."""
        self._start = time.perf_counter()
        if self.enabled:
            self._timer = threading.Timer(self.delay, self._show)
            self._timer.daemon = True
            self._timer.start()
        return self

    def __exit__(self, *exc: object) -> None:
        """Stop the timer; end the line with the time taken if it was shown."""
        if self._timer is not None:
            self._timer.cancel()
            self._timer.join()
        if self._shown.is_set():
            self.stream.write(f" done in {time.perf_counter() - self._start:.1f} s\n")
            self.stream.flush()

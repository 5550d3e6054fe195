"""Progress bars: tqdm on a terminal, silence in logs unless asked, counts kept either way."""

import io

import pytest

from uuv_ocp.progress import ENVIRONMENT_VARIABLE, ProgressBar


class Terminal(io.StringIO):
    def isatty(self):
        return True


@pytest.fixture(autouse=True)
def _default_mode(monkeypatch):
    monkeypatch.delenv(ENVIRONMENT_VARIABLE, raising=False)


def test_a_terminal_gets_a_bar_with_label_count_and_postfix():
    stream = Terminal()
    with ProgressBar(4, "s2 ipopt", stream=stream) as bar:
        for _ in range(4):
            bar.update(1, postfix="fail=0")
    text = stream.getvalue()
    assert bar.enabled and bar.count == 4
    assert "s2 ipopt" in text and "4/4" in text and "fail=0" in text
    assert text.endswith("\n")


def test_a_log_gets_nothing_unless_asked(monkeypatch):
    stream = io.StringIO()
    with ProgressBar(3, "quiet", stream=stream) as bar:
        bar.update(3)
    assert not bar.enabled and bar.count == 3 and stream.getvalue() == ""

    forced = io.StringIO()
    with ProgressBar(3, "forced", stream=forced, force=True) as bar:
        bar.update(3)
    assert "\r" not in forced.getvalue() and "3/3" in forced.getvalue().splitlines()[-1]

    monkeypatch.setenv(ENVIRONMENT_VARIABLE, "always")
    asked = io.StringIO()
    with ProgressBar(2, "asked", stream=asked) as bar:
        bar.update(2)
    assert "2/2" in asked.getvalue()


def test_disabled_and_never_draw_nothing(monkeypatch):
    stream = Terminal()
    with ProgressBar(2, "off", enabled=False, stream=stream, force=True) as bar:
        bar.update(2)
    assert stream.getvalue() == ""
    monkeypatch.setenv(ENVIRONMENT_VARIABLE, "never")
    with ProgressBar(2, "off", stream=stream) as bar:
        bar.update(2)
    assert not bar.enabled and stream.getvalue() == ""


def test_resumed_units_count_and_the_total_caps_the_count():
    stream = Terminal()
    with ProgressBar(5, "campaign", stream=stream, initial=3) as bar:
        bar.update(10)
    assert bar.count == 5
    assert "5/5" in stream.getvalue()
    assert ProgressBar(0, enabled=False).total == 1


def _read_all(master: int) -> str:
    """Return everything written to the pty so far (the line discipline may hand it over in pieces)."""
    import os
    import select

    chunks = []
    while select.select([master], [], [], 0.5)[0]:  # until nothing more arrives for 0.5 s
        try:
            chunk = os.read(master, 65536)
        except OSError:  # the other end is closed
            break
        if not chunk:
            break
        chunks.append(chunk)
    return b"".join(chunks).decode(errors="replace")


@pytest.mark.skipif(not hasattr(__import__("os"), "openpty"), reason="needs a pseudo-terminal")
@pytest.mark.parametrize("columns", [0, 100])
def test_a_terminal_that_reports_no_size_still_gets_a_bar(columns):
    """A fresh pty is 0 x 0 (as under `script` or some CI runners); tqdm then drew nothing."""
    import fcntl
    import os
    import struct
    import termios

    master, slave = os.openpty()
    try:
        fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 0, columns, 0, 0))  # no lines
        assert tuple(os.get_terminal_size(slave)) == (columns, 0)
        with open(slave, "w", closefd=False) as stream:
            with ProgressBar(5, "no size", stream=stream) as bar:
                bar.update(5)
            stream.flush()
        text = _read_all(master)
    finally:
        os.close(master)
        os.close(slave)
    assert bar.enabled and "no size" in text and "5/5" in text


def test_drawn_says_where_bars_are_drawn(monkeypatch):
    from uuv_ocp.progress import drawn

    assert drawn(True, Terminal()) and not drawn(False, Terminal())
    assert not drawn(True, io.StringIO()) and drawn(True, io.StringIO(), force=True)
    monkeypatch.setenv(ENVIRONMENT_VARIABLE, "always")
    assert drawn(True, io.StringIO())
    monkeypatch.setenv(ENVIRONMENT_VARIABLE, "never")
    assert not drawn(True, Terminal(), force=True)

"""A Ctrl-C that CasADi's SWIG layer swallows still stops the run (uuv_ocp.interrupts).

CasADi's overload resolution catches every exception while converting arguments, so a
KeyboardInterrupt raised there disappears (seen in about 1 of 6 Ctrl-C's during a campaign of
short trials).  The tests swallow one the same way and check that the run still stops.
"""

import os
import signal
import time

import pytest

from tests.helpers_campaign import small
from uuv_ocp.control.mpc import NMPC
from uuv_ocp.interrupts import check_interrupt, remember_interrupts
from uuv_ocp.studies.campaign import run_campaign


@pytest.fixture(autouse=True)
def python_sigint_handler():
    """Python's own SIGINT handler, as in any interactive run.

    A suite started as a background job (``nohup make test &``) inherits SIGINT ignored, and
    then neither Python nor :func:`remember_interrupts` handles it (an ignored SIGINT stays so).
    """
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


def _swallowed_sigint():
    """Deliver SIGINT to this process and swallow the KeyboardInterrupt, as SWIG does."""
    try:
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.05)  # the handler runs in the main thread between bytecodes
    except KeyboardInterrupt:
        pass


def test_a_swallowed_interrupt_is_raised_at_the_next_check():
    with remember_interrupts():
        _swallowed_sigint()
        with pytest.raises(KeyboardInterrupt, match="swallowed"):
            check_interrupt()
        check_interrupt()  # raised once, not again


def test_without_the_guard_nothing_is_remembered_and_a_delivered_interrupt_is_not_repeated():
    _swallowed_sigint()
    check_interrupt()  # nothing remembered outside remember_interrupts
    with pytest.raises(KeyboardInterrupt), remember_interrupts():
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.05)
    check_interrupt()  # that one reached Python: it is not raised a second time


def test_campaign_stops_on_an_interrupt_swallowed_while_a_trial_is_built(tmp_path, monkeypatch):
    original = NMPC.reset

    def reset_with_swallowed_sigint(self):
        _swallowed_sigint()
        original(self)

    monkeypatch.setattr(NMPC, "reset", reset_with_swallowed_sigint)
    with pytest.raises(KeyboardInterrupt):
        run_campaign(small(trials=2), tmp_path, workers=1, progress=False)
    assert not list(tmp_path.glob("*/trial_*.npz"))  # the interrupted trial left no record

"""The shutdown path: the first SIGINT/SIGTERM/SIGHUP raises KeyboardInterrupt (the
Ctrl-C path), a second one stops the base before the process exits."""

import os
import signal
import time

import pytest

from follow import shutdown
from follow.control.base import NullBase


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP])
def test_first_signal_takes_the_ctrl_c_path_and_handlers_are_restored(signum):
    before = signal.getsignal(signum)
    with pytest.raises(KeyboardInterrupt):
        with shutdown.ShutdownSignals() as signals:
            os.kill(os.getpid(), signum)
            time.sleep(1.0)  # the handler runs at once in the main thread
            pytest.fail("the signal did not interrupt")
    assert signals.reason == signal.Signals(signum).name
    assert signal.getsignal(signum) is before


def test_second_signal_stops_the_base_then_exits(monkeypatch):
    exits = []
    monkeypatch.setattr(shutdown.os, "_exit", lambda code: exits.append(code))
    base = NullBase()
    with shutdown.ShutdownSignals() as signals:
        signals.base = base
        with pytest.raises(KeyboardInterrupt):
            signals._handle(signal.SIGTERM, None)
        assert not base.commands  # the first signal leaves the stop to the normal path
        signals._handle(signal.SIGTERM, None)
    assert exits == [128 + signal.SIGTERM]
    assert base.closed and base.commands[-1].is_stop

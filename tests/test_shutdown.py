"""The shutdown path: the first SIGINT/SIGTERM/SIGHUP raises KeyboardInterrupt (the
Ctrl-C path), a second one stops the base before the process exits."""

import hashlib
import os
import signal
import threading
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


def test_a_second_signal_with_a_base_whose_close_hangs_exits_in_time(monkeypatch):
    """A base without emergency_stop gets a zero and close() from a helper thread; a
    close that hangs (a third-party driver) holds the exit EMERGENCY_STOP_WAIT_S at most."""
    exits, release = [], threading.Event()
    monkeypatch.setattr(shutdown.os, "_exit", lambda code: exits.append(time.monotonic()))

    class HangingClose(NullBase):
        def close(self):
            release.wait(5.0)

    base = HangingClose()
    try:
        with shutdown.ShutdownSignals() as signals:
            signals.base = base
            with pytest.raises(KeyboardInterrupt):
                signals._handle(signal.SIGTERM, None)
            started = time.monotonic()
            signals._handle(signal.SIGTERM, None)
    finally:
        release.set()
    assert len(exits) == 1 and exits[0] - started < shutdown.EMERGENCY_STOP_WAIT_S + 0.5
    assert base.commands[-1].is_stop


def _native_call(seconds: float):
    """A native call that holds the main thread for about `seconds` without returning to
    Python (as the pose network does) and lets other threads run meanwhile."""
    probe = 20_000
    started = time.perf_counter()
    hashlib.pbkdf2_hmac("sha256", b"frame", b"salt", probe)
    per_iteration_s = max(time.perf_counter() - started, 1e-6) / probe
    iterations = int(seconds / per_iteration_s)
    return lambda: hashlib.pbkdf2_hmac("sha256", b"frame", b"salt", iterations)


def test_a_signal_during_a_long_native_call_halts_at_once():
    """The handler itself runs only once the native call returns; the registered halt
    runs when the signal arrives."""
    busy = _native_call(1.0)
    halted, sent = [], []

    def send_signal():
        time.sleep(0.1)
        sent.append(time.monotonic())
        os.kill(os.getpid(), signal.SIGTERM)

    with pytest.raises(KeyboardInterrupt):
        with shutdown.ShutdownSignals():
            unregister = shutdown.halt_on_signal(lambda: halted.append(time.monotonic()))
            threading.Thread(target=send_signal).start()
            try:
                busy()
            finally:
                returned_s = time.monotonic()
    assert sent and halted, "the halt did not run"
    assert halted[0] - sent[0] < 0.25
    assert returned_s - halted[0] > 0.3  # the native call was still running
    unregister()  # harmless once the block is over


def test_no_halt_outside_the_block_or_during_cleanup():
    halted = []
    assert shutdown.halt_on_signal(lambda: halted.append(1))() is None  # no active block
    with shutdown.ShutdownSignals() as signals:
        shutdown.halt_on_signal(lambda: halted.append(2))
        signals.cleaning_up = True
        os.kill(os.getpid(), signal.SIGTERM)  # recorded, not raised: no halt either
        time.sleep(0.3)
    assert signals.reason == "SIGTERM" and halted == []


def test_a_second_signal_during_a_long_native_call_stops_and_exits_at_once(monkeypatch):
    """Two signals while the main thread is inside a native call: its handler would run
    once they are over, and once for both; the watcher stops the base and exits on the
    second at once."""
    busy = _native_call(1.0)
    exits, sent = [], []
    monkeypatch.setattr(shutdown.os, "_exit", lambda code: exits.append((code, time.monotonic())))
    base = NullBase()

    def send_signals():
        for _ in range(2):
            time.sleep(0.1)
            sent.append(time.monotonic())
            os.kill(os.getpid(), signal.SIGTERM)

    with pytest.raises(KeyboardInterrupt):  # the handler's one run, for the first
        with shutdown.ShutdownSignals() as signals:
            signals.base = base
            threading.Thread(target=send_signals).start()
            busy()
    assert len(sent) == 2 and exits, "the second signal did not exit"
    assert exits[0][0] == 128 + signal.SIGTERM and exits[0][1] - sent[1] < 0.25
    assert base.commands[-1].is_stop


def test_a_second_signal_seen_by_the_watcher_and_the_handler_stops_and_exits_once(
    monkeypatch,
):
    exits, stops = [], []
    monkeypatch.setattr(shutdown.os, "_exit", exits.append)
    base = NullBase()
    base.emergency_stop = lambda: stops.append(threading.current_thread().name)
    with shutdown.ShutdownSignals() as signals:
        signals.base = base
        with pytest.raises(KeyboardInterrupt):
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(1.0)
        os.kill(os.getpid(), signal.SIGTERM)  # the handler and the watcher both see it
        time.sleep(0.3)
    assert exits == [128 + signal.SIGTERM] and len(stops) == 1

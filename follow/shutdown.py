"""Shutdown on a signal: SIGTERM (systemd, docker) and SIGHUP (a closed terminal) take
the same path as Ctrl-C, so the base gets a zero command, the log is flushed and the
video finalised. Once the run is cleaning up (`cleanup_begins`: the run ended by itself,
failed, or was interrupted) a signal is only recorded, so it cannot cut the cleanup short
(frames unlogged, a writer closed under its thread, an error reported as a clean stop).
A second signal stops the base first, from a helper thread through the base's
`emergency_stop` (which takes no lock the interrupted code may hold), and then exits.

Python runs a signal's handler in the main thread only between two bytecodes, so while
the main thread is inside a long native call (the pose network: 20-350 ms a frame on a
CPU) the control thread would go on driving toward the last target until the call
returns. The signal is therefore also written to a pipe (`signal.set_wakeup_fd`) that a
watcher thread reads at once: it runs the halts registered with `halt_on_signal` (the
runner's control loop, which then sends only zero) before the main thread gets to the
handler. The watcher also counts the signals, one byte each, and handles the second
itself: the handler would run only once the native call returns, and signals that came
meanwhile reach it as one.
"""

from __future__ import annotations

import logging
import os
import signal
import threading
from collections.abc import Callable

from follow.types import VelocityCommand

log = logging.getLogger(__name__)

SIGNALS = tuple(getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP")
                if hasattr(signal, name))  # fmt: skip
EMERGENCY_STOP_WAIT_S = 1.0


_active: ShutdownSignals | None = None  # the one handling this process's signals


def halt_on_signal(halt: Callable[[], None]) -> Callable[[], None]:
    """Run `halt` from the signal watcher as soon as a first shutdown signal arrives,
    whatever the main thread is doing (see the module doc); it must be safe to call from
    any thread, and more than once. Returns the function that unregisters it."""
    active = _active
    if active is None:
        return lambda: None
    active._halts.append(halt)

    def unregister() -> None:
        if halt in active._halts:
            active._halts.remove(halt)

    return unregister


def cleanup_begins() -> None:
    """The run is cleaning up (stopping threads, closing the base and the outputs): from
    now on a first signal is recorded, not raised (see the module doc)."""
    if _active is not None:
        _active.cleaning_up = True


class ShutdownSignals:
    """Within `with ShutdownSignals() as s:`, the first signal raises KeyboardInterrupt
    in the main thread (`s.reason` names it); a second one stops `s.base` and exits.
    Outside the main thread (where handlers cannot be installed) it does nothing."""

    def __init__(self):
        self.base = None
        self.reason: str | None = None
        self.cleaning_up = False
        self._previous: dict[int, object] = {}
        self._halts: list[Callable[[], None]] = []
        self._wakeup: tuple[int, int] | None = None  # (read, write) ends of the pipe
        self._previous_wakeup_fd = -1
        self._watcher: threading.Thread | None = None
        self._watched = 0  # shutdown signals the watcher has read
        self._exit_lock = threading.RLock()  # one emergency stop and exit (see `_exit`)
        self._exiting = False

    def __enter__(self) -> ShutdownSignals:
        global _active
        if threading.current_thread() is threading.main_thread():
            for sig in SIGNALS:
                self._previous[sig] = signal.signal(sig, self._handle)
            self._watch_signals()
            _active = self
        return self

    def __exit__(self, *exc) -> None:
        global _active
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
        self._previous.clear()
        if self._wakeup is not None:
            signal.set_wakeup_fd(self._previous_wakeup_fd)
            os.close(self._wakeup[1])  # the watcher reads the end of the pipe and ends
            self._watcher.join(timeout=1.0)
            os.close(self._wakeup[0])
            self._wakeup = None
        self._halts.clear()
        if _active is self:
            _active = None

    def _watch_signals(self) -> None:
        read_fd, write_fd = os.pipe()
        os.set_blocking(write_fd, False)  # the C-level handler must never block
        try:
            self._previous_wakeup_fd = signal.set_wakeup_fd(write_fd, warn_on_full_buffer=False)
        except ValueError:  # not the main thread of the main interpreter after all
            os.close(read_fd)
            os.close(write_fd)
            return
        self._wakeup = (read_fd, write_fd)
        self._watcher = threading.Thread(target=self._watch, args=(read_fd,),
                                         name="signal-watch", daemon=True)  # fmt: skip
        self._watcher.start()

    def _watch(self, read_fd: int) -> None:
        """Read each signal as it arrives, whatever the main thread is doing."""
        shutdown_signals = {int(sig) for sig in SIGNALS}
        while True:
            try:
                data = os.read(read_fd, 64)
            except OSError:
                return
            if not data:
                return  # the write end closed: the block is over
            for signum in data:
                if signum in shutdown_signals:
                    self._watched_signal(signum)

    def _watched_signal(self, signum: int) -> None:
        """The first halts at once (not during cleanup, whose own stop comes first), on a
        thread of its own (a halt waits on a hung base for seconds); the second stops the
        base and exits, here, where the main thread's native call cannot hold it up."""
        self._watched += 1
        if self._watched > 1:
            self._exit(signum)
        elif not self.cleaning_up:
            threading.Thread(target=self._halt, name="signal-halt", daemon=True).start()

    def _halt(self) -> None:
        for halt in list(self._halts):
            try:
                halt()
            except Exception as exc:  # the handler's own path still stops the base
                log.error("halting on a signal: %s", exc)

    def _handle(self, signum: int, frame) -> None:
        name = signal.Signals(signum).name
        if self.reason is None and self.cleaning_up:
            self.reason = name
            log.warning("%s while cleaning up: finishing it (a second signal stops the "
                        "base and exits at once)", name)  # fmt: skip
            return
        if self.reason is None:
            self.reason = name
            raise KeyboardInterrupt(name)
        self._exit(signum)

    def _exit(self, signum: int) -> None:
        """Stop the base and exit, once: the watcher and the main thread's handler may
        both see the second signal; the one that comes second waits here for the exit
        rather than go on (the lock is re-entrant: a third signal's handler, in the main
        thread while it stops the base, returns to it)."""
        with self._exit_lock:
            if self._exiting:
                return
            self._exiting = True
            log.error("%s during shutdown: stopping the base and exiting now",
                      signal.Signals(signum).name)  # fmt: skip
            self._emergency_stop()
            os._exit(128 + signum)

    def _emergency_stop(self) -> None:
        base = self.base
        if base is None:
            return

        def stop() -> None:
            emergency = getattr(base, "emergency_stop", None)
            if emergency is not None:
                emergency()
            else:
                base.send(VelocityCommand.stop(0.0))
                base.close()

        stop_within(stop)


def stop_within(
    stop: Callable[[], None], wait_s: float = EMERGENCY_STOP_WAIT_S, name: str = "emergency-stop"
) -> bool:
    """Run `stop` (a zero command on a second signal, a control loop's last zero, `follow
    run`'s close of the base) on a helper thread named `name` and wait for it `wait_s` at
    most: a send or close that hangs must not keep the caller, nor the process, alive.
    An error is logged (closing already, or the link is gone). Returns whether `stop`
    returned in time."""

    def guarded() -> None:
        try:
            stop()
        except Exception as exc:
            log.error("%s: %s", name.replace("-", " "), exc)

    worker = threading.Thread(target=guarded, name=name, daemon=True)
    worker.start()
    worker.join(wait_s)
    return not worker.is_alive()

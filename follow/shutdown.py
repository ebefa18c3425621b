"""Shutdown on a signal: SIGTERM (systemd, docker) and SIGHUP (a closed terminal) take
the same path as Ctrl-C, so the base gets a zero command, the log is flushed and the
video finalised. Once the run is cleaning up (`cleanup_begins`: the run ended by itself,
failed, or was interrupted) a signal is only recorded, so it cannot cut the cleanup short
(frames unlogged, a writer closed under its thread, an error reported as a clean stop).
A second signal stops the base first, from a helper thread through the base's
`emergency_stop` (which takes no lock the interrupted code may hold), and then exits.
"""

from __future__ import annotations

import logging
import os
import signal
import threading

from follow.types import VelocityCommand

log = logging.getLogger(__name__)

SIGNALS = tuple(getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP")
                if hasattr(signal, name))  # fmt: skip
EMERGENCY_STOP_WAIT_S = 1.0


_active: ShutdownSignals | None = None  # the one handling this process's signals


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

    def __enter__(self) -> ShutdownSignals:
        global _active
        if threading.current_thread() is threading.main_thread():
            for sig in SIGNALS:
                self._previous[sig] = signal.signal(sig, self._handle)
            _active = self
        return self

    def __exit__(self, *exc) -> None:
        global _active
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
        self._previous.clear()
        if _active is self:
            _active = None

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
        log.error("%s during shutdown: stopping the base and exiting now", name)
        self._emergency_stop()
        os._exit(128 + signum)

    def _emergency_stop(self) -> None:
        base = self.base
        if base is None:
            return

        def stop() -> None:
            try:
                emergency = getattr(base, "emergency_stop", None)
                if emergency is not None:
                    emergency()
                else:
                    base.send(VelocityCommand.stop(0.0))
                    base.close()
            except Exception as exc:  # closing already, or the link is gone
                log.error("emergency stop: %s", exc)

        worker = threading.Thread(target=stop, name="emergency-stop", daemon=True)
        worker.start()
        worker.join(EMERGENCY_STOP_WAIT_S)

"""Shutdown on a signal: SIGTERM (systemd, docker) and SIGHUP (a closed terminal) take
the same path as Ctrl-C, so the base gets a zero command, the log is flushed and the
video finalised. A second signal while that is under way stops the base first (from a
helper thread, so a lock held by the interrupted code cannot block it) and then exits.
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


class ShutdownSignals:
    """Within `with ShutdownSignals() as s:`, the first signal raises KeyboardInterrupt
    in the main thread (`s.reason` names it); a second one stops `s.base` and exits.
    Outside the main thread (where handlers cannot be installed) it does nothing."""

    def __init__(self):
        self.base = None
        self.reason: str | None = None
        self._previous: dict[int, object] = {}

    def __enter__(self) -> ShutdownSignals:
        if threading.current_thread() is threading.main_thread():
            for sig in SIGNALS:
                self._previous[sig] = signal.signal(sig, self._handle)
        return self

    def __exit__(self, *exc) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
        self._previous.clear()

    def _handle(self, signum: int, frame) -> None:
        name = signal.Signals(signum).name
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
                base.send(VelocityCommand.stop(0.0))
                base.close()
            except Exception as exc:  # closing already, or the link is gone
                log.error("emergency stop: %s", exc)

        worker = threading.Thread(target=stop, name="emergency-stop", daemon=True)
        worker.start()
        worker.join(EMERGENCY_STOP_WAIT_S)

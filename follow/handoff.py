"""Passing work between the runner's threads without losing order or piling up frames.

`Handoff` carries one item from the pose thread to the tracking thread; the giver waits
until it has been taken, so at most two frames are in flight (one being tracked, one
inferred). `OrderedWorker` runs a callback (drawing, video encoding, logging) on its own
thread, in order, and raises its first error in the thread that feeds it.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Callable, Iterator

log = logging.getLogger(__name__)

POLL_S = 0.05  # how often a waiting thread looks at the stop flag


class Mailbox:
    """What every one-item mailbox between threads shares: a condition to wait on, a
    `close` that wakes every waiter for good (the source has ended), and `items`, the
    reader's loop. Subclasses define `get(timeout_s)`: the next item, or None on
    time-out or when closed and empty."""

    def __init__(self):
        self._cond = threading.Condition()
        self._item = None
        self._closed = False

    def get(self, timeout_s: float | None = None):
        raise NotImplementedError

    def items(self, stop: threading.Event | None = None, poll_s: float = POLL_S,
              max_wait_s: float | None = None) -> Iterator:  # fmt: skip
        """Each item as it comes, until the mailbox is closed and empty or `stop` is set
        (looked at every `poll_s` seconds while nothing comes); with `max_wait_s`,
        TimeoutError once nothing has come for that long (the giver hangs)."""
        last_s = time.monotonic()
        while stop is None or not stop.is_set():
            closed = self._closed  # before `get`: an item put just before closing is read
            item = self.get(timeout_s=poll_s)
            if item is None:
                if closed:
                    return
                if max_wait_s and time.monotonic() - last_s > max_wait_s:
                    raise TimeoutError(f"nothing came for {max_wait_s:g} s")
                continue
            last_s = time.monotonic()
            yield item

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify_all()

    @property
    def closed(self) -> bool:
        return self._closed


class Handoff(Mailbox):
    """A one-item mailbox whose giver waits until the item is taken."""

    def __init__(self):
        super().__init__()
        self._full = False

    def give(self, item, stop: threading.Event) -> bool:
        """Hand `item` over and wait until it is taken; False when `stop` was set first."""
        with self._cond:
            self._item, self._full = item, True
            self._cond.notify_all()
            while self._full and not stop.is_set():
                self._cond.wait(POLL_S)
            return not self._full

    def get(self, timeout_s: float | None = None):
        """The item given, or None on time-out or when closed and empty."""
        with self._cond:
            self._cond.wait_for(lambda: self._full or self._closed, timeout=timeout_s)
            if not self._full:
                return None
            item, self._item, self._full = self._item, None, False
            self._cond.notify_all()
            return item


class OrderedWorker:
    """Runs `callback(*args)` for each submitted item on one background thread, in order.

    The queue is bounded (`max_pending`), so a slow callback slows the feeder instead of
    piling up frames in memory. The callback's first exception stops the worker and is
    raised by the next `submit` or by `close`.
    """

    _DONE = object()

    def __init__(self, callback: Callable, max_pending: int = 4, name: str = "outputs"):
        self.callback = callback
        self.error: BaseException | None = None
        self._queue: queue.Queue = queue.Queue(maxsize=max_pending)
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def submit(self, *args) -> None:
        if self.error is not None:
            raise self.error
        while self._thread.is_alive():
            try:
                self._queue.put(args, timeout=POLL_S)
                return
            except queue.Full:
                continue
        if self.error is not None:
            raise self.error

    def close(self, timeout_s: float = 30.0) -> bool:
        """Finish every submitted item within `timeout_s` (one deadline for queueing the
        end and for the thread to reach it: a callback stuck on a stalled disk must not
        hang shutdown), then raise the callback's error if there was one. False when the
        thread is still stuck in the callback: what it writes to (a file whose lock it
        holds) must not be closed under it."""
        deadline = time.monotonic() + timeout_s
        while self._thread.is_alive() and time.monotonic() < deadline:
            try:
                self._queue.put(self._DONE, timeout=POLL_S)
                break
            except queue.Full:
                continue
        self._thread.join(max(0.0, deadline - time.monotonic()))
        if self._thread.is_alive():
            log.error("%s thread still busy %.0f s after close: the items left are lost",
                      self._thread.name, timeout_s)  # fmt: skip
            return False
        if self.error is not None:
            raise self.error
        return True

    def _run(self) -> None:
        while True:
            item = self._queue.get()
            if item is self._DONE:
                return
            try:
                self.callback(*item)
            except BaseException as exc:  # raised again in the feeding thread
                self.error = exc
                return

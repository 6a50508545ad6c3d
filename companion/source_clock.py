"""The clock of the source the station follows.

A live vehicle (serial, UDP, TCP, the twin over its socket) is in the station's time:
`mono()` is `time.monotonic()` and `wall()` is `time.time()`. A replayed log runs on its
own clock: the time of its records, advanced by the link thread record by record (and
with the wall clock between records when paced), so that what is recorded or analysed
from it (state times, session rows, the post-disarm tail, rates) is in the log's time and
the same at any replay speed. For such a source `mono()` and `wall()` are both the log's
Unix seconds.

Listeners (the recorder) run in the source's thread, synchronously, each time its clock
moves (`cb(t)`, before the record at `t` is applied) and once when it ends (`cb(None)`),
so that at `?speed=max` nothing is skipped: a listener may take the time it needs, the
replay waits for it. A log that holds several recordings (its clock steps back, see
core.mavlink.tlog_records) ends one run and starts the next: `cb(None)`, then times from
the earlier start on (`step_back`); the clock never stands still at the newest time.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

log = logging.getLogger(__name__)

ClockListener = Callable[[float | None], None]


class SourceClock:
    def __init__(self, own: bool = False) -> None:
        self.own = own  # True: the source's own time (a replay), False: the station's
        self.ended = False
        self._t: float | None = None
        self._may_go_back = False  # set by step_back until the next advance
        self._listeners: list[ClockListener] = []
        self._first = threading.Event()

    @property
    def started(self) -> bool:
        """False for a source on its own clock that has not given its first time yet."""
        return not self.own or self._t is not None

    def wait_started(self, timeout: float) -> bool:
        """Block until the source gave its first time (at once for the station's clock)."""
        return self.started or self._first.wait(timeout)

    def mono(self) -> float:
        return self._t if self.own and self._t is not None else time.monotonic()

    def wall(self) -> float:
        return self._t if self.own and self._t is not None else time.time()

    def add_listener(self, cb: ClockListener) -> None:
        self._listeners = [*self._listeners, cb]  # copy-on-write: the source thread iterates

    def advance(self, t: float) -> None:
        """The source's time is now `t` (never goes back, but after `step_back`); tells
        the listeners."""
        if self._t is not None and t <= self._t and not self._may_go_back:
            return
        self._may_go_back = False
        self._t = t
        self._first.set()
        self._tell(t)

    def step_back(self) -> None:
        """The source starts another run on an earlier clock (the next recording in a
        replayed log): the listeners are told this run ended, and the next `advance`
        may go back."""
        if not self.ended:
            self._may_go_back = True
            self._tell(None)

    def end(self) -> None:
        """The source has nothing more (a replay reached the end of its file)."""
        if not self.ended:
            self.ended = True
            self._tell(None)

    def _tell(self, t: float | None) -> None:
        for cb in self._listeners:
            try:
                cb(t)
            except Exception:  # a listener's bug must not stop the source
                log.exception("source clock listener %r failed", cb)

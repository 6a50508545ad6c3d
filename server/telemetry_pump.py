"""One telemetry pump for every `/ws/telemetry` client: one message per tick, shared.

Each client's coroutine (server/routes/telemetry.py) sends on its own socket, so a slow
client delays only itself; what it sends comes from here. A tick takes the newest
vehicle state and builds its message once (the JSON body, server/telemetry_json.py, and
the `t_server` prefix); every client that is due sends that same text. Clients do not
pace themselves with timers of their own: out of phase with each other, each would get
a state version of its own, and two page-like clients would cost two timer wake-ups and
two message builds per message instead of one.

Who is due, and when the pump ticks:
- A client is due once its own interval (`1 / max_rate`) has passed since the tick of
  its last message, it has room in its acknowledgement window (`?ack=N`: fewer than N
  messages unacknowledged), and a state newer than the one it has exists.
- Ticks come at most once per the shortest interval any client asked for (the highest
  rate, default 50/s), and only for a client that is due: never for nobody. A client
  that becomes due within a tick's interval (its ack arrived) takes that tick's message,
  so clients fall into step and share the ticks; a client with a lower `max_rate` takes
  every k-th tick, or the first one after its interval.
- A client that is busy (sending, or waiting for its ack) skips ticks; once it is due
  again it gets the newest message at once: latest value wins, nothing queues. A client
  behind the newest state gets it when due even if no newer state comes (the link's
  last state, "link lost", reaches every page).

The pump task waits on the state slot when a client needs a newer state, else on a
future of its own whose timer the clients move (no thread hop, no wake-up of the pump
for an ack). An ack does not wake its client's coroutine either: the pump counts the
client in and wakes it with the tick. The task runs while any client is connected and
is cancelled when the last one leaves: no client, no task and no timer.
"""

from __future__ import annotations

import asyncio
import math
from collections import deque
from dataclasses import dataclass
from typing import Any

from fpv_station.companion.latest import Latest, Versioned
from fpv_station.companion.vehicle_state import VehicleState
from fpv_station.core.spawn import Spawn
from fpv_station.server.telemetry_json import SharedStateJson

PUMP_TASK = "telemetry-pump"
# A moment this close before a time counts as that time (a client's due time, the next
# tick's): the loop's timers fire to the millisecond, and uvloop's clock counts whole
# milliseconds, so a timer meant for a moment may run a hair before it. Without it, each
# such timer would cost a second wake-up a millisecond later (a third of them, under uvloop).
TICK_SLACK_S = 0.002


def _reached(t: float, now: float) -> bool:
    return now >= t - TICK_SLACK_S


@dataclass(frozen=True, slots=True)
class TelemetryMessage:
    """One tick's message: the text every due client sends."""

    version: int  # of the state it carries
    t_mono: float  # loop time of the tick
    text: str


class TelemetryClient:
    """One WebSocket client as the pump sees it: its pace, what it has, and the one
    future its coroutine waits on (for its next message, or its leaving).

    `ack_window`: 0, no acknowledgements; N, at most N messages unacknowledged (in flight),
    the next one waits for `{"ack": version}`, which acknowledges every message up to
    `version` (the versions a client gets only grow)."""

    def __init__(self, max_rate: float, ack_window: int = 0) -> None:
        self.interval_s = 1.0 / max_rate
        self.ack_window = ack_window
        self._unacked: deque[int] = deque()  # versions sent, not acknowledged, oldest first
        self.version = 0  # of the last state it took
        self.due_mono = -math.inf  # its last message's tick + its interval
        self.gone = False
        self._offered = False  # found waiting and due: it takes the newest message
        self._waiter: asyncio.Future[None] | None = None
        self._timer: asyncio.TimerHandle | None = None  # its own, rarely (_serve_or_plan)

    @property
    def waiting(self) -> bool:
        """Its coroutine waits in `next_message`."""
        return self._waiter is not None

    @property
    def window_full(self) -> bool:
        """Its window is full: it gets nothing until an acknowledgement makes room."""
        return self.ack_window > 0 and len(self._unacked) >= self.ack_window

    def acknowledge(self, version: int) -> bool:
        """`{"ack": version}` came: every message up to `version` is acknowledged (an old
        or repeated ack changes nothing; one beyond what was sent, all). True if that made
        room in a window that was full."""
        was_full = self.window_full
        unacked = self._unacked
        while unacked and unacked[0] <= version:
            unacked.popleft()
        return was_full and not self.window_full

    def wake(self) -> None:
        waiter = self._waiter
        if waiter is not None and not waiter.done():
            waiter.set_result(None)

    def leave(self) -> None:
        """The client went away: its coroutine stops waiting now."""
        self.gone = True
        self.wake()

    def _take(self, message: TelemetryMessage) -> TelemetryMessage:
        self.version = message.version
        if self.ack_window:
            self._unacked.append(message.version)
        # From the tick, not from when this coroutine ran: clients of one rate stay due
        # at the same moments and share the ticks.
        self.due_mono = message.t_mono + self.interval_s
        return message


class TelemetryPump:
    """The shared ticks of one station's state slot. Used from the event loop only.

    `spawn` starts the pump task (the station's supervised `tasks.spawn`)."""

    def __init__(self, slot: Latest[VehicleState], shared: SharedStateJson, spawn: Spawn) -> None:
        self.slot = slot
        self.shared = shared
        self._spawn = spawn
        self.message: TelemetryMessage | None = None  # the newest tick's
        self.ticks = 0  # messages built (for tests and benchmarks; bodies: shared.encodes)
        self.turns = 0  # times the pump task looked at its clients (tests)
        self._clients: set[TelemetryClient] = set()
        self._interval_s = math.inf  # the shortest any client asked for
        self._task: asyncio.Task[Any] | None = None
        self._stopping: asyncio.Task[Any] | None = None  # cancelled by the last leave
        # What the pump task waits on: its own future until `_sleep_until` (a client that
        # needs it sooner moves its timer, `_timer`), or the slot until
        # `_state_wait_until` (nobody can wake that wait: a client needing an earlier
        # time gets a timer of its own).
        self._wakeup: asyncio.Future[None] | None = None
        self._timer: asyncio.TimerHandle | None = None
        self._sleep_until: float | None = None
        self._state_wait_until: float | None = None

    @property
    def running(self) -> bool:
        """The pump task is there: false once the last client left or the slot closed
        (the task is done in the step whose `finally` in `_run` wakes the clients)."""
        return self._task is not None and not self._task.done()

    @property
    def clients(self) -> int:
        return len(self._clients)

    async def join(self, client: TelemetryClient) -> None:
        """Count `client` in; the first one starts the pump task."""
        self._clients.add(client)
        self._interval_s = min(self._interval_s, client.interval_s)
        stopping = self._stopping
        if stopping is not None and not stopping.done():
            # The last client left a moment ago and cancelled the task: let it end, so
            # that one pump task runs under its name.
            await asyncio.wait([stopping])
        if not self.running:
            self._task = self._spawn(PUMP_TASK, self._run())

    def leave(self, client: TelemetryClient) -> None:
        """Count `client` out; the last one stops the pump task."""
        self._clients.discard(client)
        _cancel(client._timer)
        self._interval_s = min((c.interval_s for c in self._clients), default=math.inf)
        if not self._clients and self._task is not None:
            self._stopping, self._task = self._task, None
            self._stopping.cancel()

    def acked(self, client: TelemetryClient, version: int) -> None:
        """`client` acknowledged `version`: if its full window was all it waited for, it
        gets the newest message now, or is counted in for the next tick."""
        if not client.acknowledge(version):
            return  # it had room already, so it is in the pump's plans
        if client.waiting and not client._offered:
            if self._serve_or_plan(client, asyncio.get_running_loop()) is not None:
                self._offer(client)

    async def next_message(self, client: TelemetryClient) -> TelemetryMessage | None:
        """The next message for `client` to send, as soon as it is due (and, with acks,
        has room in its window); None once it has gone or the pump has ended (the
        state slot closed)."""
        loop = asyncio.get_running_loop()
        while self.running and not client.gone:
            if client._offered:
                client._offered = False
                if self.message is not None and self.message.version > client.version:
                    return client._take(self.message)
            message = self._serve_or_plan(client, loop)
            if message is not None:
                return client._take(message)
            client._waiter = loop.create_future()
            try:
                await client._waiter
            finally:
                client._waiter = None
                _cancel(client._timer)
        return None

    def _offer(self, client: TelemetryClient) -> None:
        client._offered = True
        client.wake()

    def _serve_or_plan(
        self, client: TelemetryClient, loop: asyncio.AbstractEventLoop
    ) -> TelemetryMessage | None:
        """The message `client` takes now; else make sure something wakes it when it is
        due: the pump's timer, the pump itself (it must watch the slot), or, while the
        pump waits on the slot, a timer of the client's own."""
        now = loop.time()
        message = self._due_message(client, now)
        if message is not None:
            return message
        ready = self._ready_at(client, now)
        if ready is None:
            return None  # its ack comes first
        if self._sleep_until is not None:
            if ready == math.inf:
                self._wake_pump()  # a newer state is needed: the pump watches the slot
            elif ready < self._sleep_until:
                self._sleep_until = ready
                _cancel(self._timer)
                self._timer = loop.call_at(ready, self._wake_pump)
        elif self._state_wait_until is not None and ready < self._state_wait_until:
            _cancel(client._timer)
            client._timer = loop.call_at(ready, client.wake)
        return None

    def _due_message(self, client: TelemetryClient, now: float) -> TelemetryMessage | None:
        """What `client` takes now: this tick's message, or a new tick; None if it is not
        due (its ack, its interval, the ticks' pace, or no newer state)."""
        if client.window_full or not _reached(client.due_mono, now):
            return None
        message = self.message
        if message is not None and not _reached(message.t_mono + self._interval_s, now):
            # Within this tick: its message if that is newer and the tick came when the
            # client was due, else wait for the next one. (A tick from before its due
            # time would start its next interval early: a 10/s client got 12 a second.)
            return message if self._serves(message, client) else None
        current = self.slot.get()
        if current is None or current.version <= client.version:
            return None
        return self._tick(current, now)

    def _ready_at(self, client: TelemetryClient, now: float) -> float | None:
        """When to look at `client` again, for a client `_due_message` gave nothing now:
        its due time (and the next tick's); inf when it is due but needs a newer state;
        None while its window is full."""
        if client.window_full:
            return None
        at = client.due_mono  # then this tick's message if it serves it, else a new tick
        message = self.message
        if message is not None and not self._serves(message, client):
            at = max(at, message.t_mono + self._interval_s)
        # Not due yet: look then (no watching the slot before; a state comes 100 times a
        # second). Due already: nothing newer came, so wait for it.
        return math.inf if _reached(at, now) else at

    @staticmethod
    def _serves(message: TelemetryMessage, client: TelemetryClient) -> bool:
        """`message` is for `client`: newer than what it has, from a tick at its due time
        or after (the tick its interval then counts from)."""
        return message.version > client.version and _reached(client.due_mono, message.t_mono)

    def _tick(self, current: Versioned[VehicleState], now: float) -> TelemetryMessage:
        # shared.message re-encodes only a state it has not seen; the same state again
        # (a due client that has an older one) costs a new `t_server` prefix only.
        self.message = TelemetryMessage(current.version, now, self.shared.message(current))
        self.ticks += 1
        return self.message

    def _wake_pump(self) -> None:
        wakeup = self._wakeup
        if wakeup is not None and not wakeup.done():
            wakeup.set_result(None)

    async def _run(self) -> None:
        loop = asyncio.get_running_loop()
        try:
            while self._clients and not self.slot.closed:
                self.turns += 1
                now = loop.time()
                ready, need = math.inf, None  # need: the version a newer state must pass
                for client in self._clients:
                    if not client.waiting or client._offered:
                        continue
                    if self._due_message(client, now) is not None:
                        self._offer(client)
                        continue
                    at = self._ready_at(client, now)
                    if at is None:
                        continue  # its ack comes first
                    if at == math.inf:
                        need = client.version if need is None else min(need, client.version)
                    ready = min(ready, at)
                if need is not None:
                    self._state_wait_until = ready
                    try:
                        # Returns at once if a state came since the look above.
                        timeout = ready - now if ready < math.inf else None
                        await self.slot.wait_newer(need, timeout=timeout)
                    finally:
                        self._state_wait_until = None
                else:
                    self._wakeup = loop.create_future()
                    self._sleep_until = ready
                    if ready < math.inf:
                        self._timer = loop.call_at(ready, self._wake_pump)
                    try:
                        await self._wakeup
                    finally:
                        _cancel(self._timer)
                        self._wakeup = self._timer = self._sleep_until = None
        finally:
            for client in self._clients:  # the slot closed, or the station stops
                client.wake()


def _cancel(timer: asyncio.TimerHandle | None) -> None:
    if timer is not None:
        timer.cancel()

"""One telemetry pump for every `/ws/telemetry` client: one message per tick, shared.

Each client's coroutine (server/routes/telemetry.py) sends from its own socket, so a
slow client delays only itself; what it sends comes from here. A tick takes the newest
vehicle state and builds its message once (the JSON body, server/telemetry_json.py,
and the `t_server` prefix); every client that is due then sends that same text. Before,
each client paced itself with a timer of its own and, out of phase with the others, got
a different state version: two page-like clients cost two timer wake-ups and two
message builds per message instead of one.

Who is due, and when the pump ticks:
- A client is due once its own interval (`1 / max_rate`) has passed since it took its
  last message, and the newest state is newer than the one it has.
- Ticks come at most once per the shortest interval any client asked for (the highest
  rate, default 50/s), and only when a waiting client is due: a tick is never built for
  nobody. A client that comes back within a tick's interval (its ack arrived, its send
  ended) takes that tick's message, so clients fall into step and share ticks. A client
  with a lower `max_rate` takes every k-th tick, or the first one after its interval.
- A client that is busy (sending, or waiting for its ack) skips ticks; when it is back
  and due it gets the newest message at once: latest value wins, nothing queues.

The pump task waits on the state slot only when every waiting client has the newest
state; otherwise on its own future, which a client that needs it sooner resolves (no
thread hop, no syscall). It runs while any client is connected and is cancelled when
the last one leaves: no client, no task and no timer.
"""

from __future__ import annotations

import asyncio
import math
from dataclasses import dataclass
from typing import Any

from companion.latest import Latest, Versioned, wait_resolved
from companion.vehicle_state import VehicleState
from core.spawn import Spawn
from server.telemetry_json import SharedStateJson

PUMP_TASK = "telemetry-pump"


@dataclass(frozen=True, slots=True)
class TelemetryMessage:
    """One tick's message: the text every due client sends."""

    version: int  # of the state it carries
    t_mono: float  # loop time of the tick
    text: str


class TelemetryClient:
    """One WebSocket client as the pump sees it: its pace, what it has, and the one
    future its coroutine waits on (for a tick, for its ack, for its leaving)."""

    def __init__(self, max_rate: float) -> None:
        self.interval_s = 1.0 / max_rate
        self.version = 0  # of the last state it took
        self.due_mono = -math.inf  # when its interval has passed
        self.gone = False
        self._offered = False  # a tick found it waiting and due
        self._waiter: asyncio.Future[None] | None = None

    def wake(self) -> None:
        waiter = self._waiter
        if waiter is not None and not waiter.done():
            waiter.set_result(None)

    def leave(self) -> None:
        """The client went away: its coroutine stops waiting now."""
        self.gone = True
        self.wake()

    async def wait(self, timeout: float | None = None) -> None:  # noqa: ASYNC109
        """Until `wake` (a tick, an ack, the leaving), or `timeout` seconds."""
        self._waiter = asyncio.get_running_loop().create_future()
        try:
            await wait_resolved(self._waiter, timeout)
        finally:
            self._waiter = None

    def _take(self, message: TelemetryMessage, now: float) -> TelemetryMessage:
        self.version = message.version
        self.due_mono = now + self.interval_s
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
        self._clients: set[TelemetryClient] = set()
        self._waiting: set[TelemetryClient] = set()  # in next_message, nothing to take yet
        self._interval_s = math.inf  # the shortest any client asked for
        self._task: asyncio.Task[Any] | None = None
        self._stopping: asyncio.Task[Any] | None = None  # cancelled by the last leave
        self._running = False
        # What the pump task waits on: its own future until `_sleep_until` (a waiting
        # client that needs it sooner wakes it), or the slot until `_state_wait_until`
        # (nobody can wake that wait: a client needing an earlier time keeps its own).
        self._wakeup: asyncio.Future[None] | None = None
        self._sleep_until: float | None = None
        self._state_wait_until: float | None = None

    @property
    def running(self) -> bool:
        return self._running

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
        if self._task is None or self._task.done():
            self._running = True
            self._task = self._spawn(PUMP_TASK, self._run())

    def leave(self, client: TelemetryClient) -> None:
        """Count `client` out; the last one stops the pump task."""
        self._clients.discard(client)
        self._waiting.discard(client)
        self._interval_s = min((c.interval_s for c in self._clients), default=math.inf)
        if not self._clients and self._task is not None:
            self._stopping, self._task = self._task, None
            self._stopping.cancel()

    async def next_message(self, client: TelemetryClient) -> TelemetryMessage | None:
        """The next message for `client` to send, as soon as it is due; None once the
        client has gone or the pump has ended (the state slot closed)."""
        loop = asyncio.get_running_loop()
        while self._running and not client.gone:
            now = loop.time()
            if client._offered:
                client._offered = False
                if self.message is not None and self.message.version > client.version:
                    return client._take(self.message, now)
            message = self._due_message(client, now)
            if message is not None:
                return client._take(message, now)
            ready = self._ready_at(client)
            timeout = None
            if self._sleep_until is not None:
                if ready < self._sleep_until or ready == math.inf:
                    self._wake_pump()  # it must tick sooner, or watch the slot for us
            elif self._state_wait_until is not None and ready < self._state_wait_until:
                timeout = ready - now
            self._waiting.add(client)
            try:
                await client.wait(timeout)
            finally:
                self._waiting.discard(client)
        return None

    def _due_message(self, client: TelemetryClient, now: float) -> TelemetryMessage | None:
        """What `client` takes now: this tick's message, or a new tick; None if it is not
        due (its interval, the ticks' pace, or no newer state)."""
        if client.due_mono > now:
            return None
        message = self.message
        if message is not None and now < message.t_mono + self._interval_s:
            # Within this tick: its message if that is newer, else wait for the next one.
            return message if message.version > client.version else None
        current = self.slot.get()
        if current is None or current.version <= client.version:
            return None
        return self._tick(current, now)

    def _ready_at(self, client: TelemetryClient) -> float:
        """When `_due_message` gives `client` a message without a newer state; inf when
        it needs one."""
        message = self.message
        if message is not None and message.version > client.version:
            return client.due_mono  # this tick's message, or (once it is old) a new tick
        if self.slot.version > client.version:
            next_tick = message.t_mono + self._interval_s if message is not None else -math.inf
            return max(client.due_mono, next_tick)
        return math.inf

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
                now = loop.time()
                ready, need = math.inf, None  # need: the version a newer state must pass
                for client in list(self._waiting):
                    if client._offered:
                        continue
                    message = self._due_message(client, now)
                    if message is not None:
                        client._offered = True
                        client.wake()
                        continue
                    at = self._ready_at(client)
                    if at == math.inf:
                        need = client.version if need is None else min(need, client.version)
                    ready = min(ready, at)
                timeout = ready - now if ready < math.inf else None
                if need is not None:
                    self._state_wait_until = ready
                    try:
                        # Returns at once if a state came since the look above.
                        await self.slot.wait_newer(need, timeout=timeout)
                    finally:
                        self._state_wait_until = None
                else:
                    self._wakeup = loop.create_future()
                    self._sleep_until = ready
                    try:
                        await wait_resolved(self._wakeup, timeout)
                    finally:
                        self._wakeup = self._sleep_until = None
        finally:
            self._running = False
            for client in self._waiting:  # the slot closed, or the station stops
                client.wake()

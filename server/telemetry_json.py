"""The vehicle state as JSON, encoded once per state version and shared by every client.

The body is cached by version; each WebSocket message is a short prefix (`t_server`,
`t_server_mono`: the source's clock when the message was built: the station's for a live
vehicle, the log's for a replay, as the state's times are) spliced onto that shared
body. The telemetry pump (server/telemetry_pump.py) builds one message per tick and every
due client sends it, so twenty browsers cost one encode, not twenty. Within a body each
group's JSON is cached too: a state shares the groups that did not change with the one
before (companion.vehicle_state), so a new version encodes only the group or two that
its packet changed. orjson encodes a group straight from its frozen dataclass, in C,
several times faster than `json.dumps` of a dict built in Python: these run 50 times a
second on the Pi.

    {"t_server": unix_s, "t_server_mono": monotonic_s, "version": n,
     "state": {"heartbeat": {...}, "gps": {...}, ..., "link": {...}}}

Each group carries `t_mono` (station monotonic time of its last update; a browser's age
for it is `t_server_mono - t_mono`) and the vehicle's own `time_boot_ms`/`time_usec`.
Non-finite floats (NaN from an autopilot) become null (orjson's rule): browsers reject
NaN in JSON. Tuples become arrays, nested groups (`messages.recent`) objects.
"""

from __future__ import annotations

from dataclasses import fields
from typing import Any

import orjson

from fpv_station.companion.latest import Versioned
from fpv_station.companion.source_clock import SourceClock
from fpv_station.companion.vehicle_state import VehicleState

_GROUPS = tuple(f.name for f in fields(VehicleState))


class SharedStateJson:
    """Caches the JSON body of the newest version. Used from the event loop only.

    `clock` is the source's (companion.source_clock): a group's age in a browser is
    `t_server_mono - t_mono`, and a replay stamps its groups with the log's time."""

    def __init__(self, clock: SourceClock | None = None) -> None:
        self.clock = clock or SourceClock()
        self._current: Versioned[VehicleState] | None = None
        self._body = ""
        self.encodes = 0  # how many times a body was built (for tests and benchmarks)
        # group name -> (the group, its JSON); holding the group keeps its identity unique
        self._groups: dict[str, tuple[Any, str]] = {}

    def body(self, current: Versioned[VehicleState]) -> str:
        # Identity, not version: each publish makes a new Versioned, and a slot swapped
        # by another service (the twin) may reuse version numbers.
        if current is not self._current:
            parts = []
            for name in _GROUPS:
                group = getattr(current.value, name)
                cached = self._groups.get(name)
                if cached is None or cached[0] is not group:
                    cached = (group, orjson.dumps(group).decode())
                    self._groups[name] = cached
                parts.append(f'"{name}":{cached[1]}')
            self._body = f'{{"version":{current.version},"state":{{{",".join(parts)}}}}}'
            self._current = current
            self.encodes += 1
        return self._body

    def message(self, current: Versioned[VehicleState]) -> str:
        body = self.body(current)
        clock = self.clock
        return f'{{"t_server":{clock.wall():.6f},"t_server_mono":{clock.mono():.6f},{body[1:]}'

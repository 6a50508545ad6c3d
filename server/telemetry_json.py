"""The vehicle state as JSON, encoded once per state version and shared by every client.

The body is cached by version; each WebSocket message is a short prefix (`t_server`,
`t_server_mono`: the source's clock when the message was built: the station's for a live
vehicle, the log's for a replay, as the state's times are) spliced onto that shared
body. The telemetry pump (server/telemetry_pump.py) builds one message per tick and every
due client sends it, so twenty browsers cost one `json.dumps`, not twenty. Within a body each
group's JSON is cached too: a state shares the groups that did not change with the one
before (companion.vehicle_state), so a new version encodes only the group or two that
its packet changed.

    {"t_server": unix_s, "t_server_mono": monotonic_s, "version": n,
     "state": {"heartbeat": {...}, "gps": {...}, ..., "link": {...}}}

Each group carries `t_mono` (station monotonic time of its last update; a browser's age
for it is `t_server_mono - t_mono`) and the vehicle's own `time_boot_ms`/`time_usec`.
Non-finite floats (NaN from an autopilot) become null: browsers reject NaN in JSON.
"""

from __future__ import annotations

import json
import math
from dataclasses import fields, is_dataclass
from typing import Any

from companion.latest import Versioned
from companion.source_clock import SourceClock
from companion.vehicle_state import VehicleState

_GROUPS = tuple(f.name for f in fields(VehicleState))
_GROUP_FIELDS: dict[type, tuple[str, ...]] = {}


def _group_dict(group: Any) -> dict[str, Any]:
    names = _GROUP_FIELDS.get(type(group))
    if names is None:
        names = _GROUP_FIELDS[type(group)] = tuple(f.name for f in fields(group))
    out: dict[str, Any] = {}
    for name in names:
        v = getattr(group, name)
        if type(v) is float and not math.isfinite(v):
            v = None
        elif type(v) is tuple and v and is_dataclass(v[0]):  # a log: messages.recent
            v = [_group_dict(item) for item in v]
        out[name] = v
    return out


def state_to_dict(state: VehicleState) -> dict[str, Any]:
    """Plain JSON-able dict with the contract's names (tuples become lists)."""
    return {g: _group_dict(getattr(state, g)) for g in _GROUPS}


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
                    cached = (group, json.dumps(_group_dict(group), separators=(",", ":")))
                    self._groups[name] = cached
                parts.append(f'"{name}":{cached[1]}')
            # The same text as json.dumps({"version": v, "state": state_to_dict(state)}).
            self._body = f'{{"version":{current.version},"state":{{{",".join(parts)}}}}}'
            self._current = current
            self.encodes += 1
        return self._body

    def message(self, current: Versioned[VehicleState]) -> str:
        body = self.body(current)
        clock = self.clock
        return f'{{"t_server":{clock.wall():.6f},"t_server_mono":{clock.mono():.6f},{body[1:]}'

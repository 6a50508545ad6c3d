"""The shared telemetry JSON: the whole state, built from per-group pieces that are
re-encoded only when their group changed."""

from __future__ import annotations

import dataclasses
import json
import math

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from fpv_station.companion.latest import Versioned
from fpv_station.companion.state_tracker import StateTracker
from fpv_station.core.mavlink.framing import MavFramer
from fpv_station.server.telemetry_json import SharedStateJson
from tests.mav_vehicle import DEFAULT_RATES_HZ, MavVehicle


def states_of_a_link() -> list:
    """The states a link publishes for real packets: every type the test vehicle sends,
    a STATUSTEXT (the messages log) and a NaN from the autopilot."""
    vehicle = MavVehicle("udp")
    tracker, framer = StateTracker(), MavFramer()
    packets = [vehicle.build(name) for _ in range(3) for name in DEFAULT_RATES_HZ]
    packets.append(vehicle.mav.statustext_encode(mavlink.MAV_SEVERITY_WARNING, b"Low battery"))
    states = []
    for t, msg in enumerate(packets):
        for parsed in framer.feed(msg.pack(vehicle.mav)):
            if tracker.update(parsed, float(t)):
                states.append(tracker.state)
    vehicle.stop()
    last = states[-1]
    states.append(
        dataclasses.replace(last, vfr_hud=dataclasses.replace(last.vfr_hud, climb_mps=math.nan))
    )
    return states


def plain(value):
    """The JSON the contract promises for a state's value: groups as objects in field
    order, tuples as arrays, non-finite floats as null."""
    if dataclasses.is_dataclass(value):
        return {f.name: plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, tuple):
        return [plain(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def test_each_body_is_the_whole_state_and_only_changed_groups_are_encoded():
    shared = SharedStateJson()
    states = states_of_a_link()
    assert len(states) > 20 and states[-2].messages.count >= 1
    for version, state in enumerate(states, 1):
        current = Versioned(version, state)
        body = shared.body(current)
        assert json.loads(body) == {"version": version, "state": plain(state)}
        assert list(json.loads(body)["state"]) == [f.name for f in dataclasses.fields(state)]
        assert "NaN" not in body  # browsers reject it
        assert shared.body(current) is body  # one build per version, shared by clients
    assert json.loads(body)["state"]["vfr_hud"]["climb_mps"] is None  # NaN: null in JSON
    assert shared.encodes == len(states)
    # A new version whose groups are all the previous ones' encodes none of them again.
    cached = dict(shared._groups)
    shared.body(Versioned(len(states) + 1, states[-1]))
    assert all(shared._groups[g][1] is cached[g][1] for g in cached)

"""Flight truth: what the station reports against what really happened, per shaped case.

    python benchmarks/accuracy.py

Each case is a log or a vehicle whose truth is known because we wrote it
(tests/shaped_tlog.py, tests/mav_vehicle.py, the twin): shaped tlogs go through the real
`replay:` source into a real server and are read over HTTP, the way the tests do
(tests/test_flight_truth.py, test_forward_rates.py, test_twin_mission.py). Prints one
markdown table for docs/ACCURACY.md.
"""

from __future__ import annotations

import json
import math
import os
import socket
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import httpx  # noqa: E402
import numpy as np  # noqa: E402
from pymavlink import mavutil  # noqa: E402

from fpv_station.analysis.report import analyze_paths  # noqa: E402
from fpv_station.companion.recording import layout  # noqa: E402
from fpv_station.server.app import create_app  # noqa: E402
from fpv_station.twin.runner import Twin  # noqa: E402
from fpv_station.twin.sensors import SensorParams  # noqa: E402
from fpv_station.twin.sim import SimConfig  # noqa: E402
from tests import shaped_tlog  # noqa: E402
from tests.helpers import free_port, run_uvicorn, station_settings, wait_until  # noqa: E402
from tests.known_flights import (  # noqa: E402
    ARDUPILOT,
    DASH_FADE,
    DASH_SPEED_MPS,
    EKF_CASES,
    EKF_HOP_M,
    JOINED_SORTIES,
    JOINED_SORTIES_END_S,
    dash,
    two_sorties,
)
from tests.mav_vehicle import MavVehicle  # noqa: E402
from tests.replayed import (  # noqa: E402
    by_stream,
    mavloss,
    pilot_altitudes,
    replay_status,
    replayed_sessions,
)
from tests.twin_gcs import MISSION, REL, take_off, upload  # noqa: E402

mav = mavutil.mavlink
ROWS: list[tuple[str, str, str, str, str]] = []


def row(case: str, quantity: str, truth: str, station: str, error: str) -> None:
    ROWS.append((case, quantity, truth, station, error))
    print(f"{case} | {quantity} | {truth} | {station} | {error}", file=sys.stderr)


def loss_cases(tmp: Path) -> None:
    for name, gap in (("SiK radio, 2 GCSs, 2 % loss, 1.8 s fade", (60.0, 62.3)),
                      ("same, 3.8 s fade (> 255 packets)", (60.0, 64.3))):  # fmt: skip
        log = shaped_tlog.sik_radio_link(gap=gap)
        path = log.write(tmp / "loss.tlog")
        link = replay_status(path)["link"]
        truth = 100 * log.truth[(1, 1)].loss_ratio
        station = 100 * link["loss_ratio"]
        ref = mavloss(path)[(1, 1)]
        row(name, "autopilot loss %", f"{truth:.2f}", f"{station:.2f} (mavloss {ref:.1f})",
            f"{station - truth:+.2f} pp (vs mavloss {station - ref:+.2f} pp)")  # fmt: skip
        radio = by_stream(link)[(51, 68)]
        row(name, "radio lost / duplicates", f"0 / {log.truth[(51, 68)].duplicates}",
            f"{radio['lost']} / {radio['duplicates']}", f"{radio['lost']} lost")  # fmt: skip


def silence_case(tmp: Path) -> None:
    speed = 10
    path = shaped_tlog.silent_vehicle().write(tmp / "silent.tlog")
    settings = station_settings(f"replay:{path}?speed={speed}", tmp / "sessions")
    with run_uvicorn(create_app(settings)) as base:
        httpx.post(f"{base}/api/recording/start")
        wait_until(lambda: httpx.get(f"{base}/api/status").json()["link"]["replay_done"], 60)
        session = httpx.post(f"{base}/api/recording/stop").json()["last_stop"]["id"]
    meta = json.loads((tmp / "sessions" / session / layout.SESSION_JSON).read_text())
    losses = meta["quality"]["link_loss"]
    got = sum(iv["end_s"] - iv["start_s"] for iv in losses)  # the log's seconds
    row("autopilot silent 45 s, radio + QGC talking (replay x10)", "session link_loss (log s)",
        "45.0", f"{got:.1f} in {len(losses)} interval(s)", f"{got - 45.0:+.1f} s")  # fmt: skip


def battery_case(tmp: Path) -> None:
    path = shaped_tlog.no_battery_monitor().write(tmp / "nobatt.tlog")
    volts = replay_status(path)["state"]["battery"]["voltage_v"]
    row("no battery monitor (SYS_STATUS 0 mV)", "battery voltage", "unknown", str(volts),
        "none" if volts is None else "wrong")  # fmt: skip


def forward_rate_case() -> None:
    port = free_port(socket.SOCK_DGRAM)
    other = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=255)
    with MavVehicle("udp") as v:
        settings = station_settings(
            v.station_source, **{"link.forward": [f"udpout:127.0.0.1:{port}"]}
        )
        with run_uvicorn(create_app(settings)) as base:
            status = lambda: httpx.get(f"{base}/api/status").json()["link"]  # noqa: E731
            wait_until(lambda: status()["stream_request"] == "message_interval", 15)
            other.wait_heartbeat(timeout=10)
            other.mav.command_long_send(
                1, 1, mav.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                mav.MAVLINK_MSG_ID_ATTITUDE, 500_000, 0, 0, 0, 0, 0,
            )  # fmt: skip
            time.sleep(3.0)  # a full rate window after the change
            hz = status()["rates_hz"].get("ATTITUDE", 0.0)
    other.close()
    row("MAVProxy on --forward asks ATTITUDE at 2 Hz", "ATTITUDE rate heard (Hz)", "50 (asked)",
        f"{hz:.1f}", f"{hz - 50:+.1f} Hz")  # fmt: skip


def twin() -> tuple[Twin, Any]:  # pymavlink's connection (untyped)
    port = free_port(socket.SOCK_DGRAM)
    gcs = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=255)
    t = Twin(config=SimConfig(sensors=SensorParams(enabled=False)),
             mavlink=f"udpout:127.0.0.1:{port}")  # fmt: skip
    t.step_for(2.5)
    gcs.wait_heartbeat(timeout=5)
    return t, gcs


def twin_cases() -> None:
    kinds = {
        "QGC on PX4 (COMMAND_LONG, AMSL)": lambda g, h: g.mav.command_long_send(
            1, 1, mav.MAV_CMD_NAV_TAKEOFF, 0, -1, 0, 0, math.nan, math.nan, math.nan, h + 3.0),
        "MAVProxy `takeoff 3` (COMMAND_LONG, above home)": lambda g, h: g.mav.command_long_send(
            1, 1, mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 0, 3.0),
        "COMMAND_INT, GLOBAL_RELATIVE_ALT_INT": lambda g, h: g.mav.command_int_send(
            1, 1, REL, mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, math.nan, 0, 0, 3.0),
    }  # fmt: skip
    for name, send in kinds.items():
        t, gcs = twin()
        height = take_off(t, gcs, send)
        t.stop()
        gcs.close()
        row(f"twin take-off, {name}", "height reached (m)", "3.0", f"{height:.2f}",
            f"{height - 3.0:+.2f} m")  # fmt: skip

    t, gcs = twin()
    upload(t, gcs, MISSION)
    gcs.mav.set_mode_send(1, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, (4 << 16) | (4 << 24))
    gcs.mav.command_long_send(1, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
    track = []
    for _ in range(240):
        t.step_for(0.25)
        track.append(t.pose().pos_enu_m.copy())
        while gcs.recv_match(blocking=False) is not None:
            pass
        if len(track) > 20 and not t.sim.commander.armed[0]:
            break
    path = np.array(track)
    for east, north in ((-8.0, 0.0), (-8.0, 6.0)):
        miss = float(np.min(np.hypot(path[:, 0] - east, path[:, 1] - north)))
        where = f"closest to waypoint ({east:g}, {north:g}) m"
        row("twin AUTO.MISSION (uploaded by MISSION_ITEM_INT)", where,
            "0 (accept radius 1 m)", f"{miss:.2f} m", f"{miss:.2f} m")  # fmt: skip
    home = float(np.hypot(*(path[-1, :2] - t.scene.start_xy_m)))
    row("twin AUTO.MISSION", "landing point from home (m)", "0", f"{home:.2f}", f"{home:.2f} m")
    t.stop()
    gcs.close()


def reset_case() -> None:
    app = create_app(station_settings("sim", **{"twin.realtime_factor": 10.0}))
    with run_uvicorn(app):
        station = app.state.station
        wait_until(lambda: station.twin.sim.t_s > 120.0, 60)
        station.twin.reset()
        t0 = last = time.monotonic()
        gap = 0.0  # the longest wait for an ATTITUDE over the 5 s after Reset
        while (now := time.monotonic()) < t0 + 5.0:
            heard = station.state.get().value.attitude.t_mono or 0.0
            last = max(last, heard)
            gap = max(gap, now - last)
            time.sleep(0.005)
    row("twin Reset after 120 s of sim time (x10)", "longest telemetry silence in 5 s after "
        "Reset (s)", "0.02 (50 Hz ATTITUDE)", f"{gap:.2f}", f"{gap - 0.02:+.2f} s")  # fmt: skip


def ekf_origin_cases(tmp: Path) -> None:
    for case, (flight, origin_s) in EKF_CASES.items():
        path = shaped_tlog.vehicle_flight(flight, ARDUPILOT, origin_set_s=origin_s).write(
            tmp / "ekf.tlog"
        )
        alts, _ = pilot_altitudes(path)
        top = float(alts.max())
        row(f"ArduPilot EKF origin jump to 180 m AMSL, {case}, 1.3 m hop",
            "highest pilot's altitude while armed (m)", f"{EKF_HOP_M:.2f}", f"{top:.2f}",
            f"{top - EKF_HOP_M:+.2f} m")  # fmt: skip


def burst_case(tmp: Path) -> None:
    path = shaped_tlog.vehicle_flight(dash(), fade=DASH_FADE, burst_s=1.0).write(tmp / "burst.tlog")
    (r,) = analyze_paths([path], "a-to-b", scene=False).results
    row("28 m/s dash, 4.3 s fade then a 1 s burst", "max speed (m/s)", f"{DASH_SPEED_MPS:.1f} (GPS)",
        f"{r.max_speed_mps:.2f}", f"{r.max_speed_mps - DASH_SPEED_MPS:+.2f} m/s")  # fmt: skip


def replay_speed_cases(tmp: Path) -> None:
    path = shaped_tlog.vehicle_flight(two_sorties()).write(tmp / "sorties.tlog")
    runs = {
        speed: replayed_sessions(path, speed, tmp / f"s{speed}") for speed in ("1", "20", "max")
    }
    for speed, sessions in runs.items():
        times = " / ".join(f"{s['result']['trial_time_s']:.2f}" for s in sessions)
        reasons = " / ".join(str(s["stop_reason"]) for s in sessions)
        worst = max(abs(s["result"]["trial_time_s"] - 10.0) for s in sessions)
        row(f"2 sorties 10 s apart, log ends armed, replay x{speed}",
            "sessions; trial times (s); stop reasons", "2; 10.00 / 10.00; disarmed / source ended",
            f"{len(sessions)}; {times}; {reasons}", f"{worst:.2f} s")  # fmt: skip


def joined_flights_case(tmp: Path) -> None:
    path = shaped_tlog.vehicle_flight(
        two_sorties(JOINED_SORTIES, end_s=JOINED_SORTIES_END_S)
    ).write(tmp / "joined.tlog")
    settings = station_settings(
        f"replay:{path}?speed=max", tmp / "joined", **{"recording.auto_record_on_arm": True}
    )
    with run_uvicorn(create_app(settings)) as base:
        get = lambda url: httpx.get(f"{base}{url}", timeout=30).json()  # noqa: E731
        wait_until(lambda: get("/api/status")["link"]["replay_done"], 60)
        wait_until(lambda: not get("/api/recording")["recording"], 10)
        (session,) = get("/api/sessions")
        rows = get(f"/api/sessions/{session['id']}/analysis?task=a-to-b")["results"]
    times = " / ".join(f"{r['trial_time_s']:.2f}" for r in rows)
    row("2 flights 3 s apart in one session (the tail joins them)", "trial rows; trial times (s)",
        "2; 10.00 / 10.00", f"{len(rows)}; {times}",
        f"{max(abs(r['trial_time_s'] - 10.0) for r in rows):.2f} s")  # fmt: skip


def main() -> None:
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        loss_cases(tmp)
        silence_case(tmp)
        battery_case(tmp)
        ekf_origin_cases(tmp)
        burst_case(tmp)
        replay_speed_cases(tmp)
        joined_flights_case(tmp)
    forward_rate_case()
    twin_cases()
    reset_case()
    print(f"load average {os.getloadavg()[0]:.1f}")
    print("| case | quantity | truth | station | error |")
    print("| --- | --- | --- | --- | --- |")
    for r in ROWS:
        print("| " + " | ".join(r) + " |")


if __name__ == "__main__":
    main()

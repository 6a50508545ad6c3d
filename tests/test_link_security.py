"""The vehicle link on a hostile network: datagrams from addresses other
than the link's peer, and MAVLink 2 signing on and off. Real uvicorn stations, real UDP
sockets, real MAVLink bytes from pymavlink's encoder (and its signing, as MAVProxy uses
it); what is checked is what the station shows (/api/status, its state) and records."""

from __future__ import annotations

import contextlib
import csv
import hashlib
import json
import os
import pty
import select
import socket
import time
import tty

import httpx
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink
from websockets.sync.client import connect

from fpv_station.companion.link import MavlinkLink
from fpv_station.companion.recording import layout
from fpv_station.core.mavlink.signing import write_key_file
from fpv_station.server.app import create_app
from fpv_station.server.cli import main as cli_main
from fpv_station.server.settings import SettingsError
from fpv_station.twin.runner import Twin
from tests.helpers import free_port, run_uvicorn, station_settings, wait_until
from tests.mav_vehicle import MavVehicle
from tests.twin_flights import NO_CAMERAS

REAL_LAT, FORGED_LAT = 43.0021, 12.5
PASSPHRASE = "field day 2026"
KEY = hashlib.sha256(PASSPHRASE.encode()).digest()  # MAVProxy's `signing setup PASSPHRASE`
WRONG_KEY = hashlib.sha256(b"not the field's passphrase").digest()


@contextlib.contextmanager
def station(source: str, tmp_path, **overrides):
    # The station asks for no rates: a position stays as the last packet set it.
    overrides = {"link.request_streams": False, **overrides}
    app = create_app(station_settings(source, tmp_path / "sessions", **overrides))
    with run_uvicorn(app) as base:
        yield app, base


def security(base: str) -> dict:
    return httpx.get(f"{base}/api/status").json()["link"]["security"]


def state(app):
    latest = app.state.station.state.get()
    return latest.value if latest else None


def forged_position(lat_deg: float, sysid: int = 1, compid: int = 1) -> bytes:
    """GPS_RAW_INT and GLOBAL_POSITION_INT in the vehicle's name, in one datagram."""
    mav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=compid)
    lat, lon = int(lat_deg * 1e7), int(-78.7875e7)
    gps = mav.gps_raw_int_encode(1, 3, lat, lon, 180000, 80, 120, 0, 0, 12)
    gpi = mav.global_position_int_encode(1000, lat, lon, 180000, 0, 0, 0, 0, 0)
    return gps.pack(mav) + gpi.pack(mav)


def sync(v: MavVehicle, app, roll: float) -> None:
    """Send a marker through the vehicle's own path and wait until the station applied it:
    everything sent to the station's socket before it has been handled."""
    v.roll_rad = roll
    v.send_now("ATTITUDE")
    assert wait_until(lambda: state(app).attitude.roll_rad == pytest.approx(roll), timeout=5)


def position_fixed(v: MavVehicle, app) -> None:
    """The vehicle's real position in the state (after its heartbeat made it the one
    followed)."""
    assert wait_until(lambda: state(app) and state(app).heartbeat.sysid == v.sysid, timeout=5)
    v.send_now("GPS_RAW_INT")
    v.send_now("GLOBAL_POSITION_INT")
    assert wait_until(lambda: state(app) and state(app).gps.lat_deg == pytest.approx(REAL_LAT))
    assert wait_until(lambda: state(app).global_position.lat_deg == pytest.approx(REAL_LAT))


def assert_position_real(app) -> None:
    s = state(app)
    assert s.gps.lat_deg == pytest.approx(REAL_LAT)
    assert s.global_position.lat_deg == pytest.approx(REAL_LAT)


# -- who may send: the link's peer only ---------------------------------------------------

# Only heartbeats on their own: positions are sent by the test, so that a forged one would
# stay in the state until the next real one.
QUIET = {"HEARTBEAT": 2.0}


def test_udpout_drops_a_forged_position_from_another_socket(tmp_path) -> None:
    with MavVehicle("udp", answer_sender=True, rates_hz=QUIET) as v:
        overrides = {"recording.auto_record_on_arm": True, "recording.post_disarm_tail_s": 0.2}
        with station(v.station_source, tmp_path, **overrides) as (app, base):
            assert wait_until(lambda: v.reply_to is not None, timeout=5)  # the station spoke
            assert wait_until(lambda: state(app) and state(app).heartbeat.autopilot == "px4")
            position_fixed(v, app)
            v.arm()
            assert wait_until(lambda: httpx.get(f"{base}/api/recording").json()["recording"])
            forged = forged_position(FORGED_LAT)
            station_addr = v.reply_to  # the station's own link socket
            assert station_addr is not None
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as attacker:
                attacker.bind(("127.0.0.1", 0))
                for _ in range(3):
                    attacker.sendto(forged, station_addr)
                sync(v, app, 0.25)
                assert_position_real(app)
                sec = security(base)
                assert sec["foreign_datagrams"] == 3
                host, port = attacker.getsockname()
                assert sec["last_foreign_sender"] == f"{host}:{port}"
                assert sec["peer"] == f"127.0.0.1:{v.port}" and sec["signing"] is False
            time.sleep(0.3)  # recorder rows past the forged packets
            v.disarm()
            assert wait_until(lambda: not httpx.get(f"{base}/api/recording").json()["recording"])
            session = httpx.get(f"{base}/api/recording").json()["last_stop"]["id"]
    folder = tmp_path / "sessions" / session
    tlog = (folder / layout.MAVLINK_TLOG).read_bytes()
    assert forged[:20] not in tlog and len(tlog) > 0
    with open(folder / layout.TELEMETRY_CSV, newline="") as f:
        rows = list(csv.DictReader(f))
    lats = {r[k] for r in rows for k in ("gps.lat_deg", "global_position.lat_deg")}
    assert lats == {"43.0021"}


def test_udpin_locks_to_the_first_sender_and_counts_others(tmp_path) -> None:
    with MavVehicle("udp", rates_hz=QUIET) as v:
        with station(v.station_source, tmp_path) as (app, base):
            assert wait_until(lambda: state(app) and state(app).heartbeat.autopilot == "px4")
            position_fixed(v, app)
            # Another host on the network (127.0.0.2 is another address on this host's
            # loopback): same ids as the vehicle, to the station's udpin port.
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as attacker:
                attacker.bind(("127.0.0.2", 0))
                attacker.sendto(forged_position(FORGED_LAT), ("127.0.0.1", v.station_port))
                sync(v, app, 0.5)
                assert_position_real(app)
                sec = security(base)
                assert sec["foreign_datagrams"] == 1 and sec["udpin_lock"] is True
                assert sec["last_foreign_sender"].startswith("127.0.0.2:")
                assert sec["peer"] == f"127.0.0.1:{v.port}"
                # The station still answers the vehicle, not the other host.
                before = len(v.received)
                assert wait_until(lambda: len(v.received) > before, timeout=3)


def test_udpin_unlocked_hears_every_sender(tmp_path) -> None:
    """`link.udpin_lock = false`: every host is heard, for several feeding one port."""
    with MavVehicle("udp", rates_hz=QUIET) as v:
        with station(v.station_source, tmp_path, **{"link.udpin_lock": False}) as (app, base):
            assert wait_until(lambda: state(app) and state(app).heartbeat.autopilot == "px4")
            position_fixed(v, app)
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as other:
                other.bind(("127.0.0.2", 0))
                other.sendto(forged_position(FORGED_LAT), ("127.0.0.1", v.station_port))
                assert wait_until(
                    lambda: state(app).gps.lat_deg == pytest.approx(FORGED_LAT), timeout=5
                )
            assert security(base)["foreign_datagrams"] == 0


def test_udpin_lock_follows_the_hosts_new_port_and_shares_it_with_a_radio(tmp_path) -> None:
    """A bridge restarted on the same host comes back from another port; a SiK radio
    (sysid 51, compid 68, a MAVLink 1 RADIO_STATUS) behind the same address is heard."""
    with MavVehicle("udp", rates_hz=QUIET) as v:
        with station(v.station_source, tmp_path) as (app, base):
            assert wait_until(lambda: state(app) and state(app).heartbeat.autopilot == "px4")
            v.silent = True  # the bridge restarts: its next packets come from another port
            with MavVehicle(
                "udp", station_port=v.station_port, sysid=51, compid=68, mavlink1=True, rates_hz={}
            ) as radio:
                radio.send_message(radio.mav.radio_status_encode(200, 190, 80, 10, 20, 0, 0))
                assert wait_until(lambda: security(base)["peer"] == f"127.0.0.1:{radio.port}")
                streams = httpx.get(f"{base}/api/status").json()["link"]["streams"]
                assert any(s["sysid"] == 51 and s["compid"] == 68 for s in streams)
            v.silent = False
            position_fixed(v, app)  # the vehicle again, from its own port
            assert wait_until(lambda: security(base)["peer"] == f"127.0.0.1:{v.port}")
            assert security(base)["foreign_datagrams"] == 0


# -- MAVLink 2 signing --------------------------------------------------------------------


def key_file(tmp_path, passphrase: str = PASSPHRASE):
    return write_key_file(tmp_path / "mavlink.key", passphrase)


def test_signed_twin_and_station_work_end_to_end(tmp_path) -> None:
    """`--source sim` with a key: the twin signs and obeys only signed packets; the
    station's state follows it and its commands (arm, take-off) reach it. The waits are
    hang guards for a loaded machine, where the twin and the station share two cores."""
    overrides = {
        "link.signing_key_file": str(key_file(tmp_path)),
        "twin.realtime_factor": 2.0,
        **NO_CAMERAS,
    }
    with station("sim", tmp_path, **overrides) as (app, base):
        twin = app.state.station.twin
        assert wait_until(lambda: state(app) and state(app).gps.fix_type == 3, timeout=60)
        # Arming commands to the twin's own port, unsigned and with the wrong key: refused,
        # and its telemetry still goes to the station, not to the sender.
        twin_addr = twin.vehicle.sock.getsockname()
        counts = twin.vehicle.signing.counts
        for n, key in enumerate((None, WRONG_KEY), start=1):
            mav = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
            if key is not None:
                mav.signing.secret_key, mav.signing.sign_outgoing = key, True
                mav.signing.timestamp = int((time.time() - 1420070400) * 1e5)
            arm = mav.command_long_encode(1, 1, 400, 0, 1, 21196, 0, 0, 0, 0, 0)
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as attacker:
                attacker.sendto(arm.pack(mav), twin_addr)
                assert wait_until(lambda n=n: counts.unsigned + counts.bad_signature == n, 30)
        assert counts.unsigned == 1 and counts.bad_signature == 1
        assert not twin.sim.commander.armed[0]
        version = app.state.station.state.get().version
        assert wait_until(lambda: app.state.station.state.get().version > version + 10, 30)
        ws_url = base.replace("http", "ws")
        with connect(ws_url + "/ws/control") as ws:
            json.loads(ws.recv(timeout=30))  # hello
            ws.send(json.dumps({"type": "arm"}))
            reply = json.loads(ws.recv(timeout=30))
            assert (reply["type"], reply["cmd"], reply["ok"]) == ("ack", "arm", True)
            assert wait_until(lambda: state(app).heartbeat.armed, timeout=30)
        sec = security(base)
        assert sec["signing"] is True and sec["signed"] > 20
        assert sec["unsigned_refused"] == sec["bad_signature_refused"] == 0
        assert counts.signed > 0 and counts.unsigned == counts.bad_signature == 1


def test_signing_refuses_unsigned_wrong_key_and_replayed_packets(tmp_path) -> None:
    port = free_port(socket.SOCK_DGRAM)
    overrides = {"link.signing_key_file": str(key_file(tmp_path))}
    with station(f"udpin:127.0.0.1:{port}", tmp_path, **overrides) as (app, base):
        # Another host speaks first, unsigned: refused, and it does not take the lock.
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as attacker:
            attacker.bind(("127.0.0.2", 0))
            attacker.sendto(forged_position(FORGED_LAT), ("127.0.0.1", port))
            assert wait_until(lambda: security(base)["unsigned_refused"] == 2, timeout=5)
        assert security(base)["peer"] is None
        # A vehicle without the key: heard at the socket, refused by signing.
        with MavVehicle("udp", station_port=port, rates_hz=QUIET) as unsigned:
            unsigned.send_now("GPS_RAW_INT")
            assert wait_until(lambda: security(base)["unsigned_refused"] >= 3, timeout=5)
        assert state(app).heartbeat.sysid is None and state(app).gps.lat_deg is None
        # The same address with the wrong key: refused too.
        with MavVehicle("udp", station_port=port, rates_hz=QUIET, signing_key=WRONG_KEY) as w:
            w.send_now("GPS_RAW_INT")
            assert wait_until(lambda: security(base)["bad_signature_refused"] >= 3, timeout=5)
        assert state(app).heartbeat.sysid is None and state(app).gps.lat_deg is None
        # The right key: heard, and what the station sends it is signed.
        with MavVehicle("udp", station_port=port, rates_hz=QUIET, signing_key=KEY) as v:
            position_fixed(v, app)
            assert wait_until(lambda: state(app).heartbeat.autopilot == "px4", timeout=5)
            assert wait_until(lambda: len(v.received) >= 2, timeout=5)
            assert all(v.signed(m) for m in list(v.received))
            # A captured good packet sent again (a replay) is refused.
            v.lat_deg = FORGED_LAT
            captured = v.send_now("GPS_RAW_INT")
            assert wait_until(lambda: state(app).gps.lat_deg == pytest.approx(FORGED_LAT))
            v.lat_deg = REAL_LAT
            position_fixed(v, app)
            v.inject(captured)
            assert wait_until(lambda: security(base)["replay_refused"] == 1, timeout=5)
            sync(v, app, 0.75)
            assert_position_real(app)
            # A forged signed packet with a far-future timestamp and a bad signature must
            # not make the vehicle's genuine packets look old (pymavlink's own check would).
            forged = bytearray(captured)
            forged[-12:-6] = (2**48 - 1).to_bytes(6, "little")
            v.inject(bytes(forged))
            sync(v, app, 1.0)
            sec = security(base)
            assert sec["replay_refused"] == 1 and sec["bad_signature_refused"] >= 4
            # One figure for all of signing's refusals, which the pilot's OSD reads.
            reasons = ("unsigned_refused", "bad_signature_refused", "replay_refused")
            assert sec["refused"] == sum(sec[r] for r in reasons)
            # A SiK radio behind the same address cannot sign: its RADIO_STATUS (MAVLink 1)
            # passes, as MAVProxy and ArduPilot let it; anything else it sent would not.
            with MavVehicle(
                "udp", station_port=port, sysid=51, compid=68, mavlink1=True, rates_hz={}
            ) as radio:
                radio.send_message(radio.mav.radio_status_encode(200, 190, 80, 10, 20, 0, 0))
                assert wait_until(lambda: security(base)["unsigned_allowed"] == 1, timeout=5)
                unsigned_before = security(base)["unsigned_refused"]
                radio.send_now("HEARTBEAT")
                assert wait_until(
                    lambda: security(base)["unsigned_refused"] == unsigned_before + 1, timeout=5
                )
            streams = httpx.get(f"{base}/api/status").json()["link"]["streams"]
            assert any(s["sysid"] == 51 and s["compid"] == 68 for s in streams)


def test_a_vehicle_whose_signing_clock_is_behind_is_heard_once_it_hears_us(tmp_path) -> None:
    """A vehicle that booted with its signing clock a week behind (no GPS yet; ArduPilot
    keeps the last one it saved): its new stream is refused as too old until our signed
    heartbeats move its clock forward, as the protocol asks; then it is heard and locked."""
    port = free_port(socket.SOCK_DGRAM)
    overrides = {"link.signing_key_file": str(key_file(tmp_path))}
    with station(f"udpin:127.0.0.1:{port}", tmp_path, **overrides) as (app, base):
        week = 7 * 86400.0
        with MavVehicle(
            "udp", station_port=port, rates_hz=QUIET, signing_key=KEY, signing_clock_s=-week
        ) as v:
            assert wait_until(lambda: security(base)["replay_refused"] >= 1, timeout=5)
            position_fixed(v, app)
            assert security(base)["peer"] == f"127.0.0.1:{v.port}"


def test_signing_over_a_stream_link_hears_the_signed_vehicle(tmp_path) -> None:
    """TCP (and serial, the Pi's usual link) has one peer by construction: a signed
    vehicle there is heard and answered with signed packets, unsigned packets refused."""
    overrides = {"link.signing_key_file": str(key_file(tmp_path))}
    with MavVehicle("tcp", rates_hz=QUIET, signing_key=KEY) as v:
        with station(v.station_source, tmp_path, **overrides) as (app, base):
            position_fixed(v, app)
            assert wait_until(lambda: len(v.received) >= 2, timeout=5)
            assert all(v.signed(m) for m in list(v.received))
            sec = security(base)
            assert sec["signed"] > 0 and sec["peer"] is None
            assert httpx.get(f"{base}/api/status").json()["link"]["last_error"] is None


def test_signing_over_a_serial_port_hears_the_signed_vehicle(tmp_path) -> None:
    """The Pi's usual link, a UART, here a pty: the signed vehicle is heard, an unsigned
    packet on the same wire is refused, and what the station writes to it is signed."""
    master, slave = pty.openpty()
    tty.setraw(master)
    os.set_blocking(master, False)
    vehicle = MavVehicle("udp", signing_key=KEY)  # its signing encoder and state only
    vehicle._sock.close()
    stranger = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)  # no key
    settings = station_settings(
        f"{os.ttyname(slave)}:921600", **{"link.signing_key_file": str(key_file(tmp_path))}
    )
    link = MavlinkLink(settings.link)
    link.start()
    parser = mavlink.MAVLink(None)
    parser.signing.secret_key = KEY  # pymavlink checks what the station signed
    heard: list = []
    try:
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and not (
            link.state.current().heartbeat.sysid == 1 and any(m.get_signed() for m in heard)
        ):
            os.write(master, vehicle.build("HEARTBEAT").pack(vehicle.mav))
            os.write(
                master, stranger.gps_raw_int_encode(1, 3, 0, 0, 0, 80, 120, 0, 0, 9).pack(stranger)
            )
            time.sleep(0.05)
            with contextlib.suppress(BlockingIOError):
                heard += parser.parse_buffer(os.read(master, 4096)) or []
        assert link.state.current().heartbeat.autopilot == "px4"
        assert heard and all(m.get_signed() for m in heard)
        sec = link.health().security
        assert sec.signed > 0 and sec.unsigned_refused > 0 and link.running
    finally:
        link.stop()
        os.close(master)
        os.close(slave)


def test_signing_off_hears_unsigned_and_signed_packets(tmp_path) -> None:
    with MavVehicle("udp", rates_hz=QUIET) as v:
        with station(v.station_source, tmp_path) as (app, base):
            position_fixed(v, app)
            assert wait_until(lambda: len(v.received) >= 2, timeout=5)  # the station's beats
            assert not any(v.signed(m) for m in list(v.received))
            assert security(base)["signing"] is False
    with MavVehicle("udp", rates_hz=QUIET, signing_key=KEY) as signed:
        with station(signed.station_source, tmp_path) as (app, base):
            position_fixed(signed, app)  # a signature it cannot check is no reason to refuse
            sec = security(base)
            assert sec["signing"] is False and sec["unsigned_refused"] == 0


# -- the key file --------------------------------------------------------------------------


def test_a_key_file_others_can_read_is_refused_with_a_clear_error(tmp_path, capsys) -> None:
    path = key_file(tmp_path)
    os.chmod(path, 0o644)
    with pytest.raises(SettingsError, match="chmod 600"):
        station_settings("sim", **{"link.signing_key_file": str(path)})
    assert cli_main(["serve", "--source", "sim", "--signing-key", str(path)]) == 2
    assert "open to other users" in capsys.readouterr().err


def test_the_key_is_the_passphrase_hashed_as_mavproxy_does(tmp_path) -> None:
    """A twin given MAVProxy's key for the passphrase (SHA-256 of it) talks to a station
    given the passphrase file (with the newline `echo` leaves)."""
    port = free_port(socket.SOCK_DGRAM)
    overrides = {"link.signing_key_file": str(key_file(tmp_path))}
    with station(f"udpin:127.0.0.1:{port}", tmp_path, **overrides) as (app, base):
        with Twin(mavlink=f"udpout:127.0.0.1:{port}", signing_key=KEY) as twin:
            assert wait_until(lambda: state(app) and state(app).heartbeat.autopilot == "px4")
            assert twin.vehicle is not None and twin.vehicle.signing is not None
            signing = twin.vehicle.signing
            assert wait_until(lambda: signing.counts.signed > 0, timeout=5)
        sec = security(base)
        assert sec["signed"] > 0 and sec["unsigned_refused"] == sec["bad_signature_refused"] == 0


@pytest.mark.parametrize(
    ("content", "mode", "error"),
    [
        (b"", 0o600, "is empty"),
        (b"\xff\xfe\x00key", 0o600, "is not text"),
        (PASSPHRASE.encode(), 0o640, "open to other users"),
        (None, 0o600, "does not exist"),
    ],
)
def test_unusable_key_files_say_why(tmp_path, content, mode, error) -> None:
    path = tmp_path / "mavlink.key"
    if content is not None:
        path.write_bytes(content)
        os.chmod(path, mode)
    with pytest.raises(SettingsError, match=error):
        station_settings("sim", **{"link.signing_key_file": str(path)})


def test_the_pilot_sees_refused_mavlink_on_the_osd(tmp_path) -> None:
    """While the station refuses datagrams, the OSD over the front video says so."""
    from playwright.sync_api import expect

    from tests.helpers import chromium

    with MavVehicle("udp") as v, station(v.station_source, tmp_path) as (app, base):
        with chromium() as browser:
            page = browser.new_page(viewport={"width": 1280, "height": 800})
            page.goto(base + "/")
            warning = page.locator("[data-osd=warning]")
            expect(page.locator("[data-osd=mode]")).to_have_text("POSCTL", timeout=30_000)
            time.sleep(2.5)  # a poll of /api/status with nothing refused
            expect(warning).not_to_contain_text("MAVLINK REFUSED")
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as attacker:
                attacker.bind(("127.0.0.2", 0))
                deadline = time.monotonic() + 8
                while time.monotonic() < deadline:
                    attacker.sendto(forged_position(FORGED_LAT), ("127.0.0.1", v.station_port))
                    time.sleep(0.5)
                    if "MAVLINK REFUSED" in (warning.text_content() or ""):
                        break
            expect(warning).to_contain_text("MAVLINK REFUSED")


def test_serve_flags_set_the_link_defences(tmp_path) -> None:
    from fpv_station.server.cli import build_parser, settings_from_args

    key = key_file(tmp_path)
    args = build_parser().parse_args(
        [
            "serve",
            "--source",
            "udpin:0.0.0.0:14550",
            "--udpin-any-sender",
            "--signing-key",
            str(key),
        ]
    )
    link = settings_from_args(args).link
    assert link.udpin_lock is False and link.signing_key() == KEY
    default = settings_from_args(build_parser().parse_args(["serve"])).link
    assert default.udpin_lock is True and default.signing_key() is None


def test_udpin_reads_a_burst_at_one_wake_up_and_still_refuses_a_foreign_datagram() -> None:
    """The link reads every datagram queued at a wake-up (an autopilot's streams come in
    bursts), one at a time, so the lock still refuses another host's datagram inside the
    burst; with nothing queued the read returns at once."""
    from fpv_station.companion.transports import UdpTransport, parse_connection

    port = free_port(socket.SOCK_DGRAM)
    transport = UdpTransport(parse_connection(f"udpin:127.0.0.1:{port}"))
    packets = [forged_position(REAL_LAT + k * 1e-4) for k in range(3)]
    with (
        contextlib.closing(transport),
        socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as vehicle,
        socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as other,
    ):
        vehicle.bind(("127.0.0.1", 0))
        other.bind(("127.0.0.2", 0))
        vehicle.sendto(packets[0], ("127.0.0.1", port))
        other.sendto(forged_position(FORGED_LAT), ("127.0.0.1", port))
        for p in packets[1:]:
            vehicle.sendto(p, ("127.0.0.1", port))
        assert select.select([transport], [], [], 5)[0]
        assert list(transport.read_queued()) == packets
        assert transport.foreign.datagrams == 1
        assert transport.peer == vehicle.getsockname()
        assert list(transport.read_queued()) == []


def test_signing_lets_the_udpin_lock_follow_the_vehicle_to_a_new_address(tmp_path) -> None:
    """A vehicle behind a Wi-Fi bridge that rebooted comes back from another address (a
    new DHCP lease). Without signing the lock cannot tell it from an attacker and holds;
    with signing, once the old address has been silent `link.link_lost_s`, its signed
    packets move the lock there. While the peer is heard, other hosts' datagrams are
    dropped before they are parsed: unsigned ones, a radio's RADIO_STATUS, and another
    holder of the key (a signed ground station elsewhere, system 7) alike."""
    port = free_port(socket.SOCK_DGRAM)
    overrides = {"link.signing_key_file": str(key_file(tmp_path))}
    with station(f"udpin:127.0.0.1:{port}", tmp_path, **overrides) as (app, base):
        with MavVehicle("udp", station_port=port, rates_hz=QUIET, signing_key=KEY) as v:
            position_fixed(v, app)
            assert security(base)["peer"] == f"127.0.0.1:{v.port}"
        with MavVehicle(
            "udp", station_port=port, rates_hz=QUIET, signing_key=KEY, host="127.0.0.2"
        ) as moved:
            # Its heartbeats, heard once the old address has been silent long enough.
            new_peer = f"127.0.0.2:{moved.port}"
            assert wait_until(lambda: security(base)["peer"] == new_peer, timeout=15)
            sync(moved, app, 0.25)
            before = len(moved.received)
            assert wait_until(lambda: len(moved.received) > before, timeout=5)  # answered
            assert all(moved.signed(m) for m in list(moved.received))
            sec = security(base)
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as attacker:
                attacker.bind(("127.0.0.3", 0))
                radio = mavlink.MAVLink(None, srcSystem=51, srcComponent=68)
                attacker.sendto(
                    forged_position(FORGED_LAT)
                    + radio.radio_status_encode(200, 190, 80, 10, 20, 0, 0).pack(radio),
                    ("127.0.0.1", port),
                )
                foreign = sec["foreign_datagrams"] + 1
                assert wait_until(lambda: security(base)["foreign_datagrams"] == foreign)
            with MavVehicle(
                "udp",
                station_port=port,
                rates_hz=QUIET,
                signing_key=KEY,
                host="127.0.0.4",
                sysid=7,
            ) as other_key_holder:
                other_key_holder.send_now("HEARTBEAT")
                assert wait_until(lambda: security(base)["foreign_datagrams"] > foreign)
            sync(moved, app, 0.5)
            assert_position_real(app)
            after = security(base)
            assert after["peer"] == new_peer
            assert after["unsigned_allowed"] == 0
            # Dropped unparsed: signing never saw them.
            for count in ("unsigned_refused", "bad_signature_refused"):
                assert after[count] == sec[count], count
            streams = httpx.get(f"{base}/api/status").json()["link"]["streams"]
            assert not any(s["sysid"] in (7, 51) for s in streams)


# -- the station's own identity, other hosts, and the ground stations we forward to -------


def signer(sysid: int, compid: int, key: bytes | None) -> mavlink.MAVLink:
    """An encoder that signs with `key` from the wall clock on (None: unsigned)."""
    mav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=compid)
    if key is not None:
        mav.signing.secret_key, mav.signing.sign_outgoing = key, True
        mav.signing.timestamp = int((time.time() - 1420070400) * 1e5)
    return mav


@contextlib.contextmanager
def link_on(source: str, **settings):
    """A started MavlinkLink and the packets it hands its listeners (the recorder's)."""
    from fpv_station.companion.link_settings import LinkSettings

    link = MavlinkLink(LinkSettings(source=source, request_streams=False, **settings))
    got: list[bytes] = []
    link.add_packet_listener(lambda t, packet: got.append(packet))
    link.start()
    try:
        yield link, got
    finally:
        link.stop()


def link_state(link):
    latest = link.state.get()
    return latest.value if latest else None


@pytest.mark.parametrize("signing", [True, False])
def test_packets_in_the_stations_own_identity_are_a_clash_refused_when_signing(
    tmp_path, signing
) -> None:
    """From the vehicle's own address (the lock passes it), signed with the key: a
    ground station set up with our system and component id, or our own packets sent
    back. It is an identity clash either way; with signing on it is refused (not
    recorded, not forwarded), although its signature is good."""
    port = free_port(socket.SOCK_DGRAM)
    key = KEY if signing else None
    extra = {"signing_key_file": key_file(tmp_path)} if signing else {}
    with (
        link_on(f"udpin:127.0.0.1:{port}", **extra) as (link, got),
        MavVehicle("udp", station_port=port, rates_hz=QUIET, signing_key=key) as v,
    ):
        assert wait_until(lambda: link_state(link).heartbeat.sysid == 1, timeout=10)
        assert link.health().security.own_identity_packets == 0
        impostor = signer(254, 190, key)  # link.gcs_sysid / gcs_compid
        arm = impostor.command_long_encode(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0).pack(impostor)
        v.inject(arm)
        assert wait_until(lambda: link.health().security.own_identity_packets == 1)
        health = link.health()
        assert health.gcs_identity_clash
        v.send_now("ATTITUDE")  # after it on the same socket: everything before is handled
        assert wait_until(lambda: link_state(link).attitude.t_mono is not None)
        assert (bytes(arm) in got) is not signing
        if signing:  # refused before the signature check: no count of signing's moved
            assert health.security.signed > 0 and health.security.bad_signature_refused == 0


def test_with_signing_another_hosts_datagrams_are_dropped_unparsed(tmp_path) -> None:
    """While the peer is heard, a flood from another host with the wrong key is dropped
    at the socket and counted there (`foreign_datagrams`), never checked by signing:
    checking every flooded signature cost the link thread several times as much."""
    port = free_port(socket.SOCK_DGRAM)
    with (
        link_on(f"udpin:127.0.0.1:{port}", signing_key_file=key_file(tmp_path)) as (link, _),
        MavVehicle("udp", station_port=port, rates_hz={"HEARTBEAT": 5.0}, signing_key=KEY) as v,
        socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as attacker,
    ):
        assert wait_until(lambda: link_state(link).heartbeat.sysid == 1, timeout=10)
        attacker.bind(("127.0.0.2", 0))
        wrong = signer(1, 1, WRONG_KEY)
        for i in range(200):
            attacker.sendto(
                wrong.attitude_encode(i, 1.0, 0, 0, 0, 0, 0).pack(wrong), ("127.0.0.1", port)
            )
            if i % 20 == 0:
                time.sleep(0.005)  # within the socket's buffer
        v.roll_rad = 0.5
        v.send_now("ATTITUDE")  # queued after the flood
        assert wait_until(lambda: link_state(link).attitude.roll_rad == pytest.approx(0.5))
        sec = link.health().security
        assert sec.foreign_datagrams >= 150  # loopback may drop a few when the buffer fills
        assert sec.bad_signature_refused == 0  # never parsed
        assert sec.peer == f"127.0.0.1:{v.port}"


def test_forwarded_ground_stations_packets_are_checked_and_counted(tmp_path) -> None:
    """A ground station on --forward with the key is passed to the vehicle; one set up as
    MAVProxy reads a passphrase of several words (its first word's key) and one without a
    key are refused, counted, neither passed on nor recorded."""
    port = free_port(socket.SOCK_DGRAM)
    first_word_key = hashlib.sha256(PASSPHRASE.split()[0].encode()).digest()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as gcs:
        gcs.bind(("127.0.0.1", 0))
        gcs.settimeout(5)
        forward = [f"udpout:127.0.0.1:{gcs.getsockname()[1]}"]
        with (
            link_on(
                f"udpin:127.0.0.1:{port}", signing_key_file=key_file(tmp_path), forward=forward
            ) as (link, got),
            MavVehicle("udp", station_port=port, rates_hz=QUIET, signing_key=KEY) as v,
        ):
            assert wait_until(lambda: link_state(link).heartbeat.sysid == 1, timeout=10)
            _, station_addr = gcs.recvfrom(65535)  # the vehicle's packets reach it
            sent = {}
            for name, key, param in (
                ("keyed", KEY, 1.0),
                ("mavproxy", first_word_key, 2.0),
                ("unsigned", None, 3.0),
            ):
                mav = signer(255, 190, key)
                packet = mav.command_long_encode(1, 1, 31010, 0, param, 0, 0, 0, 0, 0, 0).pack(mav)
                sent[name] = bytes(packet)
                gcs.sendto(packet, station_addr)
            sec = lambda: link.health().security  # noqa: E731
            assert wait_until(lambda: sec().forward_unsigned_refused == 1)
            assert wait_until(lambda: sec().forward_bad_signature_refused == 1)
            assert wait_until(lambda: sec().forward_signed == 1)
            params = lambda: [  # noqa: E731
                m.param1 for m in list(v.received) if m.get_type() == "COMMAND_LONG"
            ]
            assert wait_until(lambda: 1.0 in params())
            assert params() == [1.0]
            assert sent["keyed"] in got
            assert sent["mavproxy"] not in got and sent["unsigned"] not in got
            assert sec().refused >= 2  # the OSD's one figure counts them


def test_a_passphrase_of_several_words_warns_that_mavproxy_reads_it_differently(
    tmp_path, caplog
) -> None:
    from fpv_station.companion.link_settings import LinkSettings

    for passphrase, warned in ((PASSPHRASE, True), ("fieldday2026", False)):
        caplog.clear()
        path = write_key_file(tmp_path / f"{warned}.key", passphrase)
        port = free_port(socket.SOCK_DGRAM)
        link = MavlinkLink(LinkSettings(source=f"udpin:127.0.0.1:{port}", signing_key_file=path))
        link.stop()
        messages = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
        assert any("hashes only the first" in m for m in messages) is warned, messages

"""MavlinkLink through real sockets: UDP, TCP, a pty serial port, and tlog replay."""

import contextlib
import os
import pty
import random
import resource
import socket
import time
import tty

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from fpv_station.companion.forward_resolver import ForwardResolver
from fpv_station.companion.link import MavlinkLink
from fpv_station.companion.link_health import ForwardTarget
from fpv_station.companion.link_settings import LinkSettings
from fpv_station.companion.transports import UdpTransport, format_addr, parse_connection
from fpv_station.core.mavlink.tlog_records import write_record
from tests.helpers import free_port
from tests.helpers import wait_until as _wait_until
from tests.mav_vehicle import MavVehicle, running_link


def wait_until(predicate, timeout=10.0):
    """Generous: six engineers' suites share two cores; it returns as soon as true."""
    return _wait_until(predicate, max(timeout, 10.0))


def state(link):
    current = link.state.get()
    return current.value if current else None


@pytest.mark.parametrize("transport", ["udp", "tcp"])
def test_state_over_udp_and_tcp(transport):
    with MavVehicle(transport) as v, running_link(v.station_source) as link:
        assert wait_until(lambda: state(link).heartbeat.mode == "POSCTL")
        assert wait_until(lambda: state(link).altitude.reference == "first_fix")
        v.arm()
        v.alt_m += 3.5
        assert wait_until(lambda: state(link).altitude.relative_alt_m == pytest.approx(3.5))
        assert state(link).heartbeat.armed and state(link).altitude.reference == "arming"
        assert not state(link).link.link_lost
        # The station introduces itself as a GCS at ~1 Hz.
        assert wait_until(lambda: v.received_types().count("HEARTBEAT") >= 2, timeout=3)
        hb = next(m for m in v.received if m.get_type() == "HEARTBEAT")
        assert hb.type == mavlink.MAV_TYPE_GCS
        # Not QGroundControl's (or Mission Planner's) 255/190: both may talk to this vehicle.
        assert (hb.get_srcSystem(), hb.get_srcComponent()) == (254, 190)


def test_message_intervals_requested_and_rates_measured():
    with MavVehicle("udp") as v, running_link(v.station_source) as link:
        assert wait_until(lambda: link.health().stream_request == "message_interval")
        assert v.rates_hz["ATTITUDE"] == pytest.approx(50.0)  # asked via SET_MESSAGE_INTERVAL
        assert v.rates_hz["GPS_RAW_INT"] == pytest.approx(5.0)
        time.sleep(2.3)  # a full rate window at the new rates
        rates = link.health().rates_hz
        # Half the asked rate as the floor, as everywhere (a starved CI box; the figures
        # are the benchmarks'): ATTITUDE's is still above the vehicle's own 20 Hz.
        assert 25 < rates["ATTITUDE"] < 60, rates
        assert 2.5 < rates["GPS_RAW_INT"] < 6.5, rates
        assert 0.5 < rates["HEARTBEAT"] < 1.6, rates
        assert link.health().bytes_per_s > 1000


@pytest.mark.parametrize("reply", ["unsupported", "ignore"])
def test_falls_back_to_request_data_stream(reply):
    with MavVehicle("udp", interval_reply=reply) as v, running_link(v.station_source) as link:
        assert wait_until(lambda: link.health().stream_request == "data_stream", timeout=4)
        assert wait_until(lambda: "REQUEST_DATA_STREAM" in v.received_types())
        streams = {
            m.req_stream_id: m.req_message_rate
            for m in v.received
            if m.get_type() == "REQUEST_DATA_STREAM"
        }
        assert streams[mavlink.MAV_DATA_STREAM_EXTRA1] == 50  # ATTITUDE
        assert streams[mavlink.MAV_DATA_STREAM_POSITION] == 25


def test_loss_counted_from_sequence_numbers():
    with MavVehicle("udp") as v, running_link(v.station_source) as link:
        assert wait_until(lambda: link.health().packets > 20)
        assert link.health().lost_packets == 0
        v.skip_seq(5)
        time.sleep(0.2)
        v.skip_seq(3)
        assert wait_until(lambda: link.health().lost_packets == 8), link.health()
        h = link.health()
        assert 0 < h.loss_ratio < 0.5


def test_link_lost_and_recovered():
    with MavVehicle("udp") as v, running_link(v.station_source) as link:
        assert wait_until(lambda: not state(link).link.link_lost)
        version = link.state.version
        v.silent = True
        assert wait_until(lambda: state(link).link.link_lost, timeout=3)
        assert link.state.version > version  # a lost link is published as a change
        assert link.health().link_lost and link.health().since_heartbeat_s >= 1.5
        v.silent = False
        assert wait_until(lambda: not state(link).link.link_lost, timeout=3)
        # Regained: the rates are asked for again (the autopilot may have rebooted).
        n_rates = len(LinkSettings().message_rates_hz)
        assert wait_until(lambda: v.received_types().count("COMMAND_LONG") >= 2 * n_rates)


def test_random_garbage_and_corrupt_packets_interleaved():
    rng = random.Random(3)
    with (
        MavVehicle("udp", rates_hz={"HEARTBEAT": 5.0}) as v,
        running_link(v.station_source) as link,
    ):
        assert wait_until(lambda: state(link).heartbeat.t_mono is not None)
        for i in range(200):
            v.inject(bytes(rng.randrange(256) for _ in range(rng.randrange(1, 60))))
            v.roll_rad = i / 1000
            pkt = v.send_now("ATTITUDE")
            if i % 20 == 0:
                time.sleep(0.01)  # a real link paces its bytes; don't overflow UDP buffers
            if i % 20 == 0:
                bad = bytearray(pkt)
                bad[-2] ^= 0x55
                v.inject(bytes(bad))
        v.inject(b"\x00" * 300)
        assert wait_until(lambda: state(link).attitude.roll_rad == pytest.approx(0.199))
        h = link.health()
        assert h.garbage_bytes > 1000 and h.bad_crc >= 10
        assert h.packets >= 200  # every good ATTITUDE got through


def test_other_systems_on_the_link_are_ignored():
    with MavVehicle("udp", sysid=3) as ap:
        other = MavVehicle("udp", sysid=200, autopilot="invalid", station_port=ap.station_port)
        other.roll_rad = 1.0
        with other, running_link(ap.station_source) as link:
            other.rates_hz["ATTITUDE"] = 20.0
            assert wait_until(lambda: state(link).heartbeat.sysid == 3)
            time.sleep(0.3)
            assert state(link).attitude.roll_rad == 0.0
            assert link.health().autopilot_sysid == 3


def test_tcp_reconnects_when_the_peer_drops_and_returns():
    port = free_port()
    v = MavVehicle("tcp", port=port).start()
    with running_link(f"tcp:127.0.0.1:{port}") as link:
        assert wait_until(lambda: not state(link).link.link_lost)
        v.stop()  # the vehicle goes away entirely
        assert wait_until(lambda: state(link).link.link_lost, timeout=3)
        assert wait_until(lambda: not link.health().connected)
        with MavVehicle("tcp", port=port) as v2:  # and comes back on the same port
            v2.set_mode("ALTCTL")
            assert wait_until(lambda: state(link).heartbeat.mode == "ALTCTL", timeout=5)
            assert not state(link).link.link_lost
            assert link.health().reconnects >= 1


def test_serial_port_over_a_pty():
    master, slave = pty.openpty()
    tty.setraw(master)
    vehicle = MavVehicle("udp")  # used for its encoder and flight state only
    vehicle._sock.close()
    try:
        with running_link(f"{os.ttyname(slave)}:921600") as link:
            deadline = time.monotonic() + 5
            while time.monotonic() < deadline and state(link).heartbeat.mode != "POSCTL":
                for name in ("HEARTBEAT", "ATTITUDE", "GLOBAL_POSITION_INT"):
                    os.write(master, vehicle.build(name).pack(vehicle.mav))
                time.sleep(0.05)
            assert state(link).heartbeat.mode == "POSCTL"
            assert link.health().connected
            # The GCS heartbeat comes out of the serial port.
            got = b""
            deadline = time.monotonic() + 3
            parser = mavlink.MAVLink(None)
            types = []
            while time.monotonic() < deadline and "HEARTBEAT" not in types:
                got = os.read(master, 4096)
                types += [m.get_type() for m in parser.parse_buffer(got) or []]
            assert "HEARTBEAT" in types
    finally:
        os.close(master)
        os.close(slave)


def test_missing_serial_port_is_reported_and_retried():
    with running_link("/dev/does-not-exist:57600") as link:
        assert wait_until(lambda: link.health().last_error is not None)
        assert "does not exist" in link.health().last_error
        assert wait_until(lambda: link.health().reconnects >= 2, timeout=3)
        assert link.running


def test_replay_of_a_written_tlog_in_order_with_truncated_tail(tmp_path):
    v = MavVehicle("udp")
    v._sock.close()
    path = tmp_path / "flight.tlog"
    sent = []
    with open(path, "wb") as f:
        t = 1_700_000_000.0
        for i in range(60):
            v.roll_rad = i / 100
            for name in ("HEARTBEAT", "ATTITUDE") if i % 10 == 0 else ("ATTITUDE",):
                pkt = bytes(v.build(name).pack(v.mav))
                v.mav.seq = (v.mav.seq + 1) % 256
                write_record(f, t, pkt)
                sent.append(pkt)
            t += 0.005
        write_record(f, t, bytes(v.build("ATTITUDE").pack(v.mav))[:-7])  # cut by power loss
    got = []
    link = MavlinkLink(LinkSettings(source=f"replay:{path}?speed=4"))
    link.add_packet_listener(lambda t_wall, pkt: got.append(pkt))
    t0 = time.monotonic()
    link.start()
    try:
        assert wait_until(lambda: link.health().replay_done, timeout=5)
        elapsed = time.monotonic() - t0
        assert got == sent  # every packet, in order
        assert link.health().truncated_records == 1
        assert state(link).attitude.roll_rad == pytest.approx(0.59)
        assert 0.06 < elapsed < 4.0  # 0.3 s of log at 4x real time: paced, not at once
    finally:
        link.stop()


def test_forwarding_and_send_reach_both_ends():
    qgc = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    qgc.bind(("127.0.0.1", 0))
    qgc.settimeout(2)
    fwd = f"udpout:127.0.0.1:{qgc.getsockname()[1]}"
    with MavVehicle("udp") as v, running_link(v.station_source, forward=[fwd]) as link:
        data, addr = qgc.recvfrom(65535)  # raw copies of the vehicle's packets
        parser = mavlink.MAVLink(None)
        assert parser.parse_buffer(data)[0].get_srcSystem() == 1
        # What QGroundControl sends goes to the vehicle.
        qmav = mavlink.MAVLink(None, srcSystem=250)
        qgc.sendto(qmav.param_request_list_encode(1, 1).pack(qmav), addr)
        assert wait_until(lambda: "PARAM_REQUEST_LIST" in v.received_types())
        # And link.send() from any thread.
        link.send(link.mav.manual_control_encode(1, 100, -200, 500, 0, 0))
        assert wait_until(lambda: "MANUAL_CONTROL" in v.received_types())
        mc = next(m for m in v.received if m.get_type() == "MANUAL_CONTROL")
        assert (mc.x, mc.y, mc.z) == (100, -200, 500)
    qgc.close()


def test_forward_by_name_is_looked_up_off_the_link_and_a_name_that_fails_costs_nothing():
    """A forward target given by name is resolved by the resolver's thread (a lookup can
    block for seconds; the link starts on the event loop), and a name that does not
    resolve (the laptop not on the Wi-Fi yet) leaves the vehicle link as it was and says
    so in the health."""
    qgc = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    qgc.bind(("127.0.0.1", 0))
    qgc.settimeout(5)
    port = qgc.getsockname()[1]
    forward = [f"udpout:localhost:{port}", "udpout:qgc-laptop.invalid:14550"]
    with MavVehicle("udp") as v, running_link(v.station_source, forward=forward) as link:
        data, _ = qgc.recvfrom(65535)  # the vehicle's packets, sent to the name's address
        assert mavlink.MAVLink(None).parse_buffer(data)[0].get_srcSystem() == 1
        assert wait_until(lambda: state(link) and state(link).heartbeat.autopilot == "px4")
        assert wait_until(lambda: link.health().forwards[1].error is not None, timeout=15)
        by_name, missing = link.health().forwards
        assert by_name == ForwardTarget(f"udpout:localhost:{port}", f"127.0.0.1:{port}")
        assert missing.address is None and "qgc-laptop.invalid" in missing.error
        assert link.running
    qgc.close()


def test_forward_resolver_follows_the_names_address_and_keeps_it_when_a_lookup_fails():
    """The laptop joins late, then gets another DHCP address; the DNS server goes away.
    The lookup is what cannot happen here (no DNS to change): it is replaced, at that
    boundary; the sockets and datagrams are real."""
    laptop_a, laptop_b = (socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(2))
    for s in (laptop_a, laptop_b):
        s.bind(("127.0.0.1", 0))
        s.settimeout(0.2)
    answers: list = [socket.gaierror(-2, "Name or service not known")]

    def lookup(host: str, port: int) -> tuple[str, int]:
        assert (host, port) == ("qgc.local", 14550)
        answer = answers[0]
        if isinstance(answer, OSError):
            raise answer
        return answer

    spec = parse_connection("udpout:qgc.local:14550")
    fwd = UdpTransport(spec, resolve_name=False)
    resolver = ForwardResolver([(spec, fwd)], interval_s=60, resolve=lookup)

    def arrives(sock) -> bool:
        fwd.write(b"copy")
        try:
            return sock.recv(100) == b"copy"
        except TimeoutError:
            return False

    try:
        resolver.resolve_all()  # not on the network yet: nothing is sent anywhere
        (target,) = resolver.targets()
        assert target.address is None and "Name or service not known" in target.error
        assert not arrives(laptop_a)
        answers[0] = laptop_a.getsockname()
        resolver.resolve_all()
        assert resolver.targets()[0].error is None
        assert arrives(laptop_a)
        answers[0] = laptop_b.getsockname()  # another DHCP lease
        resolver.resolve_all()
        assert arrives(laptop_b) and not arrives(laptop_a)
        answers[0] = socket.gaierror(-3, "Temporary failure in name resolution")
        resolver.resolve_all()  # the DNS server went away: keep sending where it works
        assert resolver.targets()[0].address == format_addr(laptop_b.getsockname())
        assert "Temporary failure" in resolver.targets()[0].error
        assert arrives(laptop_b)
    finally:
        fwd.close()
        laptop_a.close()
        laptop_b.close()


def test_listener_errors_never_stop_the_link():
    with MavVehicle("udp") as v, running_link(v.station_source) as link:
        link.add_packet_listener(lambda t, p: 1 / 0)
        seen = []
        link.add_packet_listener(lambda t, p: seen.append(t))
        assert wait_until(lambda: len(seen) > 20)
        assert abs(seen[-1] - time.time()) < 2  # wall time labels
        assert link.running


def test_serial_port_that_goes_away_and_comes_back(tmp_path):
    """A USB cable pulled and plugged back: the device path vanishes, then returns."""
    port_path = tmp_path / "ttyACM0"  # a symlink standing in for the udev device node
    vehicle = MavVehicle("udp")
    vehicle._sock.close()

    def plug():
        master, slave = pty.openpty()
        tty.setraw(master)
        port_path.unlink(missing_ok=True)
        port_path.symlink_to(os.ttyname(slave))
        return master, slave

    def feed_until(master, pred):
        deadline = time.monotonic() + 6
        while time.monotonic() < deadline and not pred():
            try:
                os.write(master, vehicle.build("HEARTBEAT").pack(vehicle.mav))
            except OSError:
                pass
            time.sleep(0.05)
        return pred()

    master, slave = plug()
    with running_link(str(port_path)) as link:
        assert feed_until(master, lambda: state(link).heartbeat.mode == "POSCTL")
        os.close(master)  # unplugged: the station's reads fail
        os.close(slave)
        port_path.unlink()
        assert wait_until(lambda: not link.health().connected, timeout=3)
        vehicle.mode = "ALTCTL"
        master, slave = plug()
        try:
            assert feed_until(master, lambda: state(link).heartbeat.mode == "ALTCTL")
            assert link.health().reconnects >= 1
        finally:
            os.close(master)
            os.close(slave)


def test_mavlink1_autopilot_gets_mavlink1_replies():
    with MavVehicle("tcp", mavlink1=True, autopilot="ardupilot", sysid=77) as v:
        with running_link(v.station_source) as link:
            assert wait_until(lambda: state(link).heartbeat.mavlink_version == 1)
            assert state(link).heartbeat.mode == "LOITER"
            assert state(link).heartbeat.autopilot == "ardupilot"
            assert wait_until(lambda: state(link).attitude.t_mono is not None)
            # Old firmware may drop MAVLink 2 frames: the station answers in MAVLink 1.
            assert wait_until(
                lambda: any(
                    m.get_type() == "HEARTBEAT" and m.get_msgbuf()[0] == 0xFE for m in v.received
                )
            )


@contextlib.contextmanager
def descriptors_below_1024_taken():
    """Every descriptor number under 1024 in use, as in a station that raised its file
    limit to serve many clients (server/client_limits.py): what opens next gets a number
    select() cannot watch (FD_SETSIZE)."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if hard != resource.RLIM_INFINITY and hard < 1200:
        pytest.skip(f"the hard file limit ({hard}) is too low to go past 1023")
    resource.setrlimit(resource.RLIMIT_NOFILE, (max(soft, 1200), hard))
    taken = []
    try:
        while not taken or taken[-1] < 1024:
            taken.append(os.open(os.devnull, os.O_RDONLY))
        yield
    finally:
        for fd in taken:
            os.close(fd)
        resource.setrlimit(resource.RLIMIT_NOFILE, (soft, hard))


def test_udp_link_with_descriptors_above_1023():
    with descriptors_below_1024_taken(), MavVehicle("udp") as v:
        with running_link(v.station_source) as link:
            assert wait_until(lambda: state(link).heartbeat.mode == "POSCTL")
            assert link.health().last_error is None and link.running


def test_serial_link_with_descriptors_above_1023():
    master, slave = pty.openpty()
    tty.setraw(master)
    os.set_blocking(master, False)
    vehicle = MavVehicle("udp")  # its encoder and flight state only
    vehicle._sock.close()
    try:
        with descriptors_below_1024_taken():
            with running_link(f"{os.ttyname(slave)}:921600") as link:
                heard = b""
                deadline = time.monotonic() + 10
                while time.monotonic() < deadline and not (
                    b"\xfd" in heard and state(link).heartbeat.mode == "POSCTL"
                ):
                    with contextlib.suppress(BlockingIOError):  # a link that reads no more
                        os.write(master, vehicle.build("HEARTBEAT").pack(vehicle.mav))
                    time.sleep(0.05)
                    with contextlib.suppress(BlockingIOError):
                        heard += os.read(master, 4096)  # the station's heartbeat: it writes
                assert state(link).heartbeat.mode == "POSCTL"
                assert b"\xfd" in heard and link.running, link.health().last_error
    finally:
        os.close(master)
        os.close(slave)

"""How fast the autopilot's log comes over the MAVLink log protocol, and what the flight
state gets meanwhile: over UDP and over a serial link at 921600 baud.

    python benchmarks/onboard_log.py [--bytes 2000000] [--transport udp serial]

A test vehicle (tests/log_responder.py: heartbeat and telemetry, ATTITUDE at 50 Hz)
serves a log of `--bytes` bytes; a real `MavlinkLink` follows it and
`companion.onboard_log.LogDownload` fetches the log with the default settings. UDP runs on
loopback, as fast as both ends go. Serial runs over a pseudo-terminal pair (the station
opens its slave as a serial port at 921600 baud); a pty does not model baud timing, so
the vehicle paces every byte it writes to 921600 baud (10 bits a byte: 92 160 bytes/s),
its telemetry and the log's packets sharing that wire as on a UART. Prints the
throughput, the download's seconds, and the ATTITUDE rate the station's state got in the
3 s before the download and during it. Note the machine and its load with the figures.
"""

from __future__ import annotations

import argparse
import os
import pty
import select
import sys
import tempfile
import time
import tty
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from fpv_station.companion.link import MavlinkLink  # noqa: E402
from fpv_station.companion.link_settings import LinkSettings  # noqa: E402
from fpv_station.companion.onboard_log import LogDownload, OnboardLogSettings  # noqa: E402
from fpv_station.companion.vehicle_state import VehicleState  # noqa: E402
from fpv_station.core.mavlink.framing import message_id  # noqa: E402
from tests.log_responder import LogResponder  # noqa: E402
from tests.mav_vehicle import DEFAULT_RATES_HZ  # noqa: E402

BAUD = 921600
ATTITUDE_ID = 30
RATES_HZ = {**DEFAULT_RATES_HZ, "ATTITUDE": 50.0}


class SerialLogResponder(LogResponder):
    """The test vehicle on the master side of a pty, writing at `baud` (bytes paced)."""

    def __init__(self, logs: dict[int, bytes], baud: int, **kwargs) -> None:
        super().__init__(logs, **kwargs)
        self.master, self.slave = pty.openpty()
        tty.setraw(self.slave)
        self.station_source = f"{os.ttyname(self.slave)}:{baud}"
        self.byte_s = 10.0 / baud
        self._free_at = time.monotonic()

    def _write(self, data: bytes) -> None:  # called under the send lock: one wire
        start = max(time.monotonic(), self._free_at)
        self._free_at = start + len(data) * self.byte_s
        delay = start - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        os.write(self.master, data)

    def _recv_loop(self) -> None:
        while not self._stop.is_set():
            ready, _, _ = select.select([self.master], [], [], 0.05)
            if not ready:
                continue
            try:
                data = os.read(self.master, 4096)
            except OSError:
                return
            for msg in self._parser.parse_buffer(data) or []:
                if msg.get_type() != "BAD_DATA":
                    self.received.append(msg)
                    self._handle(msg)

    def stop(self) -> None:
        super().stop()
        os.close(self.master)
        os.close(self.slave)


class AttitudeCounter:
    """Counts the ATTITUDE packets the link heard (a packet listener, its thread), and
    the newest attitude's age in the published state at each publish."""

    def __init__(self) -> None:
        self.count = 0
        self.ages: list[float] = []

    def packet(self, t_wall: float, packet: bytes) -> None:
        if message_id(packet) == ATTITUDE_ID:
            self.count += 1

    def state(self, state: VehicleState) -> None:
        if state.attitude.t_mono is not None:
            self.ages.append(time.monotonic() - state.attitude.t_mono)


def run(transport: str, size: int) -> None:
    payload = os.urandom(size)
    if transport == "udp":
        vehicle: LogResponder = LogResponder({1: payload}, rates_hz=RATES_HZ)
    else:
        vehicle = SerialLogResponder({1: payload}, BAUD, rates_hz=RATES_HZ)
    with vehicle, tempfile.TemporaryDirectory() as tmp:
        link = MavlinkLink(LinkSettings(source=vehicle.station_source, request_streams=False))
        counter = AttitudeCounter()
        link.add_packet_listener(counter.packet)
        link.start()
        try:
            deadline = time.monotonic() + 20
            while link.health().autopilot_sysid is None and time.monotonic() < deadline:
                time.sleep(0.1)
            time.sleep(1.0)
            c0, t0 = counter.count, time.monotonic()
            time.sleep(3.0)
            before_hz = (counter.count - c0) / (time.monotonic() - t0)
            download = LogDownload(link, (1, 1), Path(tmp), OnboardLogSettings())
            c0, t0, s0 = counter.count, time.monotonic(), vehicle.sent["ATTITUDE"]
            link.state.add_listener(counter.state)
            download.start()
            download.join(600)
            link.state.remove_listener(counter.state)
            during_hz = (counter.count - c0) / (time.monotonic() - t0)
            sent_hz = (vehicle.sent["ATTITUDE"] - s0) / (time.monotonic() - t0)
            status = download.status.current()
        finally:
            link.stop()
    ages = sorted(counter.ages) or [float("nan")]
    p99_ms = ages[int(0.99 * (len(ages) - 1))] * 1000
    rate = status.received_bytes / status.download_s / 1000 if status.download_s else 0.0
    print(
        f"{transport:6s} {status.state:9s} {status.received_bytes} B in {status.download_s:.1f} s:"
        f" {rate:.1f} kB/s; re-requests {status.re_requests};"
        f" ATTITUDE {before_hz:.1f} Hz before, {during_hz:.1f} Hz during"
        f" (the vehicle sent {sent_hz:.1f} Hz; its packets lost {status.lost_packets});"
        f" state's attitude age p99 {p99_ms:.0f} ms"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--bytes", type=int, default=2_000_000)
    parser.add_argument("--transport", nargs="+", default=["udp", "serial"])
    args = parser.parse_args()
    print(f"load average {os.getloadavg()}, {os.cpu_count()} CPUs")
    for transport in args.transport:
        run(transport, args.bytes)


if __name__ == "__main__":
    main()

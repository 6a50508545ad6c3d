"""What one MAVLink packet costs the link thread: in a warm loop (framing, pymavlink's
decode, the signing check, off here, the state merge, the packet listeners, the publish),
and in a real link thread fed by the test vehicle over UDP at the station's rates.

    python benchmarks/link_packet_cost.py [--packets 20000] [--profile] [--udp-seconds 15]

The packets are the test vehicle's (tests/mav_vehicle.py) in the mix the station asks
for (ATTITUDE, GLOBAL_POSITION_INT and LOCAL_POSITION_NED most). Compare both with the
link thread's CPU per packet in benchmarks/pi_budget.py: from the warm loop to the thread
on its own, what a wake-up, the epoll wait and the recvfrom per datagram and a cold cache
add; from there to the station, what sharing the GIL and the cores with the event loop
and the other threads adds.
"""

from __future__ import annotations

import argparse
import cProfile
import os
import pstats
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from companion.link import MavlinkLink  # noqa: E402
from companion.link_settings import LinkSettings  # noqa: E402
from tests.mav_vehicle import MavVehicle  # noqa: E402

MIX = ["ATTITUDE", "GLOBAL_POSITION_INT", "LOCAL_POSITION_NED"] * 4 + [
    "VFR_HUD",
    "RC_CHANNELS",
    "SERVO_OUTPUT_RAW",
    "GPS_RAW_INT",
    "HEARTBEAT",
    "SYS_STATUS",
    "BATTERY_STATUS",
    "SYSTEM_TIME",
]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--packets", type=int, default=20000)
    ap.add_argument("--profile", action="store_true", help="also print cProfile's top 15")
    ap.add_argument(
        "--udp-seconds", type=float, default=15.0, help="the real thread over UDP (0: not)"
    )
    args = ap.parse_args()
    vehicle = MavVehicle("udp")  # only builds packets: never started
    packets = [vehicle.build(name).pack(vehicle.mav) for name in MIX]
    link = MavlinkLink(LinkSettings(source="udpin:127.0.0.1:1"))  # never started
    link.add_packet_listener(lambda t, p: None)  # as the recorder's tlog hand-off

    def run(n: int) -> float:
        t0 = time.perf_counter()
        for i in range(n):
            link._on_bytes(packets[i % len(packets)], time.monotonic())
            link._publish_state()
        return time.perf_counter() - t0

    run(2000)  # warm up
    seconds = run(args.packets)
    print(
        f"link packet cost: {seconds / args.packets * 1e6:.1f} us per packet "
        f"({args.packets} packets, warm loop, Python {sys.version.split()[0]})"
    )
    if args.profile:
        profiler = cProfile.Profile()
        profiler.runcall(run, args.packets)
        pstats.Stats(profiler).sort_stats("tottime").print_stats(15)
    if args.udp_seconds > 0:
        udp_thread_cost(args.udp_seconds)


def udp_thread_cost(seconds: float) -> None:
    """A real link thread on udpin, the test vehicle sending at the station's rates (in
    this process: its sending thread shares the GIL too), measured from /proc."""
    # What the station asks the autopilot for (about 140 a second), and its heartbeat.
    rates = {"HEARTBEAT": 1.0, **LinkSettings().message_rates_hz}
    with MavVehicle("udp", rates_hz=rates) as vehicle:
        link = MavlinkLink(LinkSettings(source=vehicle.station_source, request_streams=False))
        link.add_packet_listener(lambda t, p: None)
        link.start()
        try:
            time.sleep(3)  # heard, warmed up
            assert link._thread is not None
            stat = f"/proc/self/task/{link._thread.native_id}/stat"

            def cpu_s() -> float:
                fields = Path(stat).read_text().rsplit(")", 1)[1].split()
                return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")

            c0, p0, t0 = cpu_s(), link.health().packets, time.monotonic()
            time.sleep(seconds)
            c1, p1, t1 = cpu_s(), link.health().packets, time.monotonic()
        finally:
            link.stop()
    print(
        f"link thread over UDP: {100 * (c1 - c0) / (t1 - t0):.2f} % of one core, "
        f"{(p1 - p0) / (t1 - t0):.0f} packets/s, {1e6 * (c1 - c0) / max(p1 - p0, 1):.0f} us "
        f"per packet ({seconds:g} s, load {os.getloadavg()[0]:.2f})"
    )


if __name__ == "__main__":
    main()

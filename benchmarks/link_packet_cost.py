"""What one MAVLink packet costs the link thread in a warm loop: framing, pymavlink's
decode, the signing check (off here), the state merge, the packet listeners, the publish.

    python benchmarks/link_packet_cost.py [--packets 20000] [--profile]

The packets are the test vehicle's (tests/mav_vehicle.py) in the mix the station asks
for (ATTITUDE, GLOBAL_POSITION_INT and LOCAL_POSITION_NED most). Compare with the link
thread's CPU per packet in benchmarks/pi_budget.py: the difference is what a wake-up, the
epoll wait and the recvfrom per datagram, and a cold cache each time, add in the station.
"""

from __future__ import annotations

import argparse
import cProfile
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


if __name__ == "__main__":
    main()

"""What MAVLink 2 signing costs the link thread per packet.

    python benchmarks/link_signing.py [--packets 20000]

Builds a realistic mix of packets (the station's default stream rates: ATTITUDE 50 Hz,
GLOBAL_POSITION_INT 25 Hz, ...) with pymavlink's encoder, once unsigned and once signed
with a key, and times, side by side in one run: cutting them out of a byte stream
(`MavFramer.feed`, what every packet costs today) and checking their signatures
(`SignatureCheck.check`). Prints microseconds per packet for each, the share signing adds,
and the CPU that adds at the station's default rates (~150 packets/s). Note the load
average printed with it.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pymavlink.dialects.v20 import ardupilotmega as mavlink  # noqa: E402

from fpv_station.companion.link_settings import LinkSettings  # noqa: E402
from fpv_station.core.mavlink.framing import MavFramer  # noqa: E402
from fpv_station.core.mavlink.signing import enable_signing  # noqa: E402


def packets(n: int, key: bytes | None) -> list[bytes]:
    """`n` packets in the proportions of the station's default rates, signed if `key`."""
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    if key is not None:
        enable_signing(mav, key)
    rates = LinkSettings().message_rates_hz
    builders = {
        "ATTITUDE": lambda t: mav.attitude_encode(t, 0.1, 0.2, 0.3, 0.01, 0.02, 0.03),
        "GLOBAL_POSITION_INT": lambda t: mav.global_position_int_encode(
            t, 430021000, -787875000, 180000, 4000, 10, 20, -5, 9000
        ),
        "LOCAL_POSITION_NED": lambda t: mav.local_position_ned_encode(t, 1, 2, -3, 0.1, 0.2, 0),
        "VFR_HUD": lambda t: mav.vfr_hud_encode(1.0, 1.0, 90, 50, 184.0, 0.1),
        "GPS_RAW_INT": lambda t: mav.gps_raw_int_encode(
            t * 1000, 3, 430021000, -787875000, 180000, 80, 120, 100, 9000, 12
        ),
        "RC_CHANNELS": lambda t: mav.rc_channels_encode(t, 8, *([1500] * 18), 200),
        "SERVO_OUTPUT_RAW": lambda t: mav.servo_output_raw_encode(t * 1000, 0, *([1400] * 16)),
        "SYS_STATUS": lambda t: mav.sys_status_encode(
            0, 0, 0, 500, 12300, 450, 87, 0, 0, 0, 0, 0, 0
        ),
        "BATTERY_STATUS": lambda t: mav.battery_status_encode(
            0, 0, 0, 2500, [4100] * 3 + [65535] * 7, 450, -1, -1, 87
        ),
    }
    cycle = [n for n, hz in rates.items() if n in builders for _ in range(max(1, round(hz)))]
    out = []
    for i in range(n):
        msg = builders[cycle[i % len(cycle)]](i)
        out.append(bytes(msg.pack(mav)))
        mav.seq = (mav.seq + 1) % 256
    return out


def per_packet_us(fn, items: list[bytes], repeat: int = 3) -> float:
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn(items)
        best = min(best, time.perf_counter() - t0)
    return best / len(items) * 1e6


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--packets", type=int, default=20000)
    args = ap.parse_args()
    key = hashlib.sha256(b"benchmark passphrase").digest()
    plain, signed = packets(args.packets, None), packets(args.packets, key)

    def frame(items: list[bytes]) -> None:
        framer = MavFramer()
        for p in items:
            framer.feed(p)

    def check(items: list[bytes]) -> None:
        receiver = mavlink.MAVLink(None, srcSystem=254, srcComponent=190)
        checker = enable_signing(receiver, key)
        for p in items:
            if checker.check(p) != "signed":
                raise SystemExit("a good packet was refused: the benchmark is wrong")

    frame_plain = per_packet_us(frame, plain)
    frame_signed = per_packet_us(frame, signed)
    sig = per_packet_us(check, signed)
    rate = sum(LinkSettings().message_rates_hz.values())
    print(
        f"load average {os.getloadavg()[0]:.2f}, {args.packets} packets, python {sys.version.split()[0]}"
    )
    print(f"framing, unsigned packets: {frame_plain:6.2f} us/packet")
    print(f"framing, signed packets:   {frame_signed:6.2f} us/packet")
    print(f"signature check:           {sig:6.2f} us/packet")
    print(f"signing adds {100 * (frame_signed + sig - frame_plain) / frame_plain:.0f} % to framing")
    print(
        f"at the default {rate:.0f} packets/s: {rate * (frame_signed + sig - frame_plain) / 1e4:.3f} "
        "% of one core more"
    )


if __name__ == "__main__":
    main()

"""What a flood from another host costs the link thread, with signing on and off.

    python benchmarks/link_flood.py [--rate 10000] [--seconds 10]

A real `MavlinkLink` on udpin follows a vehicle (tests/mav_vehicle.py) on 127.0.0.1; a
second process on 127.0.0.2 sends ATTITUDE datagrams signed with a wrong key at `--rate`
per second. Prints the link thread's CPU (its own /proc stat, % of one core) and what the
link counted, once with signing on and once off. Note the load average printed with it.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from fpv_station.companion.link import MavlinkLink  # noqa: E402
from fpv_station.companion.link_settings import LinkSettings  # noqa: E402
from fpv_station.core.mavlink.signing import write_key_file  # noqa: E402
from tests.helpers import free_port  # noqa: E402
from tests.mav_vehicle import MavVehicle  # noqa: E402

PASSPHRASE = "fieldday"
FLOOD = r"""
import hashlib, socket, sys, time
from pymavlink.dialects.v20 import ardupilotmega as mavlink
port, rate, seconds = int(sys.argv[1]), float(sys.argv[2]), float(sys.argv[3])
mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
mav.signing.secret_key, mav.signing.sign_outgoing = hashlib.sha256(b"wrong").digest(), True
mav.signing.timestamp = int((time.time() - 1420070400) * 1e5)
packets = [bytes(mav.attitude_encode(i, 1.0, 0, 0, 0, 0, 0).pack(mav)) for i in range(100)]
sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
sock.bind(("127.0.0.2", 0))
t0, sent = time.monotonic(), 0
while time.monotonic() - t0 < seconds:
    for p in packets:
        sock.sendto(p, ("127.0.0.1", port))
    sent += len(packets)
    while time.monotonic() < t0 + sent / rate:
        time.sleep(0.001)
print(sent)
"""


def thread_cpu_s(tid: int) -> float:
    with open(f"/proc/self/task/{tid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def run(signing: bool, rate: float, seconds: float, folder: Path) -> str:
    port = free_port(socket.SOCK_DGRAM)
    extra = {}
    key = None
    if signing:
        extra["signing_key_file"] = write_key_file(folder / "mavlink.key", PASSPHRASE)
        key = hashlib.sha256(PASSPHRASE.encode()).digest()
    link = MavlinkLink(
        LinkSettings(source=f"udpin:127.0.0.1:{port}", request_streams=False, **extra)
    )
    link.start()
    try:
        with MavVehicle("udp", station_port=port, signing_key=key):
            deadline = time.monotonic() + 10
            while time.monotonic() < deadline:
                got = link.state.get()
                if got is not None and got.value.heartbeat.sysid == 1:
                    break
                time.sleep(0.1)
            thread = link._thread
            assert thread is not None and thread.native_id is not None
            tid = thread.native_id
            c0, t0 = thread_cpu_s(tid), time.monotonic()
            flood = [sys.executable, "-c", FLOOD, str(port), str(rate), str(seconds)]
            sent = subprocess.run(flood, capture_output=True, text=True, check=True).stdout
            c1, t1 = thread_cpu_s(tid), time.monotonic()
            sec = link.health().security
    finally:
        link.stop()
    return (
        f"| {'on' if signing else 'off'} | {int(sent)} | {100 * (c1 - c0) / (t1 - t0):.1f} % "
        f"| {sec.foreign_datagrams} | {sec.bad_signature_refused} |"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rate", type=float, default=10000.0)
    parser.add_argument("--seconds", type=float, default=10.0)
    args = parser.parse_args()
    print(f"load average {os.getloadavg()[0]:.2f}")
    print("| signing | datagrams sent | link thread CPU | dropped unparsed | bad signature |")
    print("|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for signing in (True, False):
            print(run(signing, args.rate, args.seconds, Path(tmp)))


if __name__ == "__main__":
    main()

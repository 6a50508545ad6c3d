"""What one MAVLink packet costs the link thread: in a warm loop (framing, pymavlink's
decode, the signing check, off here, the health meter, the state merge, the recorder's
packet listener, the publish), stage by stage and all together, and in a real link
thread fed by the test vehicle over UDP at the station's rates.

    python benchmarks/link_packet_cost.py [--packets 20000] [--profile] [--udp-seconds 15]

The packets are the test vehicle's (tests/mav_vehicle.py) in the mix and order the
station asks for (`LinkSettings().message_rates_hz` and a 1 Hz heartbeat: 140 a second,
ATTITUDE at 50 Hz the most), one datagram each as over UDP. The recorder listener is a
real `Recorder` with a real `RecordingSession` (files in a temporary folder; its threads
not started, its packet queue emptied between the timed runs), so the stages are the
code the station runs per packet. Compare the sum with the link thread's CPU per packet
in benchmarks/pi_budget.py: from the warm loop to the thread on its own, what a wake-up,
the epoll wait and the recvfrom per datagram and a cold cache add; from there to the
station, what sharing the GIL and the cores with the event loop and the other threads adds.
"""

from __future__ import annotations

import argparse
import cProfile
import os
import pstats
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks.pi_budget import thread_cpu_s  # noqa: E402
from fpv_station.companion.latest import Latest  # noqa: E402
from fpv_station.companion.link import MavlinkLink  # noqa: E402
from fpv_station.companion.link_health import HealthMeter  # noqa: E402
from fpv_station.companion.link_settings import LinkSettings  # noqa: E402
from fpv_station.companion.recording.recorder import Recorder  # noqa: E402
from fpv_station.companion.recording.session import RecordingSession, SessionConfig  # noqa: E402
from fpv_station.companion.recording.writer import WriterLimits  # noqa: E402
from fpv_station.companion.state_tracker import StateTracker  # noqa: E402
from fpv_station.companion.vehicle_state import VehicleState  # noqa: E402
from fpv_station.core.mavlink.framing import MavFramer  # noqa: E402
from tests.mav_vehicle import MavVehicle  # noqa: E402


def station_mix() -> list[str]:
    """Two seconds of the station's requested streams, in the order they are due."""
    rates = {"HEARTBEAT": 1.0, **LinkSettings().message_rates_hz}
    due = sorted((k / rate, name) for name, rate in rates.items() for k in range(round(2 * rate)))
    return [name for _, name in due]


def build_packets() -> list[bytes]:
    vehicle = MavVehicle("udp")  # only builds packets: never started
    vehicle.arm()
    out = []
    for name in station_mix():
        vehicle.alt_m += 0.001  # a vehicle that climbs: no two positions alike
        out.append(vehicle.build(name).pack(vehicle.mav))
    return out


def per_packet_us(stage: Callable[[int], None], n: int, repeat: int = 3) -> float:
    """The best of `repeat` timed runs, as timeit reports: the others were interrupted."""
    stage(2000)  # warm up
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        stage(n)
        best = min(best, time.perf_counter() - t0)
    return best / n * 1e6


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--packets", type=int, default=20000)
    ap.add_argument("--profile", action="store_true", help="also print cProfile's top 20")
    ap.add_argument(
        "--udp-seconds", type=float, default=15.0, help="the real thread over UDP (0: not)"
    )
    args = ap.parse_args()
    packets = build_packets()
    count = len(packets)
    msgs = [m for p in packets for m in MavFramer().feed(p)]
    assert len(msgs) == count, "every packet decodes"

    with tempfile.TemporaryDirectory(prefix="link-packet-cost-") as tmp:
        state: Latest[VehicleState] = Latest()
        recorder = Recorder(Path(tmp), state, {})
        limits = WriterLimits(packet_queue=4 * args.packets + 2000)
        session = RecordingSession(Path(tmp), state, {}, SessionConfig(limits=limits))
        recorder.session = session  # recording, its threads not started
        try:
            figures = stages(packets, msgs, recorder, session, args)
        finally:
            recorder.session = None
            session.writer.close()
    total = sum(us for name, us in figures if name != "link, all together")
    print(
        f"per packet, warm loop (best of 3 x {args.packets} packets, Python {sys.version.split()[0]}, "
        f"load {os.getloadavg()[0]:.2f}):"
    )
    for name, us in figures:
        print(f"  {name:<32} {us:6.1f} us")
    print(f"  {'sum of the stages':<32} {total:6.1f} us")
    if args.udp_seconds > 0:
        udp_thread_cost(args.udp_seconds)


def stages(packets, msgs, recorder, session, args) -> list[tuple[str, float]]:
    count = len(packets)
    n = args.packets
    t_now = time.monotonic()
    t_wall = time.time()

    def drain() -> None:
        session.writer.write_now()  # what its thread would write, outside the timing

    def framing(k: int) -> None:
        framer = MavFramer()
        for i in range(k):
            framer.feed(packets[i % count])

    meter = HealthMeter("bench")

    def health(k: int) -> None:
        on_packet = meter.on_packet
        for i in range(k):
            m = msgs[i % count]
            on_packet(m.get_type(), m.get_srcSystem(), m.get_srcComponent(), m.get_seq())

    tracker = StateTracker()

    def state_merge(k: int) -> None:
        update = tracker.update
        for i in range(k):
            if update(msgs[i % count], t_now):
                tracker.state  # noqa: B018  the link takes the new state after each datagram

    def recorder_listener(k: int) -> None:
        on_packet = recorder.on_packet
        for i in range(k):
            on_packet(t_wall, packets[i % count])

    out = [
        ("framing + decode (MavFramer.feed)", per_packet_us(framing, n)),
        ("health meter (on_packet)", per_packet_us(health, n)),
        ("state merge (update + state)", per_packet_us(state_merge, n)),
    ]
    drain()
    out.append(("recorder listener (on_packet)", per_packet_us(recorder_listener, n)))
    drain()
    assert tracker.state.attitude.t_mono is not None, "the tracker follows the vehicle"

    link = MavlinkLink(LinkSettings(source="udpin:127.0.0.1:1"))  # never started
    link.add_packet_listener(recorder.on_packet)

    def whole(k: int) -> None:  # the link thread's per-datagram step and its publish
        for i in range(k):
            link._on_bytes(packets[i % count], time.monotonic())
            link._publish_state()

    out.append(("link, all together", per_packet_us(whole, n)))
    drain()
    if args.profile:
        for name, stage in (("state merge", state_merge), ("framing", framing), ("link", whole)):
            profiler = cProfile.Profile()
            profiler.runcall(stage, n)
            print(f"-- cProfile: {name}")
            pstats.Stats(profiler).sort_stats("tottime").print_stats(20)
    return out


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
            assert link._thread is not None and link._thread.native_id is not None
            tid = link._thread.native_id

            def cpu_s() -> float:
                return sum(thread_cpu_s(os.getpid())[tid])

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

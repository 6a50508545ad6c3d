"""Recording cost: both cameras at 30 fps + telemetry at 100 Hz, against the paper's PNGs.

    python benchmarks/recording.py [--seconds 60] [--width 640 --height 480] [--dir DIR]

Cameras and the vehicle are producer threads publishing into the station's own objects
(`Latest[Frame]`, `Latest[VehicleState]`, real pymavlink packets at ~100/s); the JPEGs
are pre-encoded (encoding is the camera's cost, not the recorder's). The recorder's CPU
is the CPU time of its own threads (the writer, and the event loop thread), read per
thread from /proc through psutil; handing each frame to the writer runs in the camera's
thread (a publish listener: a lock and a deque append), counted with the camera. The paper's approach is
timed on the same frames: decode each JPEG and write it as one PNG.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import shutil
import sys
import tempfile
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import psutil

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from fpv_station.companion.recording.recorder import Recorder, RecorderOptions  # noqa: E402
from fpv_station.companion.recording.session import SessionConfig  # noqa: E402
from fpv_station.companion.recording.writer import WriterLimits  # noqa: E402
from tests.recording_fakes import FakeCamera, FakeVehicle  # noqa: E402

FPS = 30.0


def scene_jpegs(n: int, width: int, height: int) -> list[bytes]:
    """Camera-like JPEGs: smooth gradients, shapes, text and sensor noise (not pure noise)."""
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[0:height, 0:width]
    out = []
    for i in range(n):
        img = np.zeros((height, width, 3), np.uint8)
        img[..., 0] = (xx * 255 // width + i * 3) % 256
        img[..., 1] = (yy * 255 // height) % 256
        img[..., 2] = 90
        cv2.rectangle(img, (50 + 5 * i, 200), (200 + 5 * i, 400), (20, 200, 40), -1)
        cv2.circle(img, (width // 2, height // 3), 60, (240, 240, 240), -1)
        cv2.putText(img, f"frame {i}", (30, 60), cv2.FONT_HERSHEY_SIMPLEX, 1.5, (255, 255, 0), 3)
        noise = rng.normal(0, 6, img.shape)
        img = np.clip(img + noise, 0, 255).astype(np.uint8)
        ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 80])
        out.append(buf.tobytes())
    return out


def thread_cpu_s(native_ids: dict[str, int]) -> dict[str, float]:
    by_id = {t.id: t.user_time + t.system_time for t in psutil.Process().threads()}
    return {name: by_id.get(tid, 0.0) for name, tid in native_ids.items()}


async def record(root: Path, seconds: float, jpegs: list[bytes]) -> dict:
    cams = {n: FakeCamera(n, FPS, jpegs) for n in ("front", "bottom")}
    vehicle = FakeVehicle(rate_hz=100.0)
    options = RecorderOptions(
        session=SessionConfig(
            rate_hz=100.0,
            source="bench",
            camera_fps=dict.fromkeys(cams, FPS),
            limits=WriterLimits(min_free_bytes=1),
        ),
        auto_record_on_arm=False,
    )
    rec = Recorder(root, vehicle.state, {n: c.frames for n, c in cams.items()}, options)
    vehicle.listeners.append(rec.on_packet)
    await rec.open()
    for c in cams.values():
        c.start()
    vehicle.start()
    await rec.start("bench")
    session = rec.session
    assert session is not None
    writer_tid = session.thread_ids()["writer"]
    assert writer_tid is not None
    ids = {
        "event loop": threading.get_native_id(),
        "writer thread": writer_tid,
    }
    cpu0, wall0 = thread_cpu_s(ids), time.monotonic()
    await asyncio.sleep(seconds)
    cpu_mid = thread_cpu_s(ids)  # before stop: the writer thread is gone after it
    await rec.stop("requested")
    wall = time.monotonic() - wall0
    per_thread = {name: cpu_mid[name] - cpu0[name] for name in ids}
    cpu = sum(per_thread.values())
    vehicle.stop()
    for c in cams.values():
        c.stop()
    assert rec.last_stop is not None
    sid = rec.last_stop.id
    meta = json.loads((root / sid / "session.json").read_text())
    size = sum(p.stat().st_size for p in (root / sid).rglob("*") if p.is_file())
    return {
        "meta": meta,
        "cpu_s": cpu,
        "per_thread": per_thread,
        "wall_s": wall,
        "bytes": size,
        "published": {n: max(c.published) for n, c in cams.items()},
        "packets_sent": vehicle.packets_sent,
    }


def paper_png_cpu_per_frame(root: Path, jpegs: list[bytes], frames: int) -> float:
    """The paper's storage: decode every frame and write it as a PNG file."""
    out = root / "png"
    out.mkdir()
    t0 = time.process_time()
    for i in range(frames):
        img = cv2.imdecode(np.frombuffer(jpegs[i % len(jpegs)], np.uint8), cv2.IMREAD_COLOR)
        assert img is not None
        cv2.imwrite(str(out / f"{i:08d}.png"), img)
    return (time.process_time() - t0) / frames


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=480)
    ap.add_argument("--png-frames", type=int, default=200)
    ap.add_argument("--dir", type=Path, default=None, help="where to write (default: a temp dir)")
    args = ap.parse_args()
    jpegs = scene_jpegs(30, args.width, args.height)
    load_before = psutil.getloadavg()
    root = Path(tempfile.mkdtemp(prefix="fpv-bench-", dir=args.dir))
    try:
        r = asyncio.run(record(root, args.seconds, jpegs))
        r["load_before"] = load_before
        png_cpu = paper_png_cpu_per_frame(root, jpegs, args.png_frames)
    finally:
        shutil.rmtree(root, ignore_errors=True)
    q = r["meta"]["quality"]
    written = sum(c["frames_written"] for c in q["cameras"].values())
    dropped = sum(c["frames_dropped"] for c in q["cameras"].values())
    ours = r["cpu_s"] / written
    print(f"load average before: {r['load_before']}, after: {psutil.getloadavg()}")
    print(
        f"recording: {args.seconds:.0f} s, 2 cameras x {FPS:.0f} fps {args.width}x{args.height} "
        f"JPEG (mean {np.mean([len(j) for j in jpegs]) / 1e3:.1f} kB), telemetry 100 Hz"
    )
    print(f"  frames written        {written}  (published {sum(r['published'].values())})")
    print(f"  frames dropped        {dropped}")
    print(
        f"  telemetry rows        {q['telemetry_rows']}  ({q['telemetry_achieved_hz']} Hz achieved,"
        f" {q['telemetry_rows_dropped']} dropped, {q['telemetry_ticks_late']} instants late)"
    )
    print(
        f"  tlog packets          {q['tlog_packets']} of {r['packets_sent']} "
        f"({q['tlog_packets_dropped']} dropped)"
    )
    for cam, c in q["cameras"].items():
        print(
            f"  {cam:6s} achieved fps {c['achieved_fps']}, skew max {c['skew_max_s'] * 1e3:.1f} ms,"
            f" p99 {c['skew_p99_s'] * 1e3:.1f} ms"
        )
    print(f"  disk                  {r['bytes'] / 1e6 / r['wall_s']:.2f} MB/s")
    print(
        f"  recorder CPU          {r['cpu_s']:.2f} s over {r['wall_s']:.1f} s "
        f"({100 * r['cpu_s'] / r['wall_s']:.1f}% of one core)"
    )
    for name, c in r["per_thread"].items():
        print(f"    {name:28s} {c:.2f} s")
    print(f"  CPU per recorded frame {ours * 1e3:.3f} ms (telemetry and tlog included)")
    print(f"paper (decode + PNG per frame): {png_cpu * 1e3:.2f} ms CPU per frame")
    print(f"ratio: ours is {png_cpu / ours:.1f}x cheaper per frame")


if __name__ == "__main__":
    main()

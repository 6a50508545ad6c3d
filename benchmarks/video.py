"""Benchmark: both cameras at 640x480, 30 fps, streamed as MJPEG to 1, 10 and 50 viewers each.

    python benchmarks/video.py [--viewers 1 10 50] [--seconds 6] [--mode encode|passthrough]

Runs `fpv-station serve` in a subprocess with both cameras on image folders (`encode`:
uncompressed BMP frames, JPEG-encoded once per frame as for the twin or a raw camera;
`passthrough`: JPEG frames at camera size, as from an MJPEG USB grabber), then opens N
viewers per camera over loopback in this process. Prints per scenario: delivered fps per
viewer (min / median), server-added latency from capture (X-Frame-Time) to the last byte
of the part received (p50 / p99), and the server process's CPU (% of one core).
"""

from __future__ import annotations

import argparse
import asyncio
import functools
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

import cv2
import httpx
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from tests.station_process import serve_station  # noqa: E402

WIDTH, HEIGHT, FPS = 640, 480, 30.0


def make_frames(folder: Path, suffix: str, count: int = 30) -> Path:
    """Camera-like pictures: smooth shading, shapes and sensor noise (JPEG ~50-70 kB)."""
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(1)
    yy, xx = np.mgrid[0:HEIGHT, 0:WIDTH]
    for i in range(count):
        base = np.stack([(xx / WIDTH * 200 + i * 3) % 255, (yy / HEIGHT * 180), 90 + 0 * xx], -1)
        image = base.astype(np.uint8)
        cv2.circle(image, (100 + 15 * i, 240), 60, (30, 200, 240), -1)
        cv2.rectangle(image, (400, 80 + 5 * i), (560, 300), (200, 60, 60), -1)
        cv2.putText(image, f"frame {i}", (40, 440), 0, 1.5, (255, 255, 255), 3)
        noisy = image.astype(np.int16) + rng.normal(0, 4, image.shape).astype(np.int16)
        image = np.clip(noisy, 0, 255).astype(np.uint8)
        params = [int(cv2.IMWRITE_JPEG_QUALITY), 80] if suffix == ".jpg" else []
        cv2.imwrite(str(folder / f"{i:03d}{suffix}"), image, params)
    return folder


class MjpegViewer(asyncio.BufferedProtocol):
    """A cheap viewer: de-chunks and walks the multipart stream without copying bodies."""

    def __init__(self, done: asyncio.Future) -> None:
        self.buf = bytearray(1 << 18)
        self.pending = b""  # unparsed header bytes (HTTP head, chunk sizes, part heads)
        self.http_head_done = False
        self.chunk_left = 0  # data bytes left in the current HTTP chunk
        self.crlf_left = 0  # bytes of the CRLF after a chunk still to skip
        self.body_left = 0  # JPEG bytes left in the current part
        self.part_head = b""
        self.seq = 0
        self.frame_time = 0.0
        self.parts: list[tuple[int, float, float]] = []  # (seq, frame_time, arrived)
        self.done = done

    def get_buffer(self, sizehint: int) -> memoryview:
        return memoryview(self.buf)

    def buffer_updated(self, nbytes: int) -> None:
        now = time.time()
        if not self.http_head_done:
            self.pending += bytes(self.buf[:nbytes])
            end = self.pending.find(b"\r\n\r\n")
            if end < 0:
                return
            self.http_head_done = True
            rest = self.pending[end + 4 :]
            self.pending = b""
            self._dechunk(rest, 0, len(rest), now)
            return
        self._dechunk(self.buf, 0, nbytes, now)

    def _dechunk(self, raw: bytes | bytearray, i: int, n: int, now: float) -> None:
        """HTTP/1.1 chunked framing: SIZE CRLF DATA CRLF ... 0 CRLF CRLF."""
        view = memoryview(raw)
        while i < n:
            if self.chunk_left:
                take = min(self.chunk_left, n - i)
                self._multipart(view[i : i + take], now)
                i += take
                self.chunk_left -= take
                if not self.chunk_left:
                    self.crlf_left = 2
            elif self.crlf_left:
                skip = min(self.crlf_left, n - i)
                i += skip
                self.crlf_left -= skip
            else:
                j = raw.find(b"\n", i, n)
                if j < 0:
                    self.pending += bytes(raw[i:n])
                    return
                line, self.pending = self.pending + bytes(raw[i:j]), b""
                i = j + 1
                self.chunk_left = int(line.strip().split(b";")[0], 16)
                if not self.chunk_left:
                    return  # last chunk: the stream ended

    def _multipart(self, data: memoryview, now: float) -> None:
        i, n = 0, len(data)
        while i < n:
            if self.body_left:
                take = min(self.body_left, n - i)
                self.body_left -= take
                i += take
                if self.body_left == 0:  # its JPEG and the CRLF after it are in
                    self.parts.append((self.seq, self.frame_time, now))
                continue
            self.part_head += bytes(data[i:n])
            end = self.part_head.find(b"\r\n\r\n", 1)
            if end < 0:
                return
            head, rest = self.part_head[:end], len(self.part_head) - end - 4
            self.part_head = b""
            fields = dict(line.split(b": ", 1) for line in head.split(b"\r\n") if b": " in line)
            self.seq = int(fields[b"X-Frame-Seq"])
            self.frame_time = float(fields[b"X-Frame-Time"])
            self.body_left = int(fields[b"Content-Length"]) + 2  # + CRLF after the JPEG
            i = n - rest

    def connection_lost(self, exc: Exception | None) -> None:
        if not self.done.done():
            self.done.set_result(None)


async def watch(port: int, cameras: list[str], per_camera: int, seconds: float, warmup: float):
    loop = asyncio.get_running_loop()
    viewers, transports = [], []
    for cam in cameras:
        for _ in range(per_camera):
            done = loop.create_future()
            transport, viewer = await loop.create_connection(
                functools.partial(MjpegViewer, done), "127.0.0.1", port
            )
            transport.write(f"GET /video/{cam}.mjpg HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n".encode())
            viewers.append(viewer)
            transports.append(transport)
    await asyncio.sleep(warmup)
    t0 = time.time()
    await asyncio.sleep(seconds)
    t1 = time.time()
    for t in transports:
        t.close()
    return viewers, t0, t1


def percentile(values: list[float], q: float) -> float:
    return float(np.percentile(values, q)) if values else float("nan")


def run(args: argparse.Namespace) -> None:
    tmp = Path(tempfile.mkdtemp(prefix="fpv-bench-video-"))
    # BMP decodes at memcpy cost, so `encode` measures the JPEG encode, as for a raw camera.
    suffix = ".bmp" if args.mode == "encode" else ".jpg"
    front, bottom = make_frames(tmp / "front", suffix), make_frames(tmp / "bottom", suffix)
    cmd = ["--source", "none", "--front", f"folder:{front}", "--bottom", f"folder:{bottom}"]
    with serve_station([*cmd, "--viser-port", "0"]) as station:
        base, port, proc = station.base, station.port, station.process
        print(
            f"# fpv-station video benchmark: 2 cameras {WIDTH}x{HEIGHT} @ {FPS:g} fps, "
            f"mode={args.mode}, {args.seconds:g} s per run, loopback"
        )
        print(
            f"# machine: {platform.machine()}, {os.cpu_count()} cores, "
            f"{_cpu_model()}, Python {platform.python_version()}"
        )
        time.sleep(1.0)
        proc.cpu_percent(None)
        time.sleep(args.seconds)
        idle_cpu = proc.cpu_percent(None)
        cams = {c["name"]: c for c in httpx.get(f"{base}/api/cameras").json()["cameras"]}
        jpeg_kb = (
            np.mean([len(httpx.get(f"{base}/video/front.jpg").content) for _ in range(5)]) / 1024
        )
        print(
            f"# no viewers: server CPU {idle_cpu:.1f}% of one core; capture fps "
            f"front {cams['front']['delivered_fps']:.1f}, bottom {cams['bottom']['delivered_fps']:.1f}; "
            f"encode {cams['front']['encode_ms']:.2f} ms/frame; JPEG {jpeg_kb:.0f} kB"
        )
        print(
            f"{'viewers/cam':>11} {'fps min':>8} {'fps med':>8} {'lat p50 ms':>10} "
            f"{'lat p99 ms':>10} {'server CPU %':>12} {'dropped':>8} {'encodes/frame':>13}"
        )
        for n in args.viewers:
            before = httpx.get(f"{base}/api/cameras").json()["cameras"]
            proc.cpu_percent(None)
            viewers, t0, t1 = asyncio.run(watch(port, ["front", "bottom"], n, args.seconds, 1.0))
            cpu = proc.cpu_percent(None)
            after = httpx.get(f"{base}/api/cameras").json()["cameras"]
            dropped = sum(a["frames_dropped"] - b["frames_dropped"] for a, b in zip(after, before))
            made = sum(a["frames"] - b["frames"] for a, b in zip(after, before))
            encodes = sum(a["encodes"] - b["encodes"] for a, b in zip(after, before))
            fps: list[float] = []
            lat: list[float] = []
            for v in viewers:
                window = [p for p in v.parts if t0 <= p[2] <= t1]
                fps.append(len(window) / (t1 - t0))
                lat.extend((arrived - ft) * 1000.0 for _, ft, arrived in window)
            print(
                f"{n:>11} {min(fps):>8.1f} {statistics.median(fps):>8.1f} "
                f"{percentile(lat, 50):>10.2f} {percentile(lat, 99):>10.2f} {cpu:>12.1f} {dropped:>8} "
                f"{encodes / max(made, 1):>13.2f}"
            )
            time.sleep(0.5)


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown CPU"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--viewers", type=int, nargs="+", default=[1, 10, 50])
    parser.add_argument("--seconds", type=float, default=6.0)
    parser.add_argument("--mode", choices=("encode", "passthrough"), default="passthrough")
    run(parser.parse_args())


if __name__ == "__main__":
    main()

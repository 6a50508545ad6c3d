"""A small asyncio MJPEG viewer for tests and benchmarks: raw HTTP/1.1 over a socket.

Reads a `multipart/x-mixed-replace` stream part by part and records, per part, its
X-Frame-Seq, X-Frame-Time and when its last byte arrived (time.time(), so that
capture-to-arrival latency is comparable on one machine).
"""

from __future__ import annotations

import asyncio
import time
from dataclasses import dataclass, field


@dataclass
class Part:
    seq: int
    frame_time: float  # X-Frame-Time, Unix seconds
    arrived: float  # time.time() when the last byte was read
    size: int
    signal: bool


@dataclass
class Viewer:
    host: str
    port: int
    path: str
    parts: list[Part] = field(default_factory=list)
    keep_bytes: bool = False
    last_jpeg: bytes = b""
    status: int = 0
    content_type: str = ""

    async def run(self, seconds: float) -> None:
        """Watch for `seconds`, then disconnect."""
        try:
            await asyncio.wait_for(self._watch(), seconds)
        except TimeoutError:
            pass

    async def _watch(self) -> None:
        reader, writer = await asyncio.open_connection(self.host, self.port)
        try:
            writer.write(f"GET {self.path} HTTP/1.1\r\nHost: {self.host}\r\n\r\n".encode())
            await writer.drain()
            head = await reader.readuntil(b"\r\n\r\n")
            lines = head.decode("latin-1").split("\r\n")
            self.status = int(lines[0].split()[1])
            headers = _headers(lines[1:])
            self.content_type = headers.get("content-type", "")
            if self.status != 200:
                return
            chunked = headers.get("transfer-encoding", "") == "chunked"
            stream = _Dechunk(reader) if chunked else _Plain(reader)
            while True:
                line = await stream.readline()
                if not line.startswith(b"--"):
                    continue  # the CRLF after the previous part
                part_head = b""
                while (line := await stream.readline()) not in (b"\r\n", b""):
                    part_head += line
                h = _headers(part_head.decode("latin-1").split("\r\n"))
                body = await stream.readexactly(int(h["content-length"]))
                self.parts.append(
                    Part(
                        int(h["x-frame-seq"]),
                        float(h["x-frame-time"]),
                        time.time(),
                        len(body),
                        h.get("x-frame-signal", "1") == "1",
                    )
                )
                if self.keep_bytes:
                    self.last_jpeg = body
        finally:
            writer.close()

    @property
    def seqs(self) -> list[int]:
        return [p.seq for p in self.parts]


def _headers(lines: list[str]) -> dict[str, str]:
    out = {}
    for line in lines:
        if ":" in line:
            k, v = line.split(":", 1)
            out[k.strip().lower()] = v.strip()
    return out


class _Plain:
    def __init__(self, reader: asyncio.StreamReader) -> None:
        self.r = reader

    async def readline(self) -> bytes:
        return await self.r.readline()

    async def readexactly(self, n: int) -> bytes:
        return await self.r.readexactly(n)


class _Dechunk:
    """HTTP/1.1 chunked transfer decoding on top of a StreamReader."""

    def __init__(self, reader: asyncio.StreamReader) -> None:
        self.r = reader
        self.buf = bytearray()

    async def _more(self) -> None:
        size_line = await self.r.readuntil(b"\r\n")
        size = int(size_line.split(b";")[0], 16)
        if size == 0:
            raise asyncio.IncompleteReadError(bytes(self.buf), None)
        self.buf += await self.r.readexactly(size)
        await self.r.readexactly(2)

    async def readline(self) -> bytes:
        while (i := self.buf.find(b"\n")) < 0:
            await self._more()
        line = bytes(self.buf[: i + 1])
        del self.buf[: i + 1]
        return line

    async def readexactly(self, n: int) -> bytes:
        while len(self.buf) < n:
            await self._more()
        data = bytes(self.buf[:n])
        del self.buf[:n]
        return data

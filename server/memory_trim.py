"""Hand the heap's free pages back to the system now and then (glibc's `malloc_trim`).

The station frees many short-lived buffers from several threads: camera JPEGs, WebSocket
messages, the 3D panels' scene messages. glibc keeps what they free in its arenas for
reuse, so the process's resident memory creeps up while the Python heap does not grow
(benchmarks/soak.py with 3D viewers; docs/PERFORMANCE.md). `malloc_trim(0)` releases the
free pages at the top of each arena and inside them. On another C library (musl, macOS)
there is nothing to call, and the loop is not started.
"""

from __future__ import annotations

import asyncio
import ctypes
import logging
from collections.abc import Callable

log = logging.getLogger(__name__)


def glibc_malloc_trim() -> Callable[[int], int] | None:
    """glibc's `malloc_trim(pad)`, or None where the process's C library has none."""
    try:
        libc = ctypes.CDLL(None)  # the C library this process already runs on
        trim = libc.malloc_trim
    except (OSError, AttributeError):
        return None
    trim.argtypes = [ctypes.c_size_t]
    trim.restype = ctypes.c_int
    return trim


class MemoryTrimmer:
    """Calls `malloc_trim(0)` every `period_s` seconds, in a worker thread (a trim walks
    every arena: milliseconds on a Pi, not for the event loop)."""

    def __init__(self, period_s: float, trim: Callable[[int], int]) -> None:
        self.period_s = period_s
        self.trim = trim
        self.trims = 0  # calls made, for /api/health and the tests

    async def run(self) -> None:
        while True:
            await asyncio.sleep(self.period_s)
            await asyncio.to_thread(self.trim, 0)
            self.trims += 1

"""A zip of files streamed to the client as it is written: no temp file, bounded memory.

`zipfile` writes into a small file-like object whose chunks a thread hands to the event
loop through a bounded asyncio queue (at most `max_chunks` x `chunk_size` bytes in
flight); the response's async generator awaits them. Reading files and deflating happen
in that thread, never on the event loop. JPEGs (and a session's frames.mjpeg, JPEGs back
to back) are stored as they are (already compressed); text and logs are deflated at level 1 (cheap on a Pi, ~5x on CSV).
If the client goes away, the thread notices at its next chunk and stops.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import logging
import threading
import zipfile
from collections.abc import AsyncIterator, Callable, Sequence
from pathlib import Path

log = logging.getLogger(__name__)

STORED_SUFFIXES = frozenset({".jpg", ".jpeg", ".mjpeg", ".png", ".zip", ".gz"})


class _Cancelled(Exception):
    pass


class _ChunkWriter:
    """The unseekable file `zipfile` writes to (it then adds data descriptors itself)."""

    def __init__(self, emit: Callable[[bytes], None], chunk_size: int) -> None:
        self._emit = emit
        self._chunk_size = chunk_size
        self._buf = bytearray()

    def write(self, data: bytes) -> int:
        self._buf += data
        if len(self._buf) >= self._chunk_size:
            self._emit(bytes(self._buf))
            self._buf.clear()
        return len(data)

    def flush(self) -> None:
        pass

    def close(self) -> None:
        pass  # part of a writable file's interface; the stream ends with `drain`

    def drain(self) -> None:
        if self._buf:
            self._emit(bytes(self._buf))
            self._buf.clear()


async def stream_zip(
    files: Sequence[tuple[str, Path]], chunk_size: int = 1 << 16, max_chunks: int = 8
) -> AsyncIterator[bytes]:
    """Yield the bytes of a zip archive holding `files` (archive name, path on disk)."""
    loop = asyncio.get_running_loop()
    queue: asyncio.Queue[bytes | None | BaseException] = asyncio.Queue(maxsize=max_chunks)
    cancelled = threading.Event()

    def put(item: bytes | None | BaseException) -> None:
        fut = asyncio.run_coroutine_threadsafe(queue.put(item), loop)
        while True:
            try:
                fut.result(timeout=0.5)
                return
            except concurrent.futures.TimeoutError:
                if cancelled.is_set():
                    fut.cancel()
                    raise _Cancelled from None

    def produce() -> None:
        try:
            out = _ChunkWriter(put, chunk_size)
            with zipfile.ZipFile(out, "w", allowZip64=True) as zf:
                for arcname, path in files:
                    _add_file(zf, arcname, path)
            out.drain()
            put(None)
        except _Cancelled:
            pass
        except Exception as exc:  # a file vanished or could not be read mid-archive
            log.warning("zip stream failed: %s", exc)
            if not cancelled.is_set():
                try:
                    put(exc)
                except (_Cancelled, RuntimeError):
                    pass

    thread = threading.Thread(target=produce, name="zip-stream", daemon=True)
    thread.start()
    try:
        while True:
            item = await queue.get()
            if item is None:
                return
            if isinstance(item, BaseException):
                raise item
            yield item
    finally:
        cancelled.set()


_COPY_BYTES = 1 << 20


def _add_file(zf: zipfile.ZipFile, arcname: str, path: Path) -> None:
    """`path` into `zf` as it was when its entry began: exactly the bytes it had then.

    A session still recording grows while it is zipped (its packs by about 1 MB a
    second). `ZipFile.write` copies to the end of the file but chose the entry's format
    from its size at the start, so a pack that grows past 2 GB during the download would
    fail the archive ("File size too large"); the appended bytes belong to the next download
    anyway (frames.csv, zipped before the pack, names none of them)."""
    info = zipfile.ZipInfo.from_file(path, arcname)
    if path.suffix.lower() in STORED_SUFFIXES:
        info.compress_type = zipfile.ZIP_STORED
    else:
        info.compress_type = zipfile.ZIP_DEFLATED
        # What ZipFile.write(compresslevel=1) sets; private before 3.13 (compress_level).
        info._compresslevel = 1  # type: ignore[attr-defined]
    with open(path, "rb") as src, zf.open(info, "w") as dest:
        left = info.file_size
        while left > 0 and (chunk := src.read(min(left, _COPY_BYTES))):
            dest.write(chunk)
            left -= len(chunk)

"""The streamed zip (server/zipstream.py) of a session that is still being recorded: its
files grow while they are zipped. Real files, the real zipfile; only zipfile's zip64
threshold is brought down (a 2 GB pack is not made in a test)."""

from __future__ import annotations

import asyncio
import io
import os
import zipfile

from fpv_station.server.zipstream import stream_zip


def test_a_file_that_grows_while_it_is_zipped_is_zipped_as_it_was(tmp_path, monkeypatch):
    """A live session's frame pack grows by about 1 MB a second during its download.
    ZipFile.write copied to the file's end but sized the entry at its start, so a pack
    that grew past the zip64 threshold (2 GB; 1 MB here) failed the whole archive."""
    monkeypatch.setattr(zipfile, "ZIP64_LIMIT", 1 << 20)
    pack = tmp_path / "frames.mjpeg"
    original = os.urandom(900_000)
    pack.write_bytes(original)
    rows = tmp_path / "telemetry.csv"
    rows.write_text("t_s\n" + "1.0\n" * 2000)
    files = [("s/front/frames.mjpeg", pack), ("s/telemetry.csv", rows)]

    def record_more() -> None:  # frames recorded meanwhile: past the threshold
        with open(pack, "ab") as f:
            f.write(os.urandom(600_000))

    async def download() -> bytes:
        chunks = stream_zip(files, chunk_size=1 << 16, max_chunks=2)
        first = await anext(chunks)  # the pack's entry has begun; its copy is held here
        record_more()
        return first + b"".join([c async for c in chunks])

    zf = zipfile.ZipFile(io.BytesIO(asyncio.run(download())))
    assert zf.testzip() is None
    assert zf.read("s/front/frames.mjpeg") == original  # as it was when its entry began
    assert zf.getinfo("s/front/frames.mjpeg").compress_type == zipfile.ZIP_STORED
    info = zf.getinfo("s/telemetry.csv")
    assert info.compress_type == zipfile.ZIP_DEFLATED and info.compress_size < info.file_size
    assert zf.read("s/telemetry.csv") == rows.read_bytes()

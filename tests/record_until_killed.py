"""A recording process for the kill -9 test: records fake cameras and vehicle until killed.

    python -m tests.record_until_killed SESSIONS_DIR
Prints "RECORDING <session id>" once the session runs.
"""

from __future__ import annotations

import asyncio
import sys
from pathlib import Path

from companion.recording.recorder import Recorder, RecorderOptions
from companion.recording.session import SessionConfig
from companion.recording.writer import WriterLimits
from tests.recording_fakes import FakeCamera, FakeVehicle, make_jpegs


async def main(root: Path) -> None:
    jpegs = make_jpegs()
    cams = {n: FakeCamera(n, 30.0, jpegs).start() for n in ("front", "bottom")}
    vehicle = FakeVehicle().start()
    options = RecorderOptions(
        session=SessionConfig(rate_hz=30.0, source="sim", limits=WriterLimits(min_free_bytes=1)),
        auto_record_on_arm=False,
    )
    rec = Recorder(root, vehicle.state, {n: c.frames for n, c in cams.items()}, options)
    vehicle.listeners.append(rec.on_packet)
    marked = await rec.open()
    print("MARKED " + " ".join(marked), flush=True)
    status = await rec.start("test")
    print(f"RECORDING {status.id}", flush=True)
    await asyncio.Event().wait()  # until killed


if __name__ == "__main__":
    asyncio.run(main(Path(sys.argv[1])))

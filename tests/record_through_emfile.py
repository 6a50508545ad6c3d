"""A recording process that runs out of file descriptors mid-flight and gets them back.

    python -m tests.record_through_emfile SESSIONS_DIR
Lowers RLIMIT_NOFILE, arms a fake vehicle (auto-record), then opens files until EMFILE
and keeps every descriptor taken for a while, frees them, then disarms. The writer holds
its files open from the start (a frame pack per camera, session format 2), so the
session records on: frames keep reaching the disk while no descriptor is left. Lines:
"FIRST id", "STARVED frames=N failure=... session=id" (frames written while starved),
"STOPPED reason" (the session ends with the flight, as it began).
"""

from __future__ import annotations

import asyncio
import os
import resource
import sys
from pathlib import Path

from tests.recording_fakes import FakeRig, recorder_options, starve, until


async def main(root: Path) -> None:
    _, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    resource.setrlimit(resource.RLIMIT_NOFILE, (256, hard))
    rig = FakeRig(root, recorder_options(auto_record_on_arm=True, post_disarm_tail_s=0.2))
    rec, vehicle = rig.start().recorder, rig.vehicle
    await rec.open()
    vehicle.armed = True
    assert await until(lambda: rec.session is not None, 30), "no session on arming"
    assert rec.session is not None
    first = rec.session.id
    print(f"FIRST {first}", flush=True)
    await asyncio.sleep(0.5)
    hog: list[int] = []

    def written() -> int:
        return sum(rec.session.writer.stats.frames_written.values()) if rec.session else 0

    starve(hog)
    before = written()

    def starved_long_enough() -> bool:
        starve(hog)  # take every descriptor freed since
        return written() >= before + 30 or rec.failure is not None

    await until(starved_long_enough, 30)
    sid = rec.session.id if rec.session else None
    print(f"STARVED frames={written() - before} failure={rec.failure} session={sid}", flush=True)
    for fd in hog:
        os.close(fd)
    vehicle.armed = False
    if await until(lambda: rec.session is None, 10):
        print(f"STOPPED {rec.last_stop.reason if rec.last_stop else None}", flush=True)
    await rec.aclose()
    rig.stop()
    print("DONE", flush=True)


if __name__ == "__main__":
    asyncio.run(main(Path(sys.argv[1])))

"""A recording process that runs out of file descriptors mid-flight and gets them back.

    python -m tests.record_through_emfile SESSIONS_DIR
Lowers RLIMIT_NOFILE, arms a fake vehicle (auto-record), then opens files until EMFILE so
the writer's next JPEG fails for real, prints the recorder's failure, frees the files, and
prints the session it resumed into, then disarms. Lines: "FIRST id", "PROBLEM text",
"RESUMED id", "STATUS failure=...", "STOPPED reason" (the resumed session ends with the
flight, as the one armed did).
"""

from __future__ import annotations

import asyncio
import os
import resource
import sys
from pathlib import Path

from tests.recording_fakes import FakeRig, recorder_options


async def until(predicate, within_s: float) -> bool:
    """Poll `predicate` on the loop (the recorder's state has no event to wait on)."""
    for _ in range(int(within_s / 0.05)):
        if predicate():
            return True
        await asyncio.sleep(0.05)
    return bool(predicate())


async def main(root: Path) -> None:
    _, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    resource.setrlimit(resource.RLIMIT_NOFILE, (256, hard))
    rig = FakeRig(root, recorder_options(auto_record_on_arm=True, post_disarm_tail_s=0.2))
    rec, vehicle = rig.start().recorder, rig.vehicle
    await rec.open()
    vehicle.armed = True
    assert await until(lambda: rec.session is not None, 30), "no session on arming"
    first = rec.session.id
    print(f"FIRST {first}", flush=True)
    await asyncio.sleep(0.5)
    hog: list[int] = []

    def starved() -> bool:
        # Take every free descriptor, again on each poll: one the writer closes after a
        # JPEG would otherwise be its next one, and it would never fail.
        try:
            while True:
                hog.append(os.open(os.devnull, os.O_RDONLY))
        except OSError:
            pass
        return rec.failure is not None

    got_problem = await until(starved, 30)
    print(f"PROBLEM {rec.failure}", flush=True)
    await asyncio.sleep(1.0)  # a few retries fail while the descriptors are gone
    for fd in hog:
        os.close(fd)
    if got_problem and await until(lambda: rec.session is not None, 30):
        print(f"RESUMED {rec.session.id}", flush=True)
        await asyncio.sleep(1.0)
        print(f"STATUS failure={rec.failure}", flush=True)
        vehicle.armed = False
        if await until(lambda: rec.session is None, 10):
            print(f"STOPPED {rec.last_stop.reason}", flush=True)
    await rec.aclose()
    rig.stop()
    print("DONE", flush=True)


if __name__ == "__main__":
    asyncio.run(main(Path(sys.argv[1])))

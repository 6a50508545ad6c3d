"""A recording process whose files may not grow past a size (RLIMIT_FSIZE): the write
that would cross it fails with EFBIG, as a write on a full disk fails with ENOSPC, and
needs no root (a small tmpfs does).

    python -m tests.record_under_file_limit SESSIONS_DIR LIMIT_BYTES
Prints "STOPPED <session id>" once the failed write has stopped the session.

    python -m tests.record_under_file_limit SESSIONS_DIR LIMIT_BYTES FLYING_S
A vehicle armed for FLYING_S seconds (auto-record, so the recorder retries after each
failed write); prints "SESSIONS <n>", the session folders it made.
"""

from __future__ import annotations

import asyncio
import resource
import signal
import sys
from pathlib import Path

from tests.recording_fakes import FakeRig, record_until_stopped, recorder_options


def fly(root: Path, flying_s: float) -> int:
    rig = FakeRig(root, recorder_options(0, auto_record_on_arm=True))
    rig.vehicle.armed = True
    rec = rig.start().recorder

    async def run() -> None:
        await rec.open()
        await asyncio.sleep(flying_s)
        await rec.aclose()

    try:
        asyncio.run(run())
    finally:
        rig.stop()
    return sum(1 for p in root.iterdir() if p.is_dir())


def main(root: Path, limit: int, flying_s: float | None) -> None:
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a failed write, not a killed process
    resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
    if flying_s is not None:
        print(f"SESSIONS {fly(root, flying_s)}", flush=True)
        return
    st = record_until_stopped(root, min_free_bytes=0)
    assert st.last_stop is not None and not st.recording, st
    print(f"STOPPED {st.last_stop.id}", flush=True)


if __name__ == "__main__":
    main(Path(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3]) if len(sys.argv) > 3 else None)

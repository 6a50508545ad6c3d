"""A recording process for the kill -9 test: records fake cameras and vehicle until killed.

    python -m tests.record_until_killed SESSIONS_DIR
Prints "RECORDING <session id>" once the session runs.
"""

from __future__ import annotations

import asyncio
import sys
from pathlib import Path

from tests.recording_fakes import FakeRig, recorder_options


async def main(root: Path) -> None:
    rec = FakeRig(root, recorder_options(), ("front", "bottom")).start().recorder
    marked = await rec.open()
    print("MARKED " + " ".join(marked), flush=True)
    status = await rec.start("test")
    print(f"RECORDING {status.id}", flush=True)
    await asyncio.Event().wait()  # until killed


if __name__ == "__main__":
    asyncio.run(main(Path(sys.argv[1])))

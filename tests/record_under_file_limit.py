"""A recording process whose files may not grow past a size (RLIMIT_FSIZE): the write
that would cross it fails with EFBIG, as a write on a full disk fails with ENOSPC, and
needs no root (a small tmpfs does).

    python -m tests.record_under_file_limit SESSIONS_DIR LIMIT_BYTES
Prints "STOPPED <session id>" once the failed write has stopped the session.
"""

from __future__ import annotations

import resource
import signal
import sys
from pathlib import Path

from tests.test_recording_tmpfs import record_until_stopped


def main(root: Path, limit: int) -> None:
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a failed write, not a killed process
    resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
    st = record_until_stopped(root, min_free_bytes=0)
    assert st.last_stop is not None and not st.recording, st
    print(f"STOPPED {st.last_stop.id}", flush=True)


if __name__ == "__main__":
    main(Path(sys.argv[1]), int(sys.argv[2]))

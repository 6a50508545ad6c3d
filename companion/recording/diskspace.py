"""Free disk space, probed at the OS boundary (tests patch `shutil.disk_usage`)."""

from __future__ import annotations

import shutil
from pathlib import Path


def free_bytes(path: Path) -> int:
    """Bytes available to this process on the filesystem holding `path`."""
    return shutil.disk_usage(path).free

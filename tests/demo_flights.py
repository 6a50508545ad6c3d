"""Twin demonstrations (`learn.demos.fly_demo`) flown once per test run and shared.

A demo flight costs seconds of CPU (minutes with cameras on a loaded machine), and
several modules fly the same one (test_one_reader's and test_learn_eval's task-2 demo),
in whichever xdist worker gets each module. `shared_demo` flies a (seed, config) once
for the whole run: under xdist into the run's base folder that every worker sees, with a
file lock so that one worker flies while the others wait, else into this process's base
folder. The folder
it returns is shared: read it, or copy it before changing it.
"""

from __future__ import annotations

import fcntl
import hashlib
import os
import shutil
from pathlib import Path

import pytest

from fpv_station.learn.demos import DemoConfig, fly_demo

_DONE = "flown"  # written after the session folder is complete


def shared_demo(
    tmp_path_factory: pytest.TempPathFactory, seed: int, config: DemoConfig | None = None
) -> Path:
    """The session folder of demo `seed` flown with `config` (default: `DemoConfig()`),
    flown by the first caller."""
    config = config or DemoConfig()
    base = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):  # base is the run's folder/popen-gwN
        base = base.parent
    key = hashlib.sha256(repr((seed, config)).encode()).hexdigest()[:16]
    root = base / "shared-demos" / key
    root.parent.mkdir(parents=True, exist_ok=True)
    with open(root.with_suffix(".lock"), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
        done = root / _DONE
        if not done.exists():
            shutil.rmtree(root, ignore_errors=True)  # what a failed flight left
            folder = fly_demo(root, seed, config)
            done.write_text(folder.name)
        return root / done.read_text()

"""What the station loads on a Pi: no `learn` extra needed, no idle feature imported.

A Pi installs fpv-station without the `learn` extra; the command line must still build
and serve. Features nobody uses yet (analysis plots: matplotlib) must not be imported at
start: each costs memory and start-up time on the smallest Pis (docs/PERFORMANCE.md,
benchmarks/pi_budget.py). Checked in a fresh interpreter, as `fpv-station serve` starts.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# The `learn` extra's top-level modules (pyproject.toml): absent on a Pi.
LEARN_EXTRA = ("gymnasium", "pyarrow", "av", "minari", "foxglove", "mcap", "tqdm", "sklearn")
# Loaded by their first use: analysis plots (matplotlib), the 3D panels (viser: their
# first visit, GET /api/viser).
IDLE_FEATURES = ("matplotlib", "viser")
# Never needed: pymavlink's mavutil imports its MAVLink 1 `all` dialect too (9 MB), and the
# station takes only mode tables from it (core.mavlink.px4_modes, ardupilot_modes). And one
# MAVLink 2 dialect serves the whole station, the link's `ardupilotmega` (a superset of
# `common`, which beside it cost 5.4 MB and 22-60 ms of start-up).
NEVER_LOADED = ("pymavlink.mavutil", "pymavlink.dialects.v10", "pymavlink.dialects.v20.common")

CHILD = """
import json, sys
from pathlib import Path
for name in sys.argv[2].split(","):
    sys.modules[name] = None  # importing it now fails, as when it is not installed
import httpx
from fpv_station.server.app import create_app
from fpv_station.server.cli import build_parser
from tests.helpers import run_uvicorn, station_settings

build_parser()  # every subcommand's flags, as `fpv-station serve` builds them first
settings = station_settings(
    "none", Path(sys.argv[1]), **{"viser.enabled": True, "viser.port": 0}
)
with run_uvicorn(create_app(settings)) as base:
    health = httpx.get(base + "/api/health", timeout=10).json()
    sessions = httpx.get(base + "/api/sessions", timeout=10).status_code
    modules = sorted(sys.modules)
    panel = httpx.get(base + "/api/viser", timeout=30).json()  # the first visit
    client = httpx.get(f"http://127.0.0.1:{panel['port']}/", timeout=10).status_code
    replay = httpx.get(f"http://127.0.0.1:{panel['replay_port']}/", timeout=10).status_code
import fpv_station.twin.runner, fpv_station.twin.vehicle  # what `make run` adds: the embedded twin
# Loaded after start: the 3D panels' first visit and the twin.
later = sorted(set(sys.modules) - set(modules))
print(json.dumps({"ok": health["ok"], "sessions": sessions, "modules": modules,
                  "later": later, "panel": panel, "viser_pages": [client, replay]}))
"""


def test_serves_without_the_learn_extra_and_without_idle_features(tmp_path: Path) -> None:
    env = {**os.environ, "PYTHONPATH": str(ROOT), "XDG_CONFIG_HOME": str(tmp_path / "cfg")}
    done = subprocess.run(
        [sys.executable, "-c", CHILD, str(tmp_path / "sessions"), ",".join(LEARN_EXTRA)],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=90,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    reply = json.loads(done.stdout.strip().splitlines()[-1])
    assert reply["ok"] and reply["sessions"] == 200
    loaded = {m.split(".")[0] for m in reply["modules"]}
    assert not loaded & set(IDLE_FEATURES), "an idle feature was imported at start"
    assert not [m for m in reply["modules"] if m.startswith(NEVER_LOADED)]
    assert not [m for m in reply["later"] if m.startswith(NEVER_LOADED)]
    # The first visit starts the 3D panels: both viser servers serve their client.
    assert reply["panel"]["enabled"] and reply["viser_pages"] == [200, 200]

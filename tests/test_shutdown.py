"""SIGTERM under load: a real `fpv-station serve` on the twin, with its
3D panels, recording, telemetry clients and MJPEG viewers reading, clients that stopped
reading, and WebSocket clients that closed while backed up, ends with no traceback and the
session complete. How long it takes is a figure
of benchmarks/shutdown.py (docs/PERFORMANCE.md), not asserted here."""

from __future__ import annotations

import signal

from tests.shutdown_load import sigterm_under_load


def test_sigterm_under_load_ends_cleanly_and_completes_the_session(tmp_path):
    run = sigterm_under_load(tmp_path, telemetry=20, viewers=10, stalled=4, closing=2, guard_s=60.0)
    assert run.telemetry_msgs > 0 and run.video_parts > 0  # the load was real
    assert run.returncode in (0, -signal.SIGTERM), (run.returncode, run.output[-3000:])
    assert "Traceback" not in run.output, run.output
    # Nothing was left for uvicorn to cancel, and no background task died on the way out.
    assert "graceful shutdown exceeded" not in run.output, run.output
    assert "died" not in run.output, run.output
    assert run.session["status"] == "complete" and run.session["stop_reason"] == "shutdown"
    assert run.session["quality"]["telemetry_rows"] > 0

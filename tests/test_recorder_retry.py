"""The recorder keeps recording through a real EMFILE (issue 13 item 1): a process under a
lowered RLIMIT_NOFILE loses its descriptors mid-flight, the session is cut short with the
reason, the recorder reports the problem, and once descriptors are back it records again
into a new session, which ends when the vehicle disarms like the one arming started."""

from __future__ import annotations

import json

from tests.test_recording_kill import read_line, spawn


def test_recording_resumes_after_descriptors_run_out(tmp_path):
    proc = spawn(["-m", "tests.record_through_emfile", str(tmp_path)])
    try:
        first = read_line(proc, "FIRST ", timeout=60)
        problem = read_line(proc, "PROBLEM ", timeout=60)
        assert "Too many open files" in problem, problem
        resumed = read_line(proc, "RESUMED ", timeout=60)
        assert resumed != first
        assert read_line(proc, "STATUS ", timeout=60) == "failure=None"
        assert read_line(proc, "STOPPED ", timeout=60) == "disarmed"
        read_line(proc, "DONE", timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    # The cut session is kept with what it wrote before the descriptors ran out.
    assert (tmp_path / first / "telemetry.csv").stat().st_size > 0
    again = json.loads((tmp_path / resumed / "session.json").read_text())
    assert again["trigger"] == "retry" and again["status"] == "complete"
    assert again["stop_reason"] == "disarmed"
    assert (tmp_path / resumed / "telemetry.csv").stat().st_size > 0

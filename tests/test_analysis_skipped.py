"""`fpv-station analyze` on several sessions: one in which the task cannot be measured (it
never flew) is listed under `skipped` with its reason, and the others are analysed; only
when it is the only session asked for does the command fail."""

from __future__ import annotations

import json

import numpy as np

from fpv_station.server.cli import main as cli_main
from tests import synthetic as syn


def ground_run() -> syn.Flight:
    """Armed for 20 s on the pad, never off the ground (a motor test)."""
    t = np.arange(0.0, 30.0, 0.05)
    return syn.Flight(t_s=t, xyz_m=np.zeros((t.size, 3)), armed=(t >= 5.0) & (t < 25.0))


def test_a_session_that_never_flew_is_skipped_and_the_rest_analysed(tmp_path, capsys):
    flown = syn.write_session(syn.hover_flight(radius_m=0.3), tmp_path / "flown")
    grounded = syn.write_session(ground_run(), tmp_path / "grounded")
    out = tmp_path / "out"
    argv = ["analyze", str(grounded), str(flown), "--task", "hover", "--no-scene"]
    assert cli_main([*argv, "--out", str(out)]) == 0
    printed = capsys.readouterr()
    assert "| flown |" in printed.out and "grounded" not in printed.out
    assert "skipped grounded: " in printed.err
    table = json.loads((out / "hover_table.json").read_text())
    assert [r["label"] for r in table["results"]] == ["flown"]
    (skipped,) = table["skipped"]
    assert skipped["label"] == "grounded" and "never" in skipped["reason"]

    # Alone, it is an error with the same reason.
    assert cli_main(["analyze", str(grounded), "--task", "hover", "--no-scene"]) == 2
    assert skipped["reason"] in capsys.readouterr().err

"""Physical flights are judged on the field too, within the GPS's error: an ArduCopter's
tlog (shaped by the tests, no twin) of an A to B flown at 2 m through the default
field's two 3 m obstacles, and of one that lands beyond the landing pad. Where the log
records the receiver's accuracy (GPS_RAW_INT `h_acc`) that is the margin; without it,
the assumed `TaskParams.gps_accuracy_m`. A fault counts only when it holds anywhere
within the margin; one the error could undo is named as uncertain."""

from __future__ import annotations

import dataclasses

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from fpv_station.analysis.report import analyze_paths
from fpv_station.analysis.tasks import TaskParams, TaskResult
from fpv_station.core.geodesy import enu_to_geodetic
from tests import shaped_tlog
from tests import synthetic as syn

START = tuple(enu_to_geodetic([-20.0, 0.0, 0.0], *syn.FIELD_HOME))  # field.toml's start pad


def a_to_b(tmp_path, name: str, h_acc_m: float | None, **flight) -> TaskResult:
    """The default field's analysis of an A to B from the start pad, from its bare tlog."""
    f = dataclasses.replace(syn.a_to_b_flight(lateral_amp_m=0.0, **flight), home=START)
    log = shaped_tlog.vehicle_flight(f, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, h_acc_m=h_acc_m)
    (result,) = analyze_paths([log.write(tmp_path / f"{name}.tlog")], "a-to-b").results
    assert result.platform == "physical" and result.landing_pad == "landing"
    return result


def test_a_pass_through_an_obstacle(tmp_path):
    sharp = a_to_b(tmp_path, "sharp", h_acc_m=0.3, height_m=2.0)
    assert sharp.gps_margin_m == pytest.approx(0.3)
    assert sharp.obstacle_contacts == 2 and not sharp.valid
    assert sharp.invalid_reasons == ("it touched an obstacle (2 contacts)",)
    # The same flight from a receiver that does not say its accuracy: 2.5 m is wider than
    # a 1 m obstacle, so each pass may have missed it: uncertain, not a fault.
    vague = a_to_b(tmp_path, "vague", h_acc_m=None, height_m=2.0)
    assert vague.gps_margin_m == TaskParams().gps_accuracy_m
    assert vague.obstacle_contacts == 0 and vague.valid
    assert "may have touched an obstacle (2 passes" in vague.uncertain[0]
    # Above the obstacles: nothing to judge.
    high = a_to_b(tmp_path, "high", h_acc_m=0.3, height_m=4.0)
    assert high.obstacle_contacts == 0 and high.valid and high.uncertain == ()


def test_a_landing_off_the_pad(tmp_path):
    far = a_to_b(tmp_path, "far", h_acc_m=None, height_m=4.0, length_m=44.0)
    assert far.landing_accuracy_m == pytest.approx(4.0, abs=0.2)
    assert not far.valid  # 4 m off a 1.5 m pad: off wherever within 2.5 m it was
    (reason,) = far.invalid_reasons
    assert "landed off pad 'landing', 4.0 m from its centre" in reason
    # 1.8 m off: the pad's edge (with the vehicle's reach) is 1.05 m from its centre, so
    # 0.75 m off the pad, less than the assumed 2.5 m: not known.
    near = a_to_b(tmp_path, "near", h_acc_m=None, height_m=4.0, length_m=41.8)
    assert near.valid and near.invalid_reasons == ()
    assert any("from pad 'landing''s centre, off the pad" in u for u in near.uncertain)
    # A receiver that says 0.3 m: 0.75 m off is off.
    sharp = a_to_b(tmp_path, "near_sharp", h_acc_m=0.3, height_m=4.0, length_m=41.8)
    assert not sharp.valid and "landed off pad 'landing'" in sharp.invalid_reasons[0]
    assert sharp.uncertain == ()

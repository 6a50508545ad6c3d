"""The twin's flight model and PX4-like control, run faster than real time."""

from __future__ import annotations

import numpy as np
import pytest

from fpv_station.twin.dynamics import Wind
from fpv_station.twin.pilot import Leg, Pilot, fly, task_plan
from fpv_station.twin.sensors import SensorParams
from fpv_station.twin.sim import Sim, SimConfig

QUIET = SimConfig(sensors=SensorParams(enabled=False))


def hover_sim(alt_m: float = 4.0, config: SimConfig = QUIET) -> Sim:
    sim = Sim(config=config)
    sim.run_for(2.5)  # GPS fix
    assert sim.arm() == (True, "")
    pilot = Pilot([Leg("climb", alt_m=alt_m)])
    fly(sim, pilot, timeout_s=30)
    assert pilot.done
    sim.set_sticks(0, 0, 0, 0.5)
    sim.run_for(4.0)
    return sim


def test_hover_thrust_equals_weight() -> None:
    sim = hover_sim()
    af = sim.config.airframe
    thrust = float(sim.state.rotor_thrust_n[0].sum() * sim.state.R_world_body[0, 2, 2])
    assert thrust == pytest.approx(af.weight_n, rel=0.01)
    assert abs(sim.state.vel_mps[0, 2]) < 0.02
    assert sim.state.pos_m[0, 2] == pytest.approx(4.0, abs=0.1)


def test_stick_step_gives_commanded_velocity_and_settles() -> None:
    sim = hover_sim()
    max_v = sim.config.gains.max_vel_xy_mps
    sim.set_sticks(0.0, 0.5, 0.0, 0.5)  # half forward: (0.5 - 0.1) / 0.9 of full scale
    sim.run_for(6.0)
    expected = max_v * (0.5 - 0.1) / 0.9
    v = sim.state.vel_mps[0]
    assert v[0] == pytest.approx(expected, rel=0.05)  # heading east: forward = +x
    assert abs(v[1]) < 0.05 and abs(v[2]) < 0.1
    sim.set_sticks(0.0, 0.0, 0.0, 0.5)
    sim.run_for(2.0)
    x_release = sim.state.pos_m[0, 0]
    sim.run_for(4.0)
    assert np.linalg.norm(sim.state.vel_mps[0]) < 0.05  # braked and holding
    assert abs(sim.state.pos_m[0, 0] - x_release) < 0.5


def test_climb_stick_gives_climb_rate() -> None:
    sim = hover_sim(2.0)
    sim.set_sticks(0.0, 0.0, 0.0, 1.0)
    sim.run_for(2.0)
    assert sim.state.vel_mps[0, 2] == pytest.approx(sim.config.gains.max_climb_mps, rel=0.05)


def test_hover_battery_lasts_about_eleven_minutes() -> None:
    # The hover power comes from the flying twin (controller, thrust, current); the pack is
    # then drained at that load by the same battery model, 50 steps/s, down to the 10 %
    # failsafe. A full 11-minute 250 Hz flight would take a minute of CPU in a unit test.
    sim = hover_sim()
    s, dyn = sim.state, sim.dynamics
    assert 15.0 < s.current_a[0] < 40.0
    t, dt = 0.0, 0.02
    while sim.battery_pct() > sim.config.commander.battery_land_pct:
        dyn._battery(s, s.rotor_thrust_n, dt)
        t += dt
        assert t < 20 * 60
    assert 10.0 * 60 < t < 12.0 * 60
    assert s.voltage_v[0] < 3 * 3.65  # sagged under load


def test_battery_failsafe_lands_the_vehicle() -> None:
    sim = hover_sim()
    sim.state.charge_c[:] = 0.095 * sim.config.airframe.capacity_ah * 3600  # 9.5 % left
    sim.run_for(1.0)
    assert sim.commander.mode_name() == "LAND"
    sim.run_for(12.0)
    assert sim.state.on_ground[0] and not sim.commander.armed[0]
    assert any("battery" in e.text for e in sim.drain_events())


def test_same_seed_same_flight_other_seed_differs() -> None:
    windy = SimConfig(seed=7, wind=Wind((1.0, 0.5, 0.0), gust_std_mps=1.0))

    def flight(config: SimConfig) -> np.ndarray:
        sim = Sim(config=config)
        sim.run_for(2.5)
        return fly(
            sim,
            Pilot([Leg("arm"), Leg("climb", alt_m=3.0), Leg("goto", (-15.0, 2.0), 3.0)]),
            timeout_s=40,
        )

    a, b = flight(windy), flight(windy)
    np.testing.assert_array_equal(a, b)
    c = flight(SimConfig(seed=8, wind=windy.wind))
    assert a.shape != c.shape or not np.array_equal(a, c)


def test_position_mode_holds_within_30cm_for_10s() -> None:
    sim = hover_sim(config=SimConfig())  # default sensor noise and GPS drift, no wind
    track = []
    for _ in range(500):  # 10 s at 50 Hz
        sim.step(5)
        track.append(sim.state.pos_m[0].copy())
    path = np.array(track)
    horizontal = np.linalg.norm(path[:, :2] - path[0, :2], axis=1)
    assert horizontal.max() < 0.3
    assert np.ptp(path[:, 2]) < 0.3


def test_crash_into_obstacle_is_detected() -> None:
    sim = hover_sim(2.0)  # below the 3 m obstacles
    sim.set_sticks(0.0, 0.6, 0.0, 0.5)  # forward (east) towards obstacle 1 at x = -7
    sim.run_for(15.0)
    assert sim.crash_reason() == "obstacle"
    assert not sim.commander.armed[0]
    assert sim.state.pos_m[0, 0] < -7.0 + 0.5
    assert any("CRASH: obstacle" in e.text for e in sim.drain_events())
    assert sim.arm() == (False, "arming refused: the vehicle has crashed (reset the twin)")


def test_hard_ground_impact_is_a_crash() -> None:
    sim = hover_sim(10.0)
    assert sim.set_mode("STABILIZED")[0]
    sim.set_sticks(0.0, 0.0, 0.0, 0.0)  # throttle cut at 10 m
    sim.run_for(5.0)
    assert sim.crash_reason() == "ground impact"


def test_gesture_arms_and_preflight_auto_disarm() -> None:
    sim = Sim(config=QUIET)
    sim.run_for(2.5)
    sim.set_sticks(0.0, 0.0, 1.0, 0.0)
    sim.run_for(1.2)
    assert sim.commander.armed[0]
    sim.set_sticks(0.0, 0.0, 0.0, 0.0)
    sim.run_for(11.0)  # no take-off within 10 s
    assert not sim.commander.armed[0]


def test_position_mode_refuses_arming_without_gps_fix() -> None:
    sim = Sim(config=QUIET)
    ok, why = sim.arm()
    assert not ok and "GPS" in why


def test_task_two_lands_on_the_landing_pad() -> None:
    sim = Sim(config=QUIET)
    sim.run_for(2.5)
    pilot = Pilot(task_plan(sim.scene, 2))
    track = fly(sim, pilot, timeout_s=200)
    assert pilot.done and sim.crash_reason() == ""
    assert np.hypot(*(track[-1, 1:3] - sim.scene.pad("landing").xy_m)) < 0.4
    assert track[:, 3].max() > 3.0


def test_position_mode_holds_against_steady_wind_with_gusts() -> None:
    windy = SimConfig(
        sensors=SensorParams(enabled=False), seed=3, wind=Wind((3.0, -2.0, 0.0), gust_std_mps=0.8)
    )
    sim = hover_sim(config=windy)
    start = sim.state.pos_m[0].copy()
    worst = 0.0
    for _ in range(250):  # 5 s
        sim.step(5)
        worst = max(worst, float(np.linalg.norm(sim.state.pos_m[0, :2] - start[:2])))
    assert worst < 1.0  # the integrator leans into the wind; gusts push it around a little
    roll, pitch, _ = sim.pose().euler_ned_rad
    assert abs(roll) + abs(pitch) > np.radians(1.0)  # tilted into the wind to hold


def test_fly_twin_steps_a_stopped_twin_faster_than_real_time() -> None:
    from fpv_station.twin.pilot import fly_twin
    from fpv_station.twin.runner import Twin

    twin = Twin(config=QUIET)
    twin.step_for(2.5)
    pilot = Pilot(task_plan(twin.scene, 1))
    track = fly_twin(twin, pilot, timeout_s=120)
    assert pilot.done and not twin.sim.commander.armed[0]
    hover = track[(track[:, 0] > track[np.argmax(track[:, 3] > 3.95), 0])][:200]
    assert np.abs(hover[:, 3] - 4.0).max() < 0.3
    assert np.hypot(*(track[-1, 1:3] - twin.scene.pad("start").xy_m)) < 0.3


def test_free_fall_conserves_energy_and_drag_only_takes_it() -> None:
    from dataclasses import replace

    from fpv_station.twin.dynamics import Airframe, Dynamics

    def fall(airframe: Airframe) -> float:
        dyn = Dynamics(airframe=airframe)
        s = dyn.initial_state(1, np.array([0.0, 0.0]))
        s.pos_m[0, 2] = 30.0
        s.on_ground[:] = False
        while s.pos_m[0, 2] > 10.0:
            dyn.step(s, np.zeros((1, 4)))
        kinetic = 0.5 * float((s.vel_mps[0] ** 2).sum())
        return kinetic / (9.80665 * (30.0 - s.pos_m[0, 2]))  # per unit mass

    frictionless = replace(Airframe(), drag_linear_n_per_mps=0.0, drag_quadratic_n_per_mps2=0.0)
    assert fall(frictionless) == pytest.approx(1.0, abs=0.01)
    assert 0.4 < fall(Airframe()) < 0.9  # terminal speed ~18 m/s: drag takes a lot


def test_battery_energy_matches_the_power_drawn() -> None:
    sim = hover_sim()
    s, af = sim.state, sim.config.airframe
    q0, energy_j = float(s.charge_c[0]), 0.0
    for _ in range(100):  # 10 s, sampled at the battery's own 10 Hz update
        sim.step(25)
        energy_j += float(s.voltage_v[0] * s.current_a[0]) * 0.1
    f = s.rotor_thrust_n[0]
    power_w = af.power_coeff_w_per_n1_5 * float((f**1.5).sum()) + af.avionics_w
    assert energy_j == pytest.approx(power_w * 10.0, rel=0.03)
    assert (q0 - float(s.charge_c[0])) == pytest.approx(energy_j / float(s.voltage_v[0]), rel=0.03)


@pytest.mark.parametrize("task_id", [3, 4])
def test_pilot_flies_the_circle_and_figure_eight_tasks(task_id: int) -> None:
    sim = Sim(config=QUIET)
    sim.run_for(2.5)
    pilot = Pilot(task_plan(sim.scene, task_id))
    track = fly(sim, pilot, timeout_s=300)
    assert pilot.done and sim.crash_reason() == "", pilot.log[-3:]
    end = sim.scene.pad(sim.scene.task(task_id).end_pad).xy_m
    assert np.hypot(*(track[-1, 1:3] - end)) < 0.4
    assert np.abs(track[:, 2]).max() > 2.5  # it went around, not along the line
    if task_id == 4:  # a lobe around each obstacle: north and south of it, west and east
        for lobe in (track[:, 1] < -3.0, track[:, 1] > 3.0):
            ys = track[lobe, 2]
            assert ys.min() < -1.5 and ys.max() > 1.5

"""Synthetic flights whose answers are known because they are written here: shared by the
tests that check them and by benchmarks/accuracy.py, which prints the same cases' errors.

Each is a `tests.synthetic.Flight` (time, position, armed) with the truth it was built
from; tests/shaped_tlog.py and tests/synthetic.py turn them into logs and sessions."""

from __future__ import annotations

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from tests import synthetic as syn

# A motor test on the ground, three sorties with the vehicle walked between them, a GPS
# altitude blip on the pad and a tail after the last disarm: (time s, x m, z m)
# keyframes, linearly interpolated; the armed periods (s); each flight's truth.
SORTIES_DT = 0.02
SORTIES_KEYS = [
    (0, 0, 0),
    (17, 0, 0),  # motor test 5-10 s, then flight 1 armed at 15 s
    (20, 0, 5),  # climb: crosses 0.5 m at 17.3 s
    (30, 10, 5),
    (33, 10, 0),  # landed at 33 s (last airborne ~32.7 s), disarmed at 35 s
    (45, 20, 1),  # walked 10 m further, onto ground 1 m higher
    (51, 20, 1),  # flight 2 armed at 48 s; a 0.4 s GPS blip to 2 m at 51 s (not a take-off)
    (51.2, 20, 2),
    (51.4, 20, 1),
    (53, 20, 1),
    (56, 20, 7),  # climb from 1 m: crosses 1.5 m at 53.25 s
    (60, 30, 7),
    (63, 30, 1),  # landed at 63 s, disarmed at 66 s
    (72, 30, 1),
    (74, 30, 3),  # flight 3 armed at 70 s on the 1 m ground: crosses 1.5 m at 72.5 s
    (78, 30, 3),
    (80, 30, 0),  # down into a 1 m dip: below 1.5 m after 79 s; disarmed at 82 s, tail to 95 s
    (95, 30, 0),
]
SORTIES_ARMED = [(5, 10), (15, 35), (48, 66), (70, 82)]
SORTIES_TRUTH = [  # arm, takeoff, landing, disarm (s)
    (15.0, 17.3, 32.7, 35.0),
    (48.0, 53.25, 62.75, 66.0),
    (70.0, 72.5, 79.0, 82.0),
]


def three_sorties() -> syn.Flight:
    """The motor test, the three sorties and the tail (SORTIES_KEYS, SORTIES_ARMED)."""
    k = np.array(SORTIES_KEYS, dtype=float)
    t = np.arange(0.0, k[-1, 0], SORTIES_DT)
    xyz = np.stack(
        [np.interp(t, k[:, 0], k[:, 1]), np.zeros_like(t), np.interp(t, k[:, 0], k[:, 2])], 1
    )
    armed = np.zeros(t.size, bool)
    for a, d in SORTIES_ARMED:
        armed |= (t >= a) & (t < d)
    return syn.Flight(t_s=t, xyz_m=xyz, armed=armed)


# Two sorties 10 s apart, the log ending while still armed (armed periods, s).
TWO_SORTIES = ((1.0, 14.0), (24.0, None))  # the second never disarms
TWO_SORTIES_END_S = 37.0
# Two sorties disarmed 3 s apart: under the recorder's 5 s post-disarm tail, one session.
JOINED_SORTIES = ((1.0, 14.0), (17.0, 30.0))
JOINED_SORTIES_END_S = 33.0


def two_sorties(sorties=TWO_SORTIES, end_s: float = TWO_SORTIES_END_S) -> syn.Flight:
    """Each sortie: armed, climb 1 m/s to 3 m, 12 m along x at 2 m/s, down; walked back."""
    t = np.arange(0.0, end_s, 0.02)
    x, z = np.zeros_like(t), np.zeros_like(t)
    armed = np.zeros(t.size, bool)
    for arm, disarm in sorties:
        tau = t - arm
        on = (tau >= 0) & (t < (disarm if disarm is not None else end_s))
        armed |= on
        z += np.where(on, np.clip(np.minimum(tau - 1.0, 12.0 - tau), 0.0, 3.0), 0.0)
        x += np.where(on, 2.0 * np.clip(tau - 4.0, 0.0, 6.0), 0.0)
    return syn.Flight(t_s=t, xyz_m=np.stack([x, np.zeros_like(t), z], 1), armed=armed)


# Three recordings joined in one log whose clock steps back: each one a 3 m hop.
JOINED_T0 = 1_700_000_000.0
JOINED_STEPS_BACK_S = (523.0, 488.0)  # the second and third start this far back
HOP_ARMED_S, HOP_END_S = (2.0, 14.0), 20.0  # each recording: armed, a 3 m hop, disarmed


def hop_recording() -> syn.Flight:
    """One of the joined recordings: armed at 2 s, up to 3 m and down, disarmed at 14 s."""
    t = np.arange(0.0, HOP_END_S, 0.02)
    up = np.clip(np.minimum(t - 4.0, 10.0 - t), 0.0, 3.0)
    armed = (t >= HOP_ARMED_S[0]) & (t < HOP_ARMED_S[1])
    return syn.Flight(
        t_s=t, xyz_m=np.stack([np.zeros_like(t), np.zeros_like(t), up], 1), armed=armed
    )


def recording_starts() -> list[float]:
    """Each joined recording's first time: the file's clock steps back between them."""
    out = [JOINED_T0]
    for back in JOINED_STEPS_BACK_S:
        out.append(out[-1] + HOP_END_S - back)
    return out


# A 28 m/s dash through a radio fade of 4.3 s that ends in a 1 s burst of buffered packets.
DASH_SPEED_MPS = 28.0
DASH_FADE = (12.0, 16.3)  # 4.3 s without packets, the last 1 s of them then in one burst


def dash() -> syn.Flight:
    """Armed at 1.5 s, up to 3 m by 5 s, 15 s due east at 28 m/s (420 m), down, disarmed."""
    t = np.arange(0.0, 28.0, 0.02)
    x = DASH_SPEED_MPS * np.clip(t - 5.0, 0.0, 15.0)
    z = np.clip(np.minimum(t - 2.0, 23.0 - t), 0.0, 3.0)
    xyz = np.stack([x, np.zeros_like(t), z], 1)
    return syn.Flight(t_s=t, xyz_m=xyz, armed=(t >= 1.5) & (t < 25.0))


# ArduPilot's EKF origin set during a flight: a 1.3 m hop must read 1.3 m, not 181 m.
EKF_HOP_M = 1.3
ARDUPILOT = mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA


def ekf_hop(take_off_s: float, land_s: float, arm_s: float = 5.0, end_s: float = 30.0):
    """Armed at `arm_s`, a 1 m/s climb to EKF_HOP_M at `take_off_s`, down at `land_s`,
    disarmed 3 s after touching down."""
    t = np.arange(0.0, end_s, 0.02)
    up = np.clip(np.minimum(t - take_off_s, land_s - t), 0.0, EKF_HOP_M)
    xyz = np.stack([np.zeros_like(t), np.zeros_like(t), up], 1)
    armed = (t >= arm_s) & (t < land_s + EKF_HOP_M + 3.0)
    return syn.Flight(t_s=t, xyz_m=xyz, armed=armed)


EKF_CASES = {  # name: (the flight, when the EKF origin is set, s)
    "origin set armed on the ground": (ekf_hop(take_off_s=12.0, land_s=20.0), 8.0),
    "origin set during a low hop": (ekf_hop(take_off_s=8.0, land_s=18.0), 12.0),
}

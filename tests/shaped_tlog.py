"""Telemetry logs shaped like real ones, written with pymavlink's encoder, with their truth.

Real links carry several senders: the autopilot (1/1), a SiK telemetry radio (51/68)
that sends RADIO and RADIO_STATUS under one sequence number, other ground stations
(QGroundControl 255/190, MAVProxy), MAVLink 1 and 2 mixed. Radio fades drop packets
(sequence gaps), and a link that comes back delivers a burst of buffered packets with
one receive time. `Shaper` writes such a `.tlog` (8-byte big-endian Unix microseconds,
then the packet; the record format is written here, not with the station's code) and
keeps what really happened: which packets each sender sent and which were lost.

    log = Shaper(t0=1_700_000_000.0)
    ap = log.sender(1, 1)
    log.emit(ap, 0.0, ap.mav.heartbeat_encode(...))          # received at t0 + 0.0
    log.emit(ap, 0.1, msg, lost=True)                        # sent, never received
    log.write(path); log.truth[(1, 1)].loss_ratio
"""

from __future__ import annotations

import random
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from tests import synthetic

_TIME = struct.Struct(">Q")
HOME = (43.0021, -78.7875, 180.0)  # the paper's field


@dataclass
class Truth:
    sent: int = 0
    lost: int = 0
    duplicates: int = 0

    @property
    def received(self) -> int:
        return self.sent - self.lost + self.duplicates

    @property
    def loss_ratio(self) -> float:
        """Lost / sent, counting a repeated number once (as the station's figure does)."""
        return self.lost / (self.sent) if self.sent else 0.0


class Sender:
    """One (sysid, compid) with its own pymavlink encoder and sequence counter."""

    def __init__(self, sysid: int, compid: int, mavlink1: bool) -> None:
        self.mav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=compid)
        self.key = (sysid, compid)
        self.mavlink1 = mavlink1

    def pack(self, msg: mavlink.MAVLink_message, seq: int | None = None) -> bytes:
        if seq is not None:
            self.mav.seq = seq
        packet = bytes(msg.pack(self.mav, force_mavlink1=self.mavlink1))
        self.mav.seq = (self.mav.seq + 1) % 256
        return packet


@dataclass
class Shaper:
    t0: float = 1_700_000_000.0
    records: list[tuple[float, bytes]] = field(default_factory=list)
    truth: dict[tuple[int, int], Truth] = field(default_factory=dict)

    def sender(self, sysid: int, compid: int, mavlink1: bool = False) -> Sender:
        self.truth.setdefault((sysid, compid), Truth())
        return Sender(sysid, compid, mavlink1)

    def emit(
        self,
        sender: Sender,
        t_s: float,
        msg: mavlink.MAVLink_message,
        lost: bool = False,
        repeat_seq: bool = False,
    ) -> bytes:
        """`sender` sends `msg`; the station receives it at `t0 + t_s` unless `lost`.
        `repeat_seq`: under the previous packet's number (a SiK radio's second message)."""
        truth = self.truth[sender.key]
        seq = (sender.mav.seq - 1) % 256 if repeat_seq else None
        packet = sender.pack(msg, seq)
        if repeat_seq:
            truth.duplicates += 1
        else:
            truth.sent += 1
        if lost:
            truth.lost += 1
        else:
            self.records.append((self.t0 + t_s, packet))
        return packet

    def write(self, path: Path) -> Path:
        with open(path, "wb") as f:
            for t, packet in sorted(self.records, key=lambda r: r[0]):  # stable: burst order
                f.write(_TIME.pack(int(round(t * 1e6))) + packet)
        return path


# ---- the vehicle side: a PX4 or ArduPilot autopilot's periodic messages --------------------


def heartbeat(
    mav: mavlink.MAVLink, armed: bool = False, autopilot: int = mavlink.MAV_AUTOPILOT_PX4
):
    base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    if armed:
        base |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    # PX4 POSCTL (main mode 3), ArduCopter LOITER (5)
    mode = 3 << 16 if autopilot == mavlink.MAV_AUTOPILOT_PX4 else 5
    state = mavlink.MAV_STATE_ACTIVE if armed else mavlink.MAV_STATE_STANDBY
    return mav.heartbeat_encode(mavlink.MAV_TYPE_QUADROTOR, autopilot, base, mode, state)


def gcs_heartbeat(mav: mavlink.MAVLink):
    return mav.heartbeat_encode(
        mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, mavlink.MAV_STATE_ACTIVE
    )


def autopilot_messages(mav: mavlink.MAVLink, t_s: float, voltage_mv: int = 12300):
    """What an autopilot sends in the 20 ms tick at `t_s` (50 Hz ATTITUDE, 10 Hz position,
    5 Hz GPS, 2 Hz SYS_STATUS, 1 Hz HEARTBEAT): a real log's mix and proportions."""
    tick = int(round(t_s * 50))
    t_ms = int(t_s * 1000)
    out = [mav.attitude_encode(t_ms, 0.01, -0.02, 1.0, 0.0, 0.0, 0.0)]
    if tick % 5 == 0:
        lat, lon, alt = HOME
        out.append(
            mav.global_position_int_encode(
                t_ms, int(lat * 1e7), int(lon * 1e7), int(alt * 1000), 0, 0, 0, 0, 9000
            )
        )
        out.append(mav.vfr_hud_encode(0.0, 0.0, 90, 0, alt, 0.0))
    if tick % 10 == 0:
        lat, lon, alt = HOME
        out.append(
            mav.gps_raw_int_encode(
                int(t_s * 1e6), 3, int(lat * 1e7), int(lon * 1e7), int(alt * 1000),
                80, 120, 0, 0, 14,
            )
        )  # fmt: skip
    if tick % 25 == 0:
        out.append(mav.sys_status_encode(0, 0, 0, 250, voltage_mv, -1, -1, 0, 0, 0, 0, 0, 0))
    if tick % 50 == 0:
        out.append(heartbeat(mav))
    return out


def sik_radio_link(
    duration_s: float = 120.0,
    loss: float = 0.02,
    gap: tuple[float, float] | None = (60.0, 62.3),
    seed: int = 1,
) -> Shaper:
    """An autopilot over a SiK radio with two other ground stations on the link.

    - autopilot 1/1, MAVLink 2, ~73 packets/s, each lost with probability `loss`;
    - a fade from gap[0] to gap[1] s: everything the autopilot sends is lost, then the
      radio's buffer arrives as a burst (the last 0.5 s of packets, one receive time).
      Sequence numbers cannot tell 256 more lost packets from none: a fade that swallows
      more than 255 of one sender's packets (3.5 s here) is undercounted by 256 each
      time, by the station and by mavloss alike (the station reports it as link loss);
    - the SiK radio 51/68, MAVLink 1: RADIO_STATUS then RADIO under one number, 1 Hz;
    - QGroundControl 255/190 (MAVLink 2) and MAVProxy 255/0 (MAVLink 1) heartbeats, 1 Hz.
    """
    rng = random.Random(seed)
    log = Shaper()
    ap = log.sender(1, 1)
    radio = log.sender(51, 68, mavlink1=True)
    qgc = log.sender(255, 190)
    mavproxy = log.sender(255, 0, mavlink1=True)
    n_ticks = int(duration_s * 50)
    for tick in range(n_ticks):
        t = tick / 50
        in_gap = gap is not None and gap[0] <= t < gap[1]
        burst_end = gap[1] if gap is not None and gap[1] - 0.5 <= t < gap[1] else None
        for msg in autopilot_messages(ap.mav, t):
            if burst_end is not None:
                log.emit(ap, burst_end, msg)  # buffered, delivered at once when the fade ends
            else:
                log.emit(ap, t, msg, lost=in_gap or rng.random() < loss)
        if tick % 50 == 10:
            log.emit(radio, t, radio.mav.radio_status_encode(180, 170, 90, 40, 38, 0, 0))
            log.emit(radio, t, radio.mav.radio_encode(180, 170, 90, 40, 38, 0, 0), repeat_seq=True)
        if tick % 50 == 20:
            log.emit(qgc, t, gcs_heartbeat(qgc.mav))
        if tick % 50 == 30:
            log.emit(mavproxy, t, gcs_heartbeat(mavproxy.mav))
    return log


def silent_vehicle(duration_s: float = 90.0, silence: tuple[float, float] = (20.0, 65.0)) -> Shaper:
    """The autopilot falls silent for 45 s while the radio and a GCS keep talking."""
    log = Shaper()
    ap = log.sender(1, 1)
    radio = log.sender(51, 68, mavlink1=True)
    qgc = log.sender(255, 190)
    for tick in range(int(duration_s * 50)):
        t = tick / 50
        if not silence[0] <= t < silence[1]:
            for msg in autopilot_messages(ap.mav, t):
                log.emit(ap, t, msg)
        if tick % 50 == 10:
            log.emit(radio, t, radio.mav.radio_status_encode(180, 170, 90, 40, 38, 0, 0))
            log.emit(radio, t, radio.mav.radio_encode(180, 170, 90, 40, 38, 0, 0), repeat_seq=True)
        if tick % 50 == 20:
            log.emit(qgc, t, gcs_heartbeat(qgc.mav))
    return log


def no_battery_monitor(duration_s: float = 5.0) -> Shaper:
    """A vehicle without a battery monitor: SYS_STATUS says 0 mV (ArduPilot, PX4 alike)."""
    log = Shaper()
    ap = log.sender(1, 1)
    for tick in range(int(duration_s * 50)):
        t = tick / 50
        for msg in autopilot_messages(ap.mav, t, voltage_mv=0):
            log.emit(ap, t, msg)
    return log


def vehicle_flight(
    flight: synthetic.Flight,
    autopilot: int = mavlink.MAV_AUTOPILOT_PX4,
    fade: tuple[float, float] | None = None,
    burst_s: float = 1.0,
    origin_set_s: float | None = None,
    boot_s: float = 30.0,
    t0: float = 1_700_000_000.0,
    position_hz: int = 10,
    alt_error_m: np.ndarray | None = None,
    mavlink1: bool = False,
    rezero_m: float = 0.0,
    h_acc_m: float | None = None,
) -> Shaper:
    """A dense flight (`tests/synthetic.Flight`: positions and the armed state) as its
    autopilot sends it at a real log's rates: ATTITUDE 50 Hz, GLOBAL_POSITION_INT and
    VFR_HUD 10 Hz, GPS_RAW_INT 5 Hz (speed from the motion), SYS_STATUS 2 Hz, HEARTBEAT
    1 Hz with the armed flag; every message on the vehicle's clock (time_boot_ms /
    time_usec since a boot `boot_s` before the log starts).

    - `fade` (start, end) s: nothing arrives; the last `burst_s` of it arrives as one burst
      at `end` (a radio's buffer), with one receive time: a real log's "burst after a gap".
    - `origin_set_s`: ArduPilot's EKF origin. Before it GLOBAL_POSITION_INT says altitudes
      near 0 (height above the power-on point); at it the autopilot says "EKF3 IMU0 Origin
      set to GPS" and the altitude jumps to the true AMSL. GPS_RAW_INT is AMSL throughout.
      `relative_alt` is the height above the ground throughout (continuous across it).
    - `position_hz`: GLOBAL_POSITION_INT and VFR_HUD's rate (a divisor of 50; real
      ArduPilot logs over a radio have 1 to 10 Hz).
    - `alt_error_m` (one per flight sample): the GPS altitude's error, in GPS_RAW_INT and
      in GLOBAL_POSITION_INT `alt`, where 2013 ArduCopter put its GPS altitude (metres of
      wander) while `relative_alt` came from the barometer.
    - `mavlink1`: the autopilot speaks MAVLink 1 (old firmware).
    - `rezero_m`: the estimator's height drifted this much on the ground before the first
      arming, and ArduPilot re-zeroes it at arming (its barometer and height datum, and
      its home set there): until then `relative_alt` reads it, and so does `alt` before
      the origin is set (after it, the origin's height keeps `alt` continuous).
    - `h_acc_m`: the GPS's horizontal accuracy in GPS_RAW_INT `h_acc` (MAVLink 2; None:
      0, which says the receiver does not know it).
    """
    log = Shaper(t0=t0)
    ap = log.sender(1, 1, mavlink1=mavlink1)
    mav = ap.mav
    t = flight.t_s
    llh = flight.llh()
    enu = flight.enu_m()
    vel = np.gradient(enu, t, axis=0)
    home_alt = flight.home[2]
    for tick in range(int(t[-1] * 50)):
        now = tick / 50
        i = min(int(np.searchsorted(t, now)), t.size - 1)
        t_ms = int((boot_s + now) * 1000)
        lat, lon = int(round(llh[i, 0] * 1e7)), int(round(llh[i, 1] * 1e7))
        up = float(enu[i, 2])
        ve, vn, vu = (float(v) for v in vel[i])
        out = [mav.attitude_encode(t_ms, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0)]
        if origin_set_s is not None and tick == int(round(origin_set_s * 50)):
            # said as the origin is set, before the first position in the new frame
            out.append(mav.statustext_encode(6, b"EKF3 IMU0 Origin set to GPS"))
        if tick % (50 // position_hz) == 0:
            origin_set = origin_set_s is None or now >= origin_set_s
            drift = rezero_m if not flight.armed[: i + 1].any() else 0.0
            fused = home_alt + up if origin_set else up + 0.3 + drift  # the EKF's frame
            if alt_error_m is not None:
                fused += float(alt_error_m[i])
            out.append(
                mav.global_position_int_encode(
                    t_ms, lat, lon, int(round(fused * 1000)), int(round((up + drift) * 1000)),
                    int(round(vn * 100)), int(round(ve * 100)), int(round(-vu * 100)), 9000,
                )
            )  # fmt: skip
            out.append(mav.vfr_hud_encode(0.0, float(np.hypot(ve, vn)), 90, 40, fused, vu))
        if tick % 10 == 0:
            gps_alt = llh[i, 2] + (0.0 if alt_error_m is None else float(alt_error_m[i]))
            out.append(
                mav.gps_raw_int_encode(
                    int((boot_s + now) * 1e6), 3, lat, lon, int(round(gps_alt * 1000)),
                    80, 120, int(round(100 * np.hypot(ve, vn))), 0, 14,
                    h_acc=0 if h_acc_m is None else int(round(h_acc_m * 1000)),
                )
            )  # fmt: skip
        if tick % 25 == 0:
            out.append(mav.sys_status_encode(0, 0, 0, 250, 12300, -1, -1, 0, 0, 0, 0, 0, 0))
        if tick % 50 == 0:
            out.append(heartbeat(mav, bool(flight.armed[i]), autopilot))
        for msg in out:
            if fade is not None and fade[1] - burst_s <= now < fade[1]:
                log.emit(ap, fade[1], msg)  # buffered, delivered at once when the fade ends
            else:
                log.emit(ap, now, msg, lost=fade is not None and fade[0] <= now < fade[1])
    return log


def write_joined(path: Path, *logs: Shaper) -> Path:
    """Several recordings in one file, each after the one before whatever their times (a
    log appended to, or files concatenated): where a later one's clock starts earlier,
    the file's clock steps back."""
    with open(path, "wb") as f:
        for log in logs:
            for t, packet in sorted(log.records, key=lambda r: r[0]):
                f.write(_TIME.pack(int(round(t * 1e6))) + packet)
    return path

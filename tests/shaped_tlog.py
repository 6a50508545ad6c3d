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

from pymavlink.dialects.v20 import ardupilotmega as mavlink

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
    return mav.heartbeat_encode(
        mavlink.MAV_TYPE_QUADROTOR, autopilot, base, 3 << 16, mavlink.MAV_STATE_STANDBY
    )


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
        burst = gap is not None and gap[1] - 0.5 <= t < gap[1]
        for msg in autopilot_messages(ap.mav, t):
            if burst:
                log.emit(ap, gap[1], msg)  # buffered, delivered at once when the fade ends
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

"""MCAP files for Foxglove (and the ROS world), one per episode, through the Foxglove SDK.

`<out>/<recording>_flight<N>.mcap` holds the flight from arming to disarming, every
message on log time (Unix ns), so Foxglove plays it back with both cameras:

| topic | schema | one message per |
| --- | --- | --- |
| `/<camera>/image/compressed` | `foxglove.CompressedImage` | recorded frame: its JPEG bytes as recorded (re-encoded only if `--image-size` resizes it) |
| `/gps` | `foxglove.LocationFix` | telemetry row (GPS_RAW_INT position, else GLOBAL_POSITION_INT) |
| `/pose` | `foxglove.PoseInFrame` | telemetry row: `base_link` in the scene's ENU frame `field` |
| `/tf` | `foxglove.FrameTransform` | telemetry row: `field` -> `base_link` (the same pose) |
| `/telemetry` | JSON | telemetry row: `t_s` and the columns the exporters read (NaN as null) |
| `/mavlink` | raw bytes, encoding `mavlink` | MAVLink packet in the tlog |
| `/onboard/<stream>` | JSON | sample of the autopilot's own log (`learn.onboard_export`): IMU, attitude, rates, rate setpoints, motors, RC at their native rates |

Rows, frames and MAVLink packets go on the session clock shifted to Unix time (the
session's start): a packet is cut and placed by its time on the session clock
(`Recording.tlog_packets`), so a tlog of several joined recordings, whose own clock
steps back, gives each flight its own packets. The pose is the episode's position (see
`learn.episodes`) with the attitude from ATTITUDE (FRD/NED turned into FLU/ENU).
"""

from __future__ import annotations

import heapq
import math
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import foxglove
import numpy as np
from foxglove.channels import (
    CompressedImageChannel,
    FrameTransformChannel,
    LocationFixChannel,
    PoseInFrameChannel,
)
from foxglove.messages import (
    CompressedImage,
    FrameTransform,
    LocationFix,
    Pose,
    PoseInFrame,
    Quaternion,
    Timestamp,
    Vector3,
)

from fpv_station.analysis.onboard_log import SessionOnboard
from fpv_station.analysis.recording import Recording
from fpv_station.learn.episodes import COLUMNS, Episode, carry_forward, scene_xyz
from fpv_station.learn.images import resized_jpeg
from fpv_station.learn.onboard_export import onboard_events

WORLD_FRAME = "field"
BODY_FRAME = "base_link"
# (log time ns, kind, payload): kind "row", "frame", "packet" or "onboard", and the
# payload that kind's channels log.
Event = tuple[int, str, Any]


def mcap_name(rec: Recording, ep: Episode) -> str:
    safe = "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in rec.name)
    return f"{safe}_flight{ep.number}.mcap"


class McapExport:
    """`learn.export`'s adapter: the jobs write each episode's file (`write_episode_mcap`)
    as a part; this moves them, in order, to their names (`mcap_name`; a name that
    recurs, as a recording exported twice, gets `_2`, `_3`, ...)."""

    def __init__(self, out: Path):
        self.out = Path(out)
        self.files: list[Path] = []
        self._names: dict[str, int] = {}

    def add(self, part: tuple[Path, str]) -> None:
        path, name = part
        seen = self._names[name] = self._names.get(name, 0) + 1
        if seen > 1:
            name = f"{name.removesuffix('.mcap')}_{seen}.mcap"
        final = self.out / name
        os.replace(path, final)
        self.files.append(final)

    def close(self, summary) -> None:
        pass


def write_episode_mcap(
    path: Path,
    rec: Recording,
    ep: Episode,
    scene,
    task_id: int,
    cameras: tuple[str, ...],
    task: str,
    image_size: tuple[int, int] | None = None,
    onboard: SessionOnboard | None = None,
) -> None:
    ctx = foxglove.Context()
    images = {c: CompressedImageChannel(f"/{c}/image/compressed", context=ctx) for c in cameras}
    gps = LocationFixChannel("/gps", context=ctx)
    pose = PoseInFrameChannel("/pose", context=ctx)
    tf = FrameTransformChannel("/tf", context=ctx)
    telemetry = foxglove.Channel("/telemetry", context=ctx)
    raw = foxglove.Channel(
        "/mavlink",
        message_encoding="mavlink",
        # MAVLink has no MCAP schema encoding: the schema names the dialect, as text.
        schema=foxglove.Schema(name="mavlink.common", encoding="mavlink-dialect", data=b"common"),
        context=ctx,
        metadata={"format": "MAVLink 1/2 packets as received, one per message"},
    )
    streams_of_log = onboard.log.streams if onboard is not None else {}
    onboard_ch = {n: foxglove.Channel(f"/onboard/{n}", context=ctx) for n in streams_of_log}
    i0, i1 = ep.flight.arm, ep.flight.disarm
    wall0 = _wall_offset(rec)
    with foxglove.open_mcap(path, allow_overwrite=True, context=ctx) as writer:
        writer.write_metadata(
            "episode",
            {
                "recording": rec.name,
                "flight": str(ep.number),
                "task_id": str(task_id),
                "task": task,
                "landed": str(ep.landed).lower(),
            },
        )
        streams: list[Iterator[Event]] = [_row_events(rec, scene, task_id, i0, i1, wall0)]
        streams += [_frame_events(rec, c, ep, wall0, image_size) for c in cameras]
        if rec.tlog is not None:
            streams.append(_packet_events(rec, rec.t_s[i0], rec.t_s[i1], wall0))
        if onboard is not None:
            streams.append(onboard_events(onboard, rec.t_s[i0], rec.t_s[i1], wall0))
        for t_ns, kind, payload in heapq.merge(*streams, key=lambda e: e[0]):
            if kind == "row":
                fix, pose_msg, tf_msg, row = payload
                gps.log(fix, log_time=t_ns)
                pose.log(pose_msg, log_time=t_ns)
                tf.log(tf_msg, log_time=t_ns)
                telemetry.log(row, log_time=t_ns)
            elif kind == "packet":
                raw.log(payload, log_time=t_ns)
            elif kind == "onboard":
                onboard_ch[payload[0]].log(payload[1], log_time=t_ns)
            else:
                cam, jpeg = payload
                images[cam].log(
                    CompressedImage(
                        timestamp=_stamp(t_ns), frame_id=f"{cam}_camera", data=jpeg, format="jpeg"
                    ),
                    log_time=t_ns,
                )


def _row_events(
    rec: Recording, scene, task_id: int, i0: int, i1: int, wall0: float
) -> Iterator[Event]:
    xyz = scene_xyz(rec, scene, task_id, np.arange(i0, i1 + 1))
    c = rec.columns
    q = enu_flu_quaternion(
        np.nan_to_num(c["attitude.roll_rad"][i0 : i1 + 1]),
        np.nan_to_num(c["attitude.pitch_rad"][i0 : i1 + 1]),
        np.nan_to_num(c["attitude.yaw_rad"][i0 : i1 + 1]),
    )
    # The latest fix at each row, as rows hold the latest state (0 only before any fix).
    lat = carry_forward(_prefer(c["gps.lat_deg"], c["global_position.lat_deg"]))
    lon = carry_forward(_prefer(c["gps.lon_deg"], c["global_position.lon_deg"]))
    alt = carry_forward(_prefer(c["gps.alt_m"], c["global_position.alt_m"]))
    for k, i in enumerate(range(i0, i1 + 1)):
        t_ns = int(round((wall0 + rec.t_s[i]) * 1e9))
        stamp = _stamp(t_ns)
        fix = LocationFix(
            timestamp=stamp,
            frame_id="gps",
            latitude=_num(lat[i]),
            longitude=_num(lon[i]),
            altitude=_num(alt[i]),
        )
        position = Vector3(x=float(xyz[k, 0]), y=float(xyz[k, 1]), z=float(xyz[k, 2]))
        orientation = Quaternion(
            x=float(q[k, 0]), y=float(q[k, 1]), z=float(q[k, 2]), w=float(q[k, 3])
        )
        pose = PoseInFrame(
            timestamp=stamp,
            frame_id=WORLD_FRAME,
            pose=Pose(position=position, orientation=orientation),
        )
        tf = FrameTransform(
            timestamp=stamp,
            parent_frame_id=WORLD_FRAME,
            child_frame_id=BODY_FRAME,
            translation=position,
            rotation=orientation,
        )
        row: dict[str, float | None] = {"t_s": float(rec.t_s[i])}
        row.update({n: _json_num(c[n][i]) for n in COLUMNS})
        yield t_ns, "row", (fix, pose, tf, row)


def frame_window(rec: Recording, cam: str, ep: Episode) -> np.ndarray:
    t = rec.cameras[cam].t_s
    return np.flatnonzero((t >= rec.t_s[ep.flight.arm]) & (t <= rec.t_s[ep.flight.disarm]))


def _frame_events(rec: Recording, cam: str, ep: Episode, wall0: float, size) -> Iterator[Event]:
    t = rec.cameras[cam].t_s
    for k in frame_window(rec, cam, ep):
        jpeg = rec.frame_bytes(cam, int(k))
        if size is not None:
            jpeg = resized_jpeg(jpeg, size)
        yield int(round((wall0 + t[k]) * 1e9)), "frame", (cam, jpeg)


def _packet_events(rec: Recording, t_lo: float, t_hi: float, wall0: float) -> Iterator[Event]:
    """The tlog's packets from `t_lo` to `t_hi` on the session clock (a joined log's
    recordings each on their own, as the rows), on the rows' log time."""
    for t, packet in rec.tlog_packets():
        if t_lo <= t <= t_hi:
            yield int(round((wall0 + t) * 1e9)), "packet", packet


def _wall_offset(rec: Recording) -> float:
    """Unix time of the session clock's zero."""
    d = rec.wall_time - rec.t_s
    d = d[np.isfinite(d)]
    return float(np.median(d)) if d.size else 0.0


def enu_flu_quaternion(roll: np.ndarray, pitch: np.ndarray, yaw_ned: np.ndarray) -> np.ndarray:
    """(n, 4) x, y, z, w of the FLU body in ENU, from ATTITUDE's FRD-in-NED Euler angles:
    the same physical roll, pitch negated (FLU's y points left), heading counter-clockwise
    from east."""
    phi, theta, psi = roll / 2, -pitch / 2, (np.pi / 2 - yaw_ned) / 2
    cf, sf, ct, stt, cp, sp = (
        np.cos(phi),
        np.sin(phi),
        np.cos(theta),
        np.sin(theta),
        np.cos(psi),
        np.sin(psi),
    )
    return np.column_stack(
        [
            sf * ct * cp - cf * stt * sp,
            cf * stt * cp + sf * ct * sp,
            cf * ct * sp - sf * stt * cp,
            cf * ct * cp + sf * stt * sp,
        ]
    )


def _prefer(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a if np.isfinite(a).any() else b


def _json_num(v: float) -> float | None:
    return None if math.isnan(v) else float(v)


def _num(v: float) -> float:
    return 0.0 if math.isnan(v) else float(v)


def _stamp(t_ns: int) -> Timestamp:
    return Timestamp(sec=t_ns // 1_000_000_000, nsec=t_ns % 1_000_000_000)

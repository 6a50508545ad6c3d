"""Builds the recorder from the settings and the station's own objects.

The recorder's inputs are exactly the station's: the vehicle state `Latest`, each
camera's `frames` Latest, and the link's packet listener hook.
"""

from __future__ import annotations

import contextlib
from collections.abc import Mapping
from typing import Any

from fpv_station.companion.latest import Latest
from fpv_station.companion.link import MavlinkLink
from fpv_station.companion.recording.recorder import Recorder, RecorderOptions
from fpv_station.companion.recording.session import SessionConfig
from fpv_station.companion.recording.writer import WriterLimits
from fpv_station.companion.vehicle_state import VehicleState
from fpv_station.companion.video_frame import Frame
from fpv_station.core.spawn import Spawn
from fpv_station.server import __version__
from fpv_station.server.settings import Settings


def recorder_options(settings: Settings, camera_fps: Mapping[str, float | None]) -> RecorderOptions:
    r = settings.recording
    limits = WriterLimits(
        row_queue=r.row_queue,
        frame_queue=r.frame_queue,
        packet_queue=r.packet_queue,
        flush_interval_s=r.flush_interval_s,
        min_free_bytes=int(r.min_free_mb * 1024 * 1024),
    )
    session = SessionConfig(
        rate_hz=r.rate_hz,
        limits=limits,
        link_lost_s=settings.link.link_lost_s,
        source=settings.link.source,
        software_version=__version__,
        settings=_provenance(settings),
        camera_fps=dict(camera_fps),
        clock_max_disagree_s=r.clock_max_disagree_s,
    )
    return RecorderOptions(
        session=session,
        auto_record_on_arm=r.auto_record_on_arm,
        post_disarm_tail_s=r.post_disarm_tail_s,
    )


def _provenance(settings: Settings) -> dict[str, Any]:
    """The settings a dataset user needs to know how a session was made (no token)."""
    out: dict[str, Any] = {
        "recording": settings.recording.model_dump(mode="json"),
        "link": {"source": settings.link.source, "sysid": settings.link.sysid},
        "cameras": settings.cameras.model_dump(mode="json"),
    }
    if settings.link.source == "sim":  # the twin's settings made this flight
        out["twin"] = settings.twin.model_dump(mode="json")
    return out


async def open_recorder(
    settings: Settings,
    stack: contextlib.AsyncExitStack,
    spawn: Spawn,
    state: Latest[VehicleState],
    cameras: Mapping[str, Latest[Frame]],
    camera_fps: Mapping[str, float | None],
    link: MavlinkLink | None,
) -> Recorder:
    """Build the recorder, hook it to the link, mark cut-off sessions; stops with `stack`."""
    recorder = Recorder(
        settings.recording.sessions_dir,
        state,
        cameras,
        recorder_options(settings, camera_fps),
        clock=link.clock if link is not None else None,
        timesync=link.timesync if link is not None else None,
    )
    if link is not None:
        link.add_packet_listener(recorder.on_packet)
    await recorder.open(spawn)
    stack.push_async_callback(recorder.aclose)
    return recorder

"""Start and stop recording, and what is being recorded now."""

from __future__ import annotations

import dataclasses

from fastapi import APIRouter, Depends, Request
from pydantic import BaseModel

from fpv_station.companion.recording.recorder import Recorder, RecorderError
from fpv_station.server.auth import require_control_token
from fpv_station.server.errors import Unavailable

router = APIRouter(tags=["recording"])


class LastStopModel(BaseModel):
    id: str
    reason: str
    end_wall: float


class RecordingStatusModel(BaseModel):
    recording: bool
    id: str | None = None
    trigger: str | None = None  # "rest", "arm", ...
    start_wall: float | None = None
    elapsed_s: float | None = None
    telemetry_rows: int = 0
    frames_written: dict[str, int] = {}
    frames_dropped: dict[str, int] = {}
    auto_record_on_arm: bool = True
    stopping_at_wall: float | None = None  # end of the post-disarm tail, when pending
    last_stop: LastStopModel | None = None  # the previous session and why it stopped
    last_error: str | None = None  # why the last start failed, if it did
    # Seconds armed with no session recording (None: disarmed or recording), and whether
    # that is a flight not being recorded (longer than a start takes): NOT RECORDING.
    armed_unrecorded_s: float | None = None
    not_recording: bool = False


def get_recorder(request: Request) -> Recorder:
    recorder = getattr(request.app.state.station, "recorder", None)
    if recorder is None:
        raise Unavailable("Recording is not available on this station.")
    return recorder


def _model(recorder: Recorder) -> RecordingStatusModel:
    return RecordingStatusModel.model_validate(dataclasses.asdict(recorder.status()))


@router.get("/api/recording", response_model=RecordingStatusModel, summary="Recording status")
async def recording_status(recorder: Recorder = Depends(get_recorder)) -> RecordingStatusModel:
    return _model(recorder)


@router.post(
    "/api/recording/start",
    response_model=RecordingStatusModel,
    dependencies=[Depends(require_control_token)],
    summary="Start recording a session (no-op while one is recording)",
)
async def start_recording(recorder: Recorder = Depends(get_recorder)) -> RecordingStatusModel:
    try:
        await recorder.start("rest")
    except RecorderError as exc:
        raise Unavailable(f"Recording did not start: {exc}") from None
    return _model(recorder)


@router.post(
    "/api/recording/stop",
    response_model=RecordingStatusModel,
    dependencies=[Depends(require_control_token)],
    summary="Stop the session being recorded (no-op when none is)",
)
async def stop_recording(recorder: Recorder = Depends(get_recorder)) -> RecordingStatusModel:
    await recorder.stop("requested")
    return _model(recorder)

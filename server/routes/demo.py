"""Demonstration mode (server.demo_mode): a pilot's run of N attempts at the chosen task.

GET    /api/demo   the run (the current one, else the last), the attempt being flown
                   and each attempt's session with whether its trial counts
POST   /api/demo   {"pilot": "Ana", "attempts": 5} (control): start a run
DELETE /api/demo   (control): end the run now
"""

from __future__ import annotations

import asyncio

from fastapi import APIRouter, Depends, Request
from pydantic import BaseModel, ConfigDict, Field, field_validator

from fpv_station.analysis.selection import trial_failed
from fpv_station.companion.recording.meta import PILOT_NAME_MAX, check_pilot_name
from fpv_station.server.auth import require_control_token
from fpv_station.server.demo_mode import MAX_ATTEMPTS, DemoMode, DemoRun
from fpv_station.server.errors import Conflict

router = APIRouter(tags=["demo"])


class DemoStart(BaseModel):
    model_config = ConfigDict(extra="forbid")
    pilot: str = Field(max_length=4 * PILOT_NAME_MAX)
    attempts: int = Field(ge=1, le=MAX_ATTEMPTS)

    @field_validator("pilot")
    @classmethod
    def _name(cls, v: str) -> str:
        return check_pilot_name(v)


class DemoAttempt(BaseModel):
    attempt: int
    session: str
    counts: bool | None  # the trial is valid by its score; None: not scored yet
    why: str | None  # why it does not count


class DemoReply(BaseModel):
    run: DemoRun | None  # the current run, else the last one (None: none yet)
    active: bool
    attempt: int | None  # the attempt flown next, or being recorded (1-based)
    recording: bool  # that attempt's session is being recorded now
    flown: list[DemoAttempt]
    max_attempts: int = MAX_ATTEMPTS


def _demo(request: Request) -> DemoMode:
    demo = request.app.state.station.demo
    if demo is None:
        raise Conflict("This station does not record, so it has no demonstration mode.")
    return demo


async def _reply(demo: DemoMode) -> DemoReply:
    run = demo.run
    flown = []
    for k, (sid, meta) in enumerate(await asyncio.to_thread(demo.attempts_flown), 1):
        if meta is not None and meta.task is not None and meta.score is None:
            flown.append(DemoAttempt(attempt=k, session=sid, counts=None, why=None))
            continue
        why = trial_failed(meta) if meta is not None else "the session is gone"
        flown.append(DemoAttempt(attempt=k, session=sid, counts=why is None, why=why))
    recording = demo.recording_attempt()
    active = run is not None and run.active
    return DemoReply(
        run=run,
        active=active,
        attempt=(recording or len(run.sessions) + 1) if run is not None and active else None,
        recording=recording is not None,
        flown=flown,
    )


@router.get("/api/demo", response_model=DemoReply, summary="The demonstration run")
async def get_demo(request: Request) -> DemoReply:
    return await _reply(_demo(request))


@router.post(
    "/api/demo",
    response_model=DemoReply,
    summary="Start a demonstration run at the chosen task",
    dependencies=[Depends(require_control_token)],
)
async def start_demo(body: DemoStart, request: Request) -> DemoReply:
    demo = _demo(request)
    demo.start(body.pilot, body.attempts)
    await asyncio.to_thread(demo.save)
    return await _reply(demo)


@router.delete(
    "/api/demo",
    response_model=DemoReply,
    summary="End the demonstration run now",
    dependencies=[Depends(require_control_token)],
)
async def end_demo(request: Request) -> DemoReply:
    demo = _demo(request)
    if demo.end("ended by the pilot") is not None:
        await asyncio.to_thread(demo.save)
    return await _reply(demo)

"""The flight task the pilot flies next, its procedure and its scores, and the field.

    GET  /api/scene     the station's field for the pilot's map (pads, obstacles, tasks)
    GET  /api/task      the chosen task, the scene's tasks, the last score, this day's
                        attempts at the chosen task and the paper's figures for it
    POST /api/task      {"task_id": 1} or {"task_id": null} (control); kept over a
                        restart (server.trials.CHOSEN_TASK_FILE); refused (409) while
                        a demonstration run of another task is on (server.demo_mode)

The chosen task is written into every session that starts while it is chosen
(`session.json` `task`); when such a session ends the station scores it (`score`).
"""

from __future__ import annotations

import asyncio
from typing import Any

from fastapi import APIRouter, Depends, Request
from pydantic import BaseModel, ConfigDict

from fpv_station.analysis.compare import LOWER_IS_BETTER
from fpv_station.companion.recording.meta import SessionTask, TrialScore
from fpv_station.core.scene import bgr_to_rgb
from fpv_station.server.auth import require_control_token
from fpv_station.server.errors import BadRequest, Conflict
from fpv_station.server.station import Station
from fpv_station.server.trials import Trials

router = APIRouter(tags=["task"])


class TaskChoice(BaseModel):
    model_config = ConfigDict(extra="forbid")
    task_id: int | None


class TaskInfo(BaseModel):
    id: int
    name: str
    analysis: str | None
    altitude_m: float
    hold_s: float
    start_pad: str
    end_pad: str
    circle_obstacle: str | None
    procedure: list[str]


class Attempt(BaseModel):
    session: str
    start_utc: str
    score: TrialScore


class TaskReply(BaseModel):
    selected: SessionTask | None
    tasks: list[TaskInfo]
    scoring: bool  # a finished session is being scored now
    # The newest scored trial of the chosen task: this run's, else today's newest attempt
    # (a restarted station still shows the last trial flown before it stopped).
    last_session: str | None
    last_score: TrialScore | None
    attempts: list[Attempt]  # today's scored sessions of the chosen task, newest first
    paper: dict[str, dict[str, float]] | None  # the paper's figures: physical, twin
    lower_is_better: list[str]  # the result's fields where smaller is the better flight


def _trials(request: Request) -> Trials:
    station: Station = request.app.state.station
    assert station.trials is not None  # built with the station
    return station.trials


async def _reply(trials: Trials) -> TaskReply:
    sel = trials.selected
    attempts = [Attempt(**a) for a in await trials.attempts(sel.id)] if sel else []
    last = trials.last
    if last is None and attempts:
        last = (attempts[0].session, attempts[0].score)
    return TaskReply(
        selected=sel,
        tasks=[
            TaskInfo(
                id=t.id,
                name=t.name,
                analysis=t.analysis_task,
                altitude_m=t.altitude_m,
                hold_s=t.hold_s,
                start_pad=t.start_pad,
                end_pad=t.end_pad,
                circle_obstacle=t.circle_obstacle,
                procedure=list(t.procedure),
            )
            for t in trials.scene.tasks
        ],
        scoring=trials.scoring,
        last_session=last[0] if last else None,
        last_score=last[1] if last else None,
        attempts=attempts,
        paper=trials.paper(sel.analysis) if sel else None,
        lower_is_better=sorted(LOWER_IS_BETTER),
    )


@router.get("/api/task", response_model=TaskReply, summary="The chosen flight task and scores")
async def get_task(request: Request) -> TaskReply:
    return await _reply(_trials(request))


@router.post(
    "/api/task",
    response_model=TaskReply,
    summary="Choose the flight task for the next sessions (null: none)",
    dependencies=[Depends(require_control_token)],
)
async def post_task(choice: TaskChoice, request: Request) -> TaskReply:
    trials = _trials(request)
    run = request.app.state.station.demo and request.app.state.station.demo.active
    if run and choice.task_id != run.task_id:
        raise Conflict(
            f"{run.pilot}'s demonstration run of task {run.task_id} is on; end it first."
        )
    try:
        trials.select(choice.task_id)
    except KeyError:
        known = ", ".join(str(t.id) for t in trials.scene.tasks) or "none"
        raise BadRequest(
            f"No task {choice.task_id} in scene '{trials.scene.name}'; tasks: {known}."
        ) from None
    await asyncio.to_thread(trials.save_choice)
    return await _reply(trials)


@router.get("/api/scene", summary="The station's field for the pilot's map")
async def get_scene(request: Request) -> dict[str, Any]:
    trials = _trials(request)
    scene = trials.scene
    return {
        "name": scene.name,
        # False: a real flight with no scene file; the map shows only home and the trail.
        "is_field": trials.is_field,
        "home": {
            "lat_deg": scene.home.lat_deg,
            "lon_deg": scene.home.lon_deg,
            "alt_m": scene.home.alt_m,
        },
        "size_m": [scene.field.size_x_m, scene.field.size_y_m],
        "pads": [
            {
                "name": p.name,
                "x_m": p.x_m,
                "y_m": p.y_m,
                "size_m": p.size_m,
                "rgb": bgr_to_rgb(p.bgr),
            }
            for p in scene.pads
        ],
        "obstacles": [
            {
                "name": o.name,
                "x_m": o.x_m,
                "y_m": o.y_m,
                "width_m": o.width_m,
                "depth_m": o.depth_m,
                "height_m": o.height_m,
                "rgb": bgr_to_rgb(o.bgr),
            }
            for o in scene.obstacles
        ],
    }

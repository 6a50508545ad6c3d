"""API errors and their one reply shape: `{"error": Name, "error_msg": text}`.

    ApiError                  (500, base; never raised bare)
    ├── BadRequest            (400)
    ├── Unauthorized          (401)
    ├── NotFound              (404)
    ├── Conflict              (409)
    └── Unavailable           (503, a service that is not running or not ready)

Errors of the session store (`companion.recording.store`: a bad id or path -> 400, an
unknown session or file -> 404) are mapped here too, so no route translates them itself.
Handlers are installed in one place (`install_error_handlers`); unexpected exceptions
are logged with their traceback and answered with a short 500, never the traceback.
"""

from __future__ import annotations

import asyncio
import logging
import weakref
from typing import Any

from fastapi import FastAPI, Request, WebSocket
from fastapi.exceptions import RequestValidationError, WebSocketRequestValidationError
from fastapi.responses import JSONResponse
from pydantic import BaseModel
from starlette.exceptions import HTTPException as StarletteHTTPException

from fpv_station.companion.recording import store as session_store

log = logging.getLogger(__name__)


class ErrorReply(BaseModel):
    error: str
    error_msg: str


class ApiError(Exception):
    status_code = 500

    def __init__(self, message: str) -> None:
        super().__init__(message)
        self.message = message


class BadRequest(ApiError):
    status_code = 400


class Unauthorized(ApiError):
    status_code = 401


class NotFound(ApiError):
    status_code = 404


class Conflict(ApiError):
    status_code = 409


class Unavailable(ApiError):
    status_code = 503


def error_response(status_code: int, name: str, message: str) -> JSONResponse:
    return JSONResponse(
        ErrorReply(error=name, error_msg=message).model_dump(), status_code=status_code
    )


async def deny_websocket(ws: WebSocket, status_code: int, name: str, message: str) -> None:
    """Refuse a WebSocket upgrade with an HTTP answer in the error shape (503 at a cap,
    400 for a bad query), not a bare 403: browsers and scripts see why."""
    # uvicorn's websockets-sansio protocol (0.54) then logs "ASGI callable returned
    # without completing handshake." at ERROR for every denial, a bug it has open
    # (Kludex/uvicorn#3138). It logs from the task that ran this handler: DenialLogFilter
    # drops that record for the tasks marked here, and a uvicorn without the bug leaves
    # nothing behind (the mark goes with the task).
    task = asyncio.current_task()
    if task is not None:
        _DENYING_TASKS.add(task)
    await ws.send_denial_response(error_response(status_code, name, message))


_DENYING_TASKS: weakref.WeakSet[asyncio.Task[Any]] = weakref.WeakSet()


class DenialLogFilter(logging.Filter):
    """On `uvicorn.error`: drops uvicorn's false "without completing handshake" error
    logged by a task that sent a denial through `deny_websocket`; the same message from
    any other task (a handler that really returned without accepting) is still logged."""

    MESSAGE = "ASGI callable returned without completing handshake."

    def filter(self, record: logging.LogRecord) -> bool:
        if record.levelno != logging.ERROR or record.getMessage() != self.MESSAGE:
            return True
        try:
            task = asyncio.current_task()
        except RuntimeError:  # logged outside an event loop
            return True
        if task is not None and task in _DENYING_TASKS:
            _DENYING_TASKS.discard(task)
            return False
        return True


def install_error_handlers(app: FastAPI) -> None:
    @app.exception_handler(ApiError)
    async def _api_error(_: Request, exc: ApiError) -> JSONResponse:
        return error_response(exc.status_code, type(exc).__name__, exc.message)

    @app.exception_handler(session_store.SessionStoreError)
    async def _store_error(_: Request, exc: session_store.SessionStoreError) -> JSONResponse:
        return _from_store_error(exc)

    @app.exception_handler(RequestValidationError)
    async def _validation(_: Request, exc: RequestValidationError) -> JSONResponse:
        problems = "; ".join(
            f"{'.'.join(str(p) for p in err['loc'])}: {err['msg']}" for err in exc.errors()
        )
        return error_response(422, "ValidationError", problems)

    @app.exception_handler(WebSocketRequestValidationError)
    async def _ws_validation(ws: WebSocket, exc: WebSocketRequestValidationError) -> None:
        problems = "; ".join(
            f"{'.'.join(str(p) for p in err['loc'])}: {err['msg']}" for err in exc.errors()
        )
        await deny_websocket(ws, 400, "BadRequest", problems)

    @app.exception_handler(StarletteHTTPException)
    async def _http(_: Request, exc: StarletteHTTPException) -> JSONResponse:
        return error_response(exc.status_code, "HTTPError", str(exc.detail))

    @app.exception_handler(Exception)
    async def _unexpected(request: Request, exc: Exception) -> JSONResponse:
        log.exception("unhandled error on %s %s", request.method, request.url.path)
        return error_response(500, "InternalError", "Internal error; see the station's log.")


def _from_store_error(exc: Exception) -> JSONResponse:
    missing = (session_store.SessionNotFound, session_store.SessionFileNotFound)
    api = NotFound if isinstance(exc, missing) else BadRequest
    return error_response(api.status_code, api.__name__, str(exc))

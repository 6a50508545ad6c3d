"""The control token: what guards endpoints that change things (recording, delete, twin).

With `server.token` unset (the default) everything is open, as on a field network where
the pilot's laptop is the only client. With a token set, control endpoints need
`Authorization: Bearer <token>`; WebSockets, which browsers cannot give headers, may pass
`?token=<token>`. Reading (telemetry, video, session downloads) stays open.

    @router.post("/api/recording/start", dependencies=[Depends(require_control_token)])
"""

from __future__ import annotations

import secrets

from starlette.requests import HTTPConnection

from fpv_station.server.errors import Unauthorized


def _presented_token(conn: HTTPConnection) -> str | None:
    header = conn.headers.get("authorization")
    if header:
        scheme, _, value = header.partition(" ")
        if scheme.lower() == "bearer" and value.strip():
            return value.strip()
    return conn.query_params.get("token")


def require_control_token(conn: HTTPConnection) -> None:
    """FastAPI dependency: refuse with 401 unless the configured token is presented."""
    expected = conn.app.state.settings.server.token
    if not expected:
        return
    presented = _presented_token(conn)
    if presented is None:
        raise Unauthorized(
            "This station requires a control token: send 'Authorization: Bearer <token>'."
        )
    if not secrets.compare_digest(presented.encode(), expected.encode()):
        raise Unauthorized("The control token is wrong.")

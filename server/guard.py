"""Who may change things, checked before any route runs (an ASGI middleware).

The pilot's browser visits other websites while it holds the station's page open, and any
host on the field Wi-Fi can reach the Pi. Four checks, token or no token, in every
mode (`--open` too):

- **Host.** DNS rebinding: a page on `evil.example` re-points its name at the Pi, and its
  requests are then same-origin for the browser, with `Host: evil.example`. Every request
  and upgrade must name the station by an IP literal (its own address, however it was
  reached), `localhost`, the machine's own name (`NAME`, `NAME.local`) or a name in
  `server.allowed_hosts`; otherwise 421 (a WebSocket is closed with 1008). A request
  without `Host` (HTTP/1.0, not a browser) passes.

- **Origin.** A browser names the page that makes a request in `Origin`. A request that
  changes something (any method but GET/HEAD/OPTIONS) and every WebSocket upgrade must
  come from the station's own origin (the `Host` it was reached at) or one listed in
  `server.allowed_origins`; otherwise 403 (a WebSocket is closed with 1008 before it is
  accepted). Requests without `Origin` are not from a web page (curl, scripts, the test
  clients): they pass here and meet the control token.
- **Content type.** A request that changes something and has a body must say
  `application/json`: the `text/plain` and form bodies a cross-site page can send without
  asking are refused (415).
- **Body size.** A declared `Content-Length` over `server.max_body_bytes` is refused (413)
  before a byte is read; a chunked body is cut off at the limit the same way.

Replies use the one error shape {"error", "error_msg"} (server.errors). Every HTTP
answer carries `Content-Security-Policy: frame-ancestors 'self'` and `X-Frame-Options:
SAMEORIGIN`: no other site can frame the pilot's page and steer clicks on it.

WebSocket messages are bounded too: each route's frame limit (server/listen.py), and
`loads_message` for their JSON, whose nesting is limited before it is parsed (Python's
parser would end a deep enough document with RecursionError, dropping the socket).
"""

from __future__ import annotations

import contextlib
import json
import logging
import re
import socket
from collections.abc import Awaitable, Callable, MutableMapping
from typing import Any
from urllib.parse import urlsplit

from fpv_station.companion.transports import is_ip_address

Scope = MutableMapping[str, Any]
Message = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[Message]]
Send = Callable[[Message], Awaitable[None]]
ASGIApp = Callable[[Scope, Receive, Send], Awaitable[None]]

_SAFE_METHODS = {"GET", "HEAD", "OPTIONS"}
MAX_JSON_DEPTH = 8  # every message the station takes is a flat object
_DEFAULT_PORTS = {"http": 80, "https": 443, "ws": 80, "wss": 443}


def _origin_key(origin: str) -> tuple[str, int] | None:
    """(host, port) of an Origin value, None for "null" or junk."""
    try:
        parts = urlsplit(origin)
        port = parts.port or _DEFAULT_PORTS.get(parts.scheme)
    except ValueError:
        return None
    if not parts.hostname or port is None:
        return None
    return parts.hostname.lower(), port


_FRAMING = [
    (b"content-security-policy", b"frame-ancestors 'self'"),
    (b"x-frame-options", b"SAMEORIGIN"),
]


def own_names(extra: list[str]) -> set[str]:
    """The names a request may reach the station by, besides IP literals."""
    names = {"localhost", *(n.lower().rstrip(".") for n in extra)}
    with contextlib.suppress(OSError):
        host = socket.gethostname().lower()
        names |= {host, f"{host}.local"}
    return names


def _host_name(host: str) -> str | None:
    """The name or address of a Host header, without its port; None for junk."""
    try:
        name = urlsplit(f"http://{host}").hostname
    except ValueError:
        return None
    return name.rstrip(".") if name else None


def _host_key(host: str, scheme: str) -> tuple[str, int] | None:
    """(host, port) of a Host header as the browser used it."""
    return _origin_key(f"{'https' if scheme in ('https', 'wss') else 'http'}://{host}")


class RequestGuard:
    def __init__(
        self,
        app: ASGIApp,
        allowed_origins: list[str],
        max_body_bytes: int,
        allowed_hosts: list[str] | None = None,
    ) -> None:
        self.app = app
        self.allowed = {k for o in allowed_origins if (k := _origin_key(o)) is not None}
        self.max_body = max_body_bytes
        self.names = own_names([*(allowed_hosts or []), *(h for h, _ in self.allowed)])

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        kind = scope["type"]
        if kind not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        headers = {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope["headers"]}
        if kind == "http":
            send = _with_framing_headers(send)
        if not self._host_ok(headers.get("host")):
            why = (
                f"Host '{headers.get('host', '')[:100]}' is not this station: reach it by its "
                "address or a name in server.allowed_hosts."
            )
            await _refuse(kind, send, 421, "MisdirectedRequest", why)
            return
        changes = kind == "websocket" or scope["method"] not in _SAFE_METHODS
        if changes and not self._origin_ok(headers, scope):
            why = (
                f"Origin '{headers.get('origin', '')[:100]}' may not control this station; "
                "open the station's own page (or add the origin to server.allowed_origins)."
            )
            await _refuse(kind, send, 403, "Forbidden", why)
            return
        if kind == "websocket":
            await self.app(scope, receive, send)
            return
        length = headers.get("content-length")
        if length is not None and (not length.isdigit() or int(length) > self.max_body):
            await _reply(
                send, 413, "PayloadTooLarge", f"Request bodies are at most {self.max_body} bytes."
            )
            return
        ctype = headers.get("content-type", "").split(";")[0].strip().lower()
        has_body = (length is not None and length != "0") or "transfer-encoding" in headers
        if changes and has_body and ctype != "application/json":
            await _reply(
                send,
                415,
                "UnsupportedMediaType",
                f"Send JSON ('Content-Type: application/json'), not '{ctype or 'none'}'.",
            )
            return
        await self._call_with_body_limit(scope, receive, send)

    def _host_ok(self, host: str | None) -> bool:
        if host is None:
            return True  # HTTP/1.0: not a browser
        name = _host_name(host)
        return name is not None and (is_ip_address(name) or name.lower() in self.names)

    def _origin_ok(self, headers: dict[str, str], scope: Scope) -> bool:
        origin = headers.get("origin")
        if origin is None:
            return True  # not a web page: the control token decides
        key = _origin_key(origin)
        if key is None:
            return False
        own = _host_key(headers.get("host", ""), scope.get("scheme", "http"))
        return key == own or key in self.allowed

    async def _call_with_body_limit(self, scope: Scope, receive: Receive, send: Send) -> None:
        """A body without a declared length (chunked) is read here up to the limit and
        handed on whole; the routes' own body parsing would turn an error into a 400."""
        headers = dict(scope["headers"])
        if b"content-length" in headers or b"transfer-encoding" not in headers:
            await self.app(scope, receive, send)
            return
        chunks, size, more = [], 0, True
        while more:
            message = await receive()
            if message["type"] != "http.request":  # the client left
                return
            chunks.append(message.get("body", b""))
            size += len(chunks[-1])
            more = message.get("more_body", False)
            if size > self.max_body:
                await _reply(
                    send,
                    413,
                    "PayloadTooLarge",
                    f"Request bodies are at most {self.max_body} bytes.",
                )
                return
        body, sent = b"".join(chunks), False

        async def replay() -> Message:
            nonlocal sent
            if sent:
                return await receive()  # after the body: wait for the disconnect
            sent = True
            return {"type": "http.request", "body": body, "more_body": False}

        await self.app(scope, replay, send)


def loads_message(text: str, max_depth: int = MAX_JSON_DEPTH) -> Any:
    """A WebSocket message's JSON; ValueError (with the reason) when it is not JSON or
    is nested deeper than `max_depth`, before the parser sees it."""
    depth, in_string, escaped = 0, False, False
    for ch in text:
        if in_string:
            if escaped:
                escaped = False
            elif ch == "\\":
                escaped = True
            elif ch == '"':
                in_string = False
        elif ch == '"':
            in_string = True
        elif ch in "[{":
            depth += 1
            if depth > max_depth:
                raise ValueError(f"JSON nested deeper than {max_depth} levels")
        elif ch in "]}":
            depth -= 1
    return json.loads(text)


async def _refuse(kind: str, send: Send, status: int, name: str, why: str) -> None:
    """An HTTP request gets `status` in the error shape; a WebSocket upgrade is closed
    with 1008 before it is accepted (the client sees 403)."""
    if kind == "websocket":
        await send({"type": "websocket.close", "code": 1008, "reason": why[:120]})
    else:
        await _reply(send, status, name, why)


def _with_framing_headers(send: Send) -> Send:
    async def framed(message: Message) -> None:
        if message["type"] == "http.response.start":
            names = {k.lower() for k, _ in message.get("headers", [])}
            extra = [(k, v) for k, v in _FRAMING if k not in names]
            message = {**message, "headers": [*message.get("headers", []), *extra]}
        await send(message)

    return framed


async def _reply(send: Send, status: int, name: str, message: str) -> None:
    body = json.dumps({"error": name, "error_msg": message}).encode()
    await send(
        {
            "type": "http.response.start",
            "status": status,
            "headers": [
                (b"content-type", b"application/json"),
                (b"content-length", str(len(body)).encode()),
                (b"connection", b"close"),
            ],
        }
    )
    await send({"type": "http.response.body", "body": body})


class RedactTokens(logging.Filter):
    """Keeps `?token=...` out of every log line: uvicorn's access log and its WebSocket
    lines (`"WebSocket /ws/control?token=..." [accepted]`) log the full request target.
    Each string argument is redacted where it is (uvicorn's access formatter unpacks the
    arguments by position), then the message and a traceback's text."""

    _TOKEN = re.compile(r"(token=)[^&\s\"']+", re.IGNORECASE)

    def _redact(self, value: object) -> object:
        return self._TOKEN.sub(r"\1<redacted>", value) if isinstance(value, str) else value

    def filter(self, record: logging.LogRecord) -> bool:
        if isinstance(record.args, tuple):
            record.args = tuple(self._redact(a) for a in record.args)
        elif isinstance(record.args, dict):
            record.args = {k: self._redact(v) for k, v in record.args.items()}
        record.msg = self._redact(record.msg)
        if record.exc_info and not record.exc_text:
            record.exc_text = logging.Formatter().formatException(record.exc_info)
        if record.exc_text:
            record.exc_text = self._TOKEN.sub(r"\1<redacted>", record.exc_text)
        return True


_REDACTED_LOGGERS = ("", "uvicorn", "uvicorn.error", "uvicorn.access")


def redact_tokens_in_logs() -> None:
    """Install `RedactTokens` on uvicorn's loggers and on the handlers of the root and
    uvicorn loggers (a handler's filter sees the records every logger propagates to it).
    Call again after logging is configured anew (uvicorn's Config does)."""
    for name in _REDACTED_LOGGERS:
        logger = logging.getLogger(name)
        for holder in (logger, *logger.handlers):
            if not any(isinstance(f, RedactTokens) for f in holder.filters):
                holder.addFilter(RedactTokens())

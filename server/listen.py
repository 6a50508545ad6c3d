"""The listening socket uvicorn serves on, tuned so that slow viewers do not see old video.

Linux lets a TCP socket queue megabytes of unsent data (send-buffer autotuning up to
`tcp_wmem` max, 4 MB by default): for an MJPEG viewer on a weak link that is seconds
of stale frames in the kernel, out of reach of the server's "skip to the newest frame".
TCP_NOTSENT_LOWAT caps the unsent bytes instead, so the socket stops accepting data
early, uvicorn's flow control makes the stream wait, and the stream then takes the
newest frame. Data in flight is not limited, so throughput on a good link is unchanged.
Accepted connections inherit the option from the listening socket.
"""

from __future__ import annotations

import logging
import socket

import uvicorn

log = logging.getLogger(__name__)

NOTSENT_LOWAT_BYTES = 64 * 1024  # about one 640x480 JPEG
_TCP_NOTSENT_LOWAT = getattr(socket, "TCP_NOTSENT_LOWAT", 25)  # 25 on Linux


def listening_socket(host: str, port: int, backlog: int = 128) -> socket.socket:
    """A bound, listening TCP socket for `host:port` (IPv6 when host has a colon)."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        if family == socket.AF_INET6 and host in ("::", ""):
            sock.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY, 0)
        try:
            sock.setsockopt(socket.IPPROTO_TCP, _TCP_NOTSENT_LOWAT, NOTSENT_LOWAT_BYTES)
        except OSError as exc:  # not Linux/macOS: streams still work, with deeper buffers
            log.info("TCP_NOTSENT_LOWAT unavailable (%s); slow viewers may lag more", exc)
        sock.bind((host, port))
        sock.listen(backlog)
    except OSError:
        sock.close()
        raise
    sock.set_inheritable(True)
    return sock


def uvicorn_server(app, log_level: str = "info") -> uvicorn.Server:
    """The uvicorn server as `fpv-station serve` runs it (tests run the same one).

    No permessage-deflate: browsers ask for it, and it would compress every telemetry
    message once per client, the per-client re-encoding the shared JSON body avoids.
    MJPEG streams never end by themselves: they get 2 s at shutdown, then are cancelled.
    """
    config = uvicorn.Config(
        app,
        log_level=log_level,
        ws_per_message_deflate=False,
        timeout_graceful_shutdown=2,
        lifespan="on",
    )
    return uvicorn.Server(config)

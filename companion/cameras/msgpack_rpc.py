"""A small blocking msgpack-rpc client (the protocol AirSim's rpclib server speaks).

Wire format (msgpack-rpc spec): request `[0, msgid, method, params]`, response
`[1, msgid, error, result]`, notification `[2, method, params]`, over one TCP stream.
One caller at a time (the camera's capture thread); every call has a timeout so that a
hung simulator becomes an error instead of a stuck thread.
"""

from __future__ import annotations

import itertools
import socket
from typing import Any

import msgpack

REQUEST, RESPONSE, NOTIFY = 0, 1, 2


class RpcError(Exception):
    """The server answered with an error; `error` is its payload as sent."""

    def __init__(self, method: str, error: Any) -> None:
        super().__init__(f"{method}: {error}")
        self.error = error


class RpcConnectionError(ConnectionError):
    """The connection failed, closed, timed out or sent something that is not msgpack-rpc."""


class MsgpackRpcClient:
    def __init__(self, host: str, port: int, timeout_s: float = 2.0) -> None:
        self.host, self.port, self.timeout_s = host, port, timeout_s
        self._sock: socket.socket | None = None
        self._unpacker: msgpack.Unpacker | None = None
        self._ids = itertools.count(1)

    def connect(self) -> None:
        self.close()
        try:
            sock = socket.create_connection((self.host, self.port), timeout=self.timeout_s)
        except OSError as exc:
            raise RpcConnectionError(
                f"cannot connect to {self.host}:{self.port}: {exc.strerror or exc}"
            ) from None
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._sock = sock
        # AirSim packs byte vectors as bin, but some builds send them as str; keep any
        # non-UTF-8 str payload recoverable as bytes (surrogateescape).
        self._unpacker = msgpack.Unpacker(
            raw=False, unicode_errors="surrogateescape", max_buffer_size=64 << 20
        )

    @property
    def connected(self) -> bool:
        return self._sock is not None

    def call(self, method: str, *params: Any) -> Any:
        if self._sock is None or self._unpacker is None:
            self.connect()
        assert self._sock is not None and self._unpacker is not None
        msgid = next(self._ids) & 0xFFFFFFFF
        payload = msgpack.packb([REQUEST, msgid, method, list(params)], use_bin_type=True)
        try:
            self._sock.sendall(payload)
            while True:
                for message in self._unpacker:
                    if _is_response(message) and message[1] == msgid:
                        if message[2] is not None:
                            raise RpcError(method, message[2])
                        return message[3]
                    # Notifications and stale responses (of a timed-out call) are skipped.
                chunk = self._sock.recv(1 << 20)
                if not chunk:
                    raise RpcConnectionError(f"{self.host}:{self.port} closed the connection")
                self._unpacker.feed(chunk)
        except TimeoutError:
            self.close()
            raise RpcConnectionError(
                f"{method} got no answer from {self.host}:{self.port} in {self.timeout_s:g} s"
            ) from None
        except OSError as exc:
            self.close()
            raise RpcConnectionError(f"{self.host}:{self.port}: {exc.strerror or exc}") from None
        except (msgpack.ExtraData, msgpack.FormatError, msgpack.StackError, ValueError) as exc:
            self.close()
            raise RpcConnectionError(f"{self.host}:{self.port} sent bad msgpack: {exc}") from None

    def close(self) -> None:
        if self._sock is not None:
            try:
                self._sock.close()
            finally:
                self._sock = None
                self._unpacker = None


def _is_response(message: Any) -> bool:
    return isinstance(message, (list, tuple)) and len(message) == 4 and message[0] == RESPONSE

"""Connection strings and the byte transports behind them (serial, UDP, TCP).

    /dev/serial0:921600        serial port with baud rate (Pi UART to the Pixhawk TELEM2)
    /dev/ttyACM0               serial port, default baud (USB: the rate does not matter)
    udpin:0.0.0.0:14550        listen; hear and answer the first host that speaks (udp: is
                               the same; `link.udpin_lock = false`: whoever sent last)
    udpout:192.168.1.5:14550   send to a fixed peer; only its replies are heard
    tcp:127.0.0.1:5760         TCP client (SITL, mavlink-router, ser2net)
    replay:FILE.tlog[?speed=N] play a telemetry log back, real time unless speed says
    none                       no vehicle link

Transports are blocking-free for the reader (it selects on `fileno()` first) and raise
`ConnectionError` (or `OSError`) when the port or peer goes away; the link reconnects.
"""

from __future__ import annotations

import ipaddress
import os
import select
import socket
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Literal, Protocol
from urllib.parse import parse_qs

DEFAULT_BAUD = 115200
_UDP_MAX = 65535

Kind = Literal["serial", "udpin", "udpout", "tcp", "replay", "none", "sim"]


class ConnectionStringError(ValueError):
    """A --source or --forward string that cannot be understood; says what is expected."""


@dataclass(frozen=True, slots=True)
class ConnSpec:
    kind: Kind
    text: str
    host: str = ""
    port: int = 0
    path: str = ""
    baud: int = DEFAULT_BAUD
    speed: float = 1.0  # replay pace; 0 = as fast as possible


def parse_connection(text: str) -> ConnSpec:
    text = text.strip()
    if text == "none":
        return ConnSpec(kind="none", text=text)
    if text == "sim":
        return ConnSpec(kind="sim", text=text)
    if text.startswith("replay:"):
        rest = text.removeprefix("replay:")
        path, _, query = rest.partition("?")
        speed = 1.0
        if query:
            params = parse_qs(query)
            raw = params.get("speed", ["1"])[0]
            try:
                speed = 0.0 if raw == "max" else float(raw)
            except ValueError:
                raise ConnectionStringError(
                    f"Replay speed '{raw}' in '{text}' is not a number "
                    "(use ?speed=4 or ?speed=max)."
                ) from None
            if speed < 0:
                raise ConnectionStringError(f"Replay speed in '{text}' must be >= 0.")
        if not path:
            raise ConnectionStringError(f"'{text}' names no file: use replay:FILE.tlog.")
        return ConnSpec(kind="replay", text=text, path=path, speed=speed)
    prefixes: tuple[tuple[str, Kind], ...] = (
        ("udpin:", "udpin"),
        ("udp:", "udpin"),
        ("udpout:", "udpout"),
        ("tcp:", "tcp"),
    )
    for prefix, kind in prefixes:
        if text.startswith(prefix):
            host, sep, port = text.removeprefix(prefix).rpartition(":")
            if not sep or not port.isdigit() or not 0 < int(port) < 65536:
                raise ConnectionStringError(
                    f"'{text}' needs HOST:PORT after '{prefix}' "
                    f"(for example {prefix}127.0.0.1:14550)."
                )
            host = host or "0.0.0.0"
            return ConnSpec(kind=kind, text=text, host=host, port=int(port))
    if text.startswith("/") or text.upper().startswith("COM"):
        path, sep, baud = text.rpartition(":")
        if sep and baud.isdigit():
            return ConnSpec(kind="serial", text=text, path=path, baud=int(baud))
        return ConnSpec(kind="serial", text=text, path=text)
    raise ConnectionStringError(
        f"Unknown MAVLink connection '{text}'. Use a serial port (/dev/serial0:921600), "
        "udpin:HOST:PORT, udpout:HOST:PORT, tcp:HOST:PORT, replay:FILE.tlog, sim or none."
    )


class Transport(Protocol):
    def fileno(self) -> int: ...
    def read(self) -> bytes: ...
    def read_queued(self) -> Iterator[bytes]:
        """What is queued now, as reads (a stream's one read already takes all of it;
        UDP's are one datagram each): one wake-up of the reader for a burst."""
        ...

    def write(self, data: bytes) -> None: ...
    def close(self) -> None: ...


@dataclass(slots=True)
class ForeignSenders:
    """Datagrams refused because another address sent them; kept across reconnects."""

    datagrams: int = 0
    last: tuple[str, int] | None = None


class UdpTransport:
    """udpout sends to a fixed peer and hears only it; udpin binds and answers the host
    that spoke first (`lock`) or whoever spoke last (no lock).

    A datagram from any other address is dropped before it is parsed and counted in
    `foreign` (a `ForeignSenders` the owner may keep across reconnects): on a shared
    network anyone can send to our port, and one forged GLOBAL_POSITION_INT would
    otherwise move the vehicle on the map and into the recording. udpout matches the
    peer's address and port exactly (a UDP peer answers from the port it listens on). A
    locked udpin matches the first sender's host and follows its port: a bridge or
    router that restarts comes back from a new ephemeral port on the same host, and must
    not lose the vehicle until the station restarts. Several systems behind one address (autopilot, SiK radio, a GCS through
    mavlink-router) all pass; telling them apart is MAVLink signing's work, not this.

    `confirm_senders` (set when the link signs): a udpin sender becomes the peer (the one
    answered, and the host the lock holds) only when its datagram held a packet signed
    with the key (`adopt_sender`), so that an unsigned datagram sent first cannot take
    the lock, nor one sent later take our answers. Until then the last sender is
    answered. Once locked, another host's datagrams are dropped before they are parsed
    while the peer's host is heard (checking a flood's signatures would cost the link
    thread several times what dropping it does); after `probation_after_s` of its
    silence they are marked `probation` instead: the link lets the lock follow only the
    followed autopilot's signed packets there (the vehicle at a new address, after a
    bridge's reboot), and nothing unsigned from there.
    """

    def __init__(
        self,
        spec: ConnSpec,
        lock: bool = True,
        foreign: ForeignSenders | None = None,
        resolve_name: bool = True,
    ) -> None:
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._sock.setblocking(False)
        self._lock = lock
        self.foreign = foreign if foreign is not None else ForeignSenders()
        self.confirm_senders = False
        self.probation_after_s = 2.0  # the peer's silence after which others are heard
        self.probation = False  # the last datagram came from another host than the peer's
        self._peer_heard = 0.0  # time.monotonic() of the peer's host's last datagram
        self._sender: tuple[str, int] | None = None  # of the last datagram read
        try:
            if spec.kind == "udpin":
                self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                self._sock.bind((spec.host, spec.port))
                self._peer: tuple[str, int] | None = None
            elif resolve_name or is_ip_address(spec.host):
                self._peer = resolve_udp_peer(spec.host, spec.port)
                if ipaddress.ip_address(self._peer[0]).is_loopback:
                    # A peer on this host: nothing off the host needs to reach our port.
                    self._sock.bind(("127.0.0.1", 0))
            else:  # a name the owner resolves off this thread (companion.forward_resolver)
                self._peer = None
        except BaseException:
            self._sock.close()
            raise
        self._fixed_peer = spec.kind == "udpout"

    @property
    def peer(self) -> tuple[str, int] | None:
        """Where replies go (udpin: None until someone spoke)."""
        return self._peer

    def fileno(self) -> int:
        return self._sock.fileno()

    def read(self) -> bytes:
        """One datagram's bytes; b"" when none is queued or it came from a foreign sender."""
        data = self._receive()
        return data or b""

    def read_queued(self, limit: int = 64) -> Iterator[bytes]:
        """Each datagram queued now (at most `limit`), one at a time: an autopilot sends
        its streams in bursts (ATTITUDE, GLOBAL_POSITION_INT and LOCAL_POSITION_NED on
        the same tick), and a burst read at one wake-up is one epoll wait and one state
        publish instead of one each per datagram. The caller handles each datagram
        before the next is read, so `adopt_sender` still names that datagram's sender."""
        for _ in range(limit):
            data = self._receive()
            if data is None:
                return
            if data:
                yield data

    def _receive(self) -> bytes | None:
        """The next datagram's bytes, b"" for one refused (a foreign sender), None when
        nothing is queued."""
        try:
            data, addr = self._sock.recvfrom(_UDP_MAX)
        except (BlockingIOError, ConnectionRefusedError):
            # udpout: an ICMP "port unreachable" for our last send; the peer may come back
            return None
        addr = addr[:2]
        if self._accepts(addr):
            self.probation = False
            self._peer_heard = time.monotonic()
        elif (
            self.confirm_senders
            and not self._fixed_peer
            and time.monotonic() - self._peer_heard > self.probation_after_s
        ):
            # Signing on and the peer silent: another host may be the vehicle at a new
            # address (a DHCP lease, a bridge that rebooted). Its datagram is parsed and
            # signing judges it.
            self.probation = True
        else:
            self.foreign.datagrams += 1
            self.foreign.last = addr
            return b""
        self._sender = addr
        if not self.confirm_senders:
            self.adopt_sender()
        return data

    def set_peer(self, peer: tuple[str, int]) -> None:
        """udpout: the address its peer's name resolves to now (a laptop that joined the
        network late, or came back with another DHCP address)."""
        if self._fixed_peer:
            self._peer = peer

    def adopt_sender(self) -> None:
        """udpin: the last datagram's sender becomes the peer (answered; the lock's host)."""
        if not self._fixed_peer and self._sender is not None:
            self._peer = self._sender

    def _accepts(self, addr: tuple[str, int]) -> bool:
        peer = self._peer
        if self._fixed_peer:
            return addr == peer
        return peer is None or not self._lock or addr[0] == peer[0]

    def write(self, data: bytes) -> None:
        # udpin waiting for a signed packet: answer the last sender meanwhile. A vehicle
        # whose signing clock is behind ours is refused until our signed packets move its
        # clock forward, so it must hear them; this sets no lock.
        target = self._peer if self._peer is not None else self._sender
        if target is None:
            return  # udpin: nobody has spoken yet, so nobody to answer
        try:
            self._sock.sendto(data, target)
        except OSError:
            # UDP: a full buffer, a refused port, an unreachable network (WiFi down) all
            # mean a lost datagram, the protocol's normal loss; never a reason to drop
            # the vehicle link (a forward target's trouble must not cost the vehicle).
            pass

    def close(self) -> None:
        self._sock.close()


def is_ip_address(host: str) -> bool:
    """`host` is an address, not a name: resolving it needs no lookup."""
    try:
        ipaddress.ip_address(host)
    except ValueError:
        return False
    return True


def resolve_udp_peer(host: str, port: int) -> tuple[str, int]:
    """The IPv4 address datagrams from `host:port` come from. Resolved once: a name
    looked up per packet blocks the link thread. 0.0.0.0 means this host (Linux sends
    there over loopback, and the answer comes from 127.0.0.1)."""
    if host == "0.0.0.0":
        return ("127.0.0.1", port)
    info = socket.getaddrinfo(host, port, socket.AF_INET, socket.SOCK_DGRAM)
    return (str(info[0][4][0]), port)


def format_addr(addr: tuple[str, int] | None) -> str | None:
    return None if addr is None else f"{addr[0]}:{addr[1]}"


class TcpTransport:
    def __init__(self, spec: ConnSpec, connect_timeout_s: float = 2.0) -> None:
        self._sock = socket.create_connection((spec.host, spec.port), timeout=connect_timeout_s)
        self._sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._sock.settimeout(1.0)  # bounds a write to a peer that stopped reading

    def fileno(self) -> int:
        return self._sock.fileno()

    def read(self) -> bytes:
        data = self._sock.recv(_UDP_MAX)
        if not data:
            raise ConnectionError("TCP peer closed the connection")
        return data

    def read_queued(self) -> Iterator[bytes]:
        yield self.read()

    def write(self, data: bytes) -> None:
        self._sock.sendall(data)

    def close(self) -> None:
        self._sock.close()


class SerialTransport:
    """pyserial opens and sets up the port (baud, raw mode); reading and writing go to its
    non-blocking descriptor directly, because pyserial's own read() and write() wait in
    select(), which raises ValueError for a descriptor numbered 1024 or more (the station
    raises its file limit for its clients) and would end the link thread."""

    def __init__(self, spec: ConnSpec, write_timeout_s: float = 1.0) -> None:
        import serial  # pyserial; imported here so that tests without ports never need it

        if not Path(spec.path).exists():
            raise FileNotFoundError(f"serial port {spec.path} does not exist")
        self._port = serial.Serial(spec.path, spec.baud, timeout=0)
        self._fd = self._port.fileno()  # opened O_NONBLOCK by pyserial
        self._write_timeout_s = write_timeout_s
        self._writable = select.poll()
        self._writable.register(self._fd, select.POLLOUT)

    def fileno(self) -> int:
        return self._fd

    def read(self) -> bytes:
        try:
            data = os.read(self._fd, _UDP_MAX)
        except BlockingIOError:
            return b""
        if not data:
            # readable but nothing came: the device is gone (unplugged USB)
            raise ConnectionError("serial port returned no data: device gone")
        return data

    def read_queued(self) -> Iterator[bytes]:
        yield self.read()

    def write(self, data: bytes) -> None:
        view = memoryview(data)
        deadline = time.monotonic() + self._write_timeout_s
        while view:
            try:
                view = view[os.write(self._fd, view) :]
            except BlockingIOError:
                pass
            left = deadline - time.monotonic()
            if view and (left <= 0 or not self._writable.poll(left * 1000)):
                # the other end stopped reading (flow control held): reconnect
                raise TimeoutError(f"serial write timed out after {self._write_timeout_s:g} s")

    def close(self) -> None:
        self._port.close()


def open_transport(
    spec: ConnSpec, udpin_lock: bool = True, foreign: ForeignSenders | None = None
) -> Transport:
    if spec.kind in ("udpin", "udpout"):
        return UdpTransport(spec, lock=udpin_lock, foreign=foreign)
    if spec.kind == "tcp":
        return TcpTransport(spec)
    if spec.kind == "serial":
        return SerialTransport(spec)
    raise ConnectionStringError(f"'{spec.text}' is not a byte transport.")

"""Keeps the address of each `--forward udpout:NAME:PORT` target current.

A field team powers the Pi up before the laptop running QGroundControl joins the field
Wi-Fi, and the laptop gets its address from DHCP: a name resolved once at start (as
before) either failed for good ("not forwarding there" until a restart) or kept sending to
an address the laptop no longer has. Names are looked up in a thread of their own, first at
start and then every `interval_s`, because a DNS or mDNS lookup can block for seconds and
neither the event loop (which starts the link) nor the link thread may wait for it.

A failed lookup keeps the last good address: a DNS server that went away must not cut a
forward that works. A target given as an IP address is not looked up at all.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable

from fpv_station.companion.link_health import ForwardTarget
from fpv_station.companion.transports import ConnSpec, UdpTransport, format_addr, resolve_udp_peer

log = logging.getLogger(__name__)

Resolve = Callable[[str, int], tuple[str, int]]


class ForwardResolver:
    """Looks up the names of `targets` (their spec and socket) every `interval_s` and
    points each socket at the address found (`UdpTransport.set_peer`)."""

    def __init__(
        self,
        targets: list[tuple[ConnSpec, UdpTransport]],
        interval_s: float,
        resolve: Resolve = resolve_udp_peer,
    ) -> None:
        self._targets = targets
        self._interval_s = interval_s
        self._resolve = resolve
        self._errors: dict[str, str | None] = {spec.text: None for spec, _ in targets}
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        if self._targets:
            self._thread = threading.Thread(target=self._run, name="forward-resolver", daemon=True)
            self._thread.start()

    def stop(self) -> None:
        self._stop.set()  # a lookup under way ends on its own; the thread is a daemon

    def targets(self) -> tuple[ForwardTarget, ...]:
        return tuple(
            ForwardTarget(spec.text, format_addr(transport.peer), self._errors[spec.text])
            for spec, transport in self._targets
        )

    def resolve_all(self) -> None:
        """One pass over every target (the thread's loop; tests call it directly)."""
        for spec, transport in self._targets:
            try:
                address = self._resolve(spec.host, spec.port)
            except (OSError, UnicodeError) as exc:  # gaierror is an OSError
                if self._errors[spec.text] is None:
                    log.warning("--forward %s: cannot resolve %s: %s", spec.text, spec.host, exc)
                self._errors[spec.text] = f"cannot resolve {spec.host}: {exc}"
                continue
            if self._errors[spec.text] is not None or address != transport.peer:
                log.info("--forward %s: sending to %s", spec.text, format_addr(address))
            self._errors[spec.text] = None
            transport.set_peer(address)

    def _run(self) -> None:
        while not self._stop.is_set():
            self.resolve_all()
            self._stop.wait(self._interval_s)

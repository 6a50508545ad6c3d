"""systemd's notify protocol: READY when the station serves, WATCHDOG while it is healthy.

Under `Type=notify` with `WatchdogSec=` (deploy/fpv-station.service) systemd passes
`NOTIFY_SOCKET` (an AF_UNIX datagram socket; a leading '@' means the abstract namespace)
and `WATCHDOG_USEC`. The watchdog is fed from a coroutine on the event loop and only while
every supervised task is alive (server/tasks.py): a hung loop or a dead task stops the
pings and systemd restarts the station. Outside systemd (no NOTIFY_SOCKET) all of this
is a no-op. The protocol is a few datagrams, so no library (sdnotify, systemd-python) is
worth a dependency; see sd_notify(3).
"""

from __future__ import annotations

import asyncio
import logging
import os
import socket
from collections.abc import Mapping
from dataclasses import dataclass

from fpv_station.server.tasks import TaskSupervisor

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Notifier:
    address: str | bytes  # a path, or bytes starting with NUL for the abstract namespace
    watchdog_s: float | None  # the WatchdogSec systemd gave us; None: no watchdog

    @classmethod
    def from_environ(cls, environ: Mapping[str, str] | None = None) -> Notifier | None:
        """The notifier systemd asked for, or None when not started by systemd."""
        env = os.environ if environ is None else environ
        path = env.get("NOTIFY_SOCKET", "")
        if not path:
            return None
        address: str | bytes = "\0" + path[1:] if path.startswith("@") else path
        watchdog_s = None
        usec = env.get("WATCHDOG_USEC", "")
        pid = env.get("WATCHDOG_PID", "")
        if usec.isdigit() and int(usec) > 0 and (not pid or pid == str(os.getpid())):
            watchdog_s = int(usec) / 1e6
        return cls(address, watchdog_s)

    def send(self, *fields: str) -> bool:
        """One datagram of `KEY=value` lines; False (logged) if systemd cannot be reached."""
        try:
            # Non-blocking: a datagram queue that is full (systemd busy, or a reader that never
            # reads) must not stall the event loop; a lost ping is retried next period.
            flags = socket.SOCK_DGRAM | socket.SOCK_CLOEXEC | socket.SOCK_NONBLOCK
            with socket.socket(socket.AF_UNIX, flags) as s:
                s.sendto("\n".join(fields).encode(), self.address)
            return True
        except OSError as exc:
            log.warning("systemd notify %s failed: %s", fields, exc)
            return False


async def notify_loop(notifier: Notifier, tasks: TaskSupervisor) -> None:
    """READY=1 once, then WATCHDOG=1 every half WatchdogSec while `tasks` are healthy.

    When a supervised task has died the pings stop (with a STATUS line saying which task)
    so that systemd's watchdog restarts the station; a station that cannot recover by
    itself is better restarted than left serving stale telemetry.
    """
    notifier.send("READY=1", "STATUS=serving")
    if notifier.watchdog_s is None:
        return
    period = notifier.watchdog_s / 2  # sd_watchdog_enabled(3) recommends half
    reported = False
    while True:
        await asyncio.sleep(period)
        if tasks.healthy:
            notifier.send("WATCHDOG=1")
        elif not reported:
            failed = ", ".join(f"{k}: {v}" for k, v in tasks.failures.items())
            notifier.send(f"STATUS=unhealthy, watchdog stopped: {failed}")
            log.error("watchdog pings stopped: %s", failed)
            reported = True


def notify_stopping(notifier: Notifier | None) -> None:
    if notifier is not None:
        notifier.send("STOPPING=1")

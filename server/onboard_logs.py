"""The autopilot's own log of each flight, brought into its session.

After a session that the vehicle's disarm ended (`onboard_log.after_disarm`), and when
asked (`POST /api/sessions/{id}/onboard_log`), one `companion.onboard_log.LogDownload`
fetches the flight's log over the link into the session folder. One download at a time:
the link is shared with the flight. When it ends, session.json gets `onboard_log` (file,
bytes, complete, download seconds, the log's span on the session clock as
`analysis.onboard_log` reads it), amended as the trial score is (`read_meta`, then
`write_meta`).
A replay has no vehicle to ask, so it never downloads.
"""

from __future__ import annotations

import asyncio
import datetime as dt
import logging
from pathlib import Path

from fpv_station.companion.link import MavlinkLink
from fpv_station.companion.onboard_log import DownloadStatus, LogDownload, OnboardLogSettings
from fpv_station.companion.recording import layout
from fpv_station.companion.recording.meta import OnboardLog, SessionMeta, read_meta, write_meta
from fpv_station.companion.recording.recorder import Recorder, Spawn
from fpv_station.server.errors import Conflict, Unavailable

log = logging.getLogger(__name__)


class OnboardLogs:
    def __init__(
        self,
        settings: OnboardLogSettings,
        link: MavlinkLink | None,
        recorder: Recorder | None,
        spawn: Spawn,
    ) -> None:
        self.settings = settings
        self.link = link
        self.recorder = recorder
        self._spawn = spawn
        self.current: LogDownload | None = None
        if recorder is not None:
            recorder.session_end_hooks.append(self._on_session_end)

    @property
    def available(self) -> bool:
        """A live vehicle link to ask (not a replay, not none)."""
        return self.link is not None and self.link.spec.kind != "replay"

    def status(self) -> DownloadStatus:
        """The current or last download's status ("idle" before the first)."""
        return self.current.status.current() if self.current is not None else DownloadStatus()

    def _on_session_end(self, meta: SessionMeta, folder: Path) -> None:
        if not self.settings.after_disarm or not self.available:
            return
        if meta.stop_reason != "disarmed" or meta.arming is None:
            return
        try:
            self.request(meta.id, folder)
        except (Conflict, Unavailable) as exc:
            log.warning("onboard log of %s not fetched: %s", meta.id, exc.message)

    def request(
        self,
        session_id: str,
        folder: Path,
        log_id: int | None = None,
        flight_end_utc: float | None = None,
    ) -> DownloadStatus:
        """Start fetching the log of session `session_id` into `folder`: `log_id`, or
        the log that covers a flight ending at `flight_end_utc` (None: the newest)."""
        if not self.available or self.link is None:
            raise Unavailable("No vehicle link to fetch an onboard log from (none, or a replay).")
        if self.current is not None and self.current.running:
            busy = self.current.status.current().session
            raise Conflict(f"The onboard log of session '{busy}' is being downloaded; wait.")
        target = self.link.autopilot()
        if target is None:
            raise Unavailable("No autopilot heard on the link yet.")
        download = LogDownload(
            self.link,
            target,
            folder,
            self.settings,
            session=session_id,
            log_id=log_id,
            flight_end_utc=flight_end_utc,
        )
        self.current = download
        download.start()
        self._spawn(f"onboard-log-{session_id}", self._watch(download, folder))
        log.info("fetching the onboard log of session %s", session_id)
        return download.status.current()

    async def _watch(self, download: LogDownload, folder: Path) -> None:
        """Wait for the download's end (its status, published by its thread), then
        record it in session.json off the loop."""
        seen = download.status.get()
        while seen is not None and not seen.value.done:
            seen = await download.status.wait_newer(seen.version, timeout=5.0)
        if seen is not None:
            await asyncio.to_thread(_store, folder, seen.value)

    def cancel(self) -> None:
        if self.current is not None:
            self.current.cancel()

    def close(self) -> None:
        """The station stops: end a download under way (its thread writes no more)."""
        if self.current is not None:
            self.current.cancel()
            self.current.join(5.0)


def _store(folder: Path, status: DownloadStatus) -> None:
    """Blocking: amend session.json with what the download brought, and where the log
    lies on the session clock (`analysis.onboard_log`, which also records its
    `onboard_alignment`)."""
    from fpv_station.analysis.onboard_log import write_alignment  # numpy, pyulog: only now

    span: dict = {}
    if status.file is not None:
        try:
            aligned = write_alignment(folder)
        except Exception as exc:  # a cut-off log, a session without telemetry: still stored
            log.warning("onboard log of %s: not on the session clock: %s", folder.name, exc)
            aligned = None
        if aligned is not None and aligned.start_s is not None and aligned.end_s is not None:
            span = {"t_s": [aligned.start_s, aligned.end_s], "clock": aligned.clock}
    entry = OnboardLog(
        state=status.state,
        file=status.file,
        bytes=status.received_bytes,
        complete=status.state == "complete",
        download_s=status.download_s,
        log_id=status.log_id,
        message=status.message,
        fetched_utc=dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
        **span,
    )
    path = folder / layout.SESSION_JSON
    try:
        meta = read_meta(path)
        write_meta(path, meta.model_copy(update={"onboard_log": entry}))
    except (OSError, ValueError) as exc:
        log.error("cannot store the onboard log in %s: %s", path, exc)
    log.info("onboard log of %s: %s", folder.name, status.message)

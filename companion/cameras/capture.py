"""A camera: one capture thread that turns its source's frames into shared JPEG Frames.

The thread owns the source (open, read, close, reopen with back-off); each frame is
encoded at most once (MJPEG passthrough: never) and published into `frames`, a
`Latest[Frame]` that every viewer and the recorder read. When the source cannot open,
fails, or stalls, the camera publishes a NO SIGNAL frame (`signal=False`) with its name
and the reason, about once a second, until the source delivers again. Nothing a source
does can stop the thread or touch another camera.
"""

from __future__ import annotations

import collections
import contextlib
import logging
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass

import cv2

from fpv_station.companion.cameras.jpeg import JpegEncoder
from fpv_station.companion.cameras.nosignal import render_no_signal
from fpv_station.companion.cameras.source import Captured, FrameSource, SourceConfig, SourceError
from fpv_station.companion.cameras.spec import CameraSpec
from fpv_station.companion.latest import Latest
from fpv_station.companion.video_frame import Frame

log = logging.getLogger(__name__)

FPS_WINDOW_S = 2.0
NO_SIGNAL_REFRESH_S = 1.0


@dataclass(frozen=True, slots=True)
class CameraStats:
    name: str
    source: str  # the spec as configured
    description: str
    signal: bool
    reason: str | None  # why there is no signal
    width: int
    height: int
    configured_fps: float
    delivered_fps: float  # good frames per second over the last FPS_WINDOW_S
    frames: int  # good frames captured
    frames_dropped: int  # frame slots missed (late, corrupt) while the source delivered
    encodes: int
    encode_ms: float  # JPEG encode time, moving average over about 20 frames
    passthrough_frames: int  # frames whose JPEG came from the device as is
    clients: int  # MJPEG viewers now
    last_frame_time: float | None  # Unix time of the newest good frame's capture
    last_frame_age_s: float | None
    opens: int  # successful source opens (1 + recoveries)
    tilt_up_deg: float | None  # optical axis above the nose (settings or the source's own)
    vfov_deg: float | None  # vertical field of view; None when unknown


class Camera:
    """One named camera; `frames` is the contract (`station.cameras[name].frames`)."""

    def __init__(
        self,
        spec: CameraSpec,
        config: SourceConfig,
        source: FrameSource | None,
        retry_min_s: float = 0.5,
        retry_max_s: float = 5.0,
    ) -> None:
        self.name = config.name
        self.spec = spec
        self.config = config
        self.source = source
        self.frames: Latest[Frame] = Latest()
        self.clients = 0  # changed only on the event loop (MJPEG route)
        self.encoder = JpegEncoder(config.jpeg_quality)
        self._retry_min_s, self._retry_max_s = retry_min_s, retry_max_s
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._publish_lock = threading.Lock()
        self._seq = 0
        self._signal = False
        self._reason: str | None = "starting"
        self._width, self._height = config.width, config.height
        self._frames = self._dropped = self._passthrough = self._opens = 0
        self._last_good_mono: float | None = None
        self._last_good_wall: float | None = None
        self._recent = collections.deque[float](maxlen=max(8, int(config.fps * FPS_WINDOW_S) + 2))
        self._no_signal_cache: tuple[str, bytes] | None = None
        self._no_signal_mono = 0.0

    # -- life cycle ------------------------------------------------------------------
    def start(self) -> None:
        if self.source is None:
            self._publish_no_signal("no camera configured (spec 'none')")
            return
        for target, role in ((self._capture_loop, "capture"), (self._watchdog_loop, "watchdog")):
            thread = threading.Thread(target=target, name=f"camera-{self.name}-{role}", daemon=True)
            self._threads.append(thread)
            thread.start()

    def request_stop(self) -> None:
        """Ask the threads to end without waiting (to stop several cameras at once)."""
        self._stop.set()

    def stop(self, timeout_s: float = 3.0) -> None:
        self._stop.set()
        for thread in self._threads:
            thread.join(timeout_s)
            if thread.is_alive():
                log.warning("camera %s: thread %s did not stop in time", self.name, thread.name)
        self._threads.clear()
        self.frames.close()

    @property
    def fps(self) -> float:
        """The configured frame rate (the recorder sizes its buffers by it)."""
        return self.config.fps

    @contextlib.contextmanager
    def watching(self) -> Iterator[None]:
        """Count a viewer for as long as the block runs (event loop only)."""
        self.clients += 1
        try:
            yield
        finally:
            self.clients -= 1

    # -- the capture thread ----------------------------------------------------------
    def _capture_loop(self) -> None:
        assert self.source is not None
        backoff_s = self._retry_min_s
        while not self._stop.is_set():
            frames_before = self._frames
            reason = _one_line(self._run_source(self.source))
            if self._stop.is_set():
                break
            if self._frames > frames_before:
                backoff_s = self._retry_min_s  # it worked for a while: retry soon
            log.warning("camera %s: no signal (%s); retry in %.1f s", self.name, reason, backoff_s)
            deadline = time.monotonic() + backoff_s
            while (left := deadline - time.monotonic()) > 0:
                self._publish_no_signal(f"{reason} - retry in {left:.0f} s")
                if self._stop.wait(min(NO_SIGNAL_REFRESH_S, left)):
                    return
            self._publish_no_signal(f"{reason} - retrying")
            backoff_s = min(backoff_s * 2.0, self._retry_max_s)

    def _run_source(self, source: FrameSource) -> str:
        """Open the source and publish its frames until it fails; returns why it stopped."""
        try:
            source.open()
        except SourceError as exc:
            return str(exc)
        except Exception as exc:  # a source bug must not kill the thread
            log.exception("camera %s: source open crashed", self.name)
            return f"{type(exc).__name__}: {exc}"
        self._opens += 1
        period_s = 1.0 / self.config.fps
        next_t = time.monotonic()
        try:
            while not self._stop.is_set():
                if source.paced:
                    now = time.monotonic()
                    if next_t > now:
                        if self._stop.wait(next_t - now):
                            break
                    elif now - next_t > period_s:  # late by whole frames: skip, do not burst
                        self._dropped += int((now - next_t) / period_s)
                        next_t = now
                    next_t += period_s
                captured = source.read()
                if captured is None:
                    self._dropped += 1
                    continue
                self._publish_captured(captured, period_s, source)
        except SourceError as exc:
            return str(exc)
        except Exception as exc:
            log.exception("camera %s: source read crashed", self.name)
            return f"{type(exc).__name__}: {exc}"
        finally:
            try:
                source.close()
            except Exception:
                log.exception("camera %s: source close failed", self.name)
        return "stopped"

    def _publish_captured(self, captured: Captured, period_s: float, source: FrameSource) -> None:
        t_mono, t_wall = time.monotonic(), time.time()  # capture time, before the encode
        if captured.jpeg is not None:
            jpeg, width, height = captured.jpeg, captured.width, captured.height
            self._passthrough += 1
        else:
            image = captured.image
            assert image is not None
            height, width = image.shape[:2]
            want = (self.config.width, self.config.height)
            if source.resize_to_config and (width, height) != want:
                image = cv2.resize(image, want, interpolation=cv2.INTER_AREA)
                width, height = want
            jpeg = self.encoder.encode(image)
        last = self._last_good_mono
        if not source.paced and last is not None and t_mono - last > 1.5 * period_s:
            self._dropped += round((t_mono - last) / period_s) - 1  # device skipped frames
        with self._publish_lock:
            self._seq += 1
            self.frames.publish(Frame(self.name, self._seq, jpeg, width, height, t_mono, t_wall))
            self._frames += 1
            self._last_good_mono, self._last_good_wall = t_mono, t_wall
            self._recent.append(t_mono)
            self._width, self._height = width, height
            self._signal, self._reason = True, None

    # -- NO SIGNAL ---------------------------------------------------------------------
    def _publish_no_signal(self, reason: str) -> None:
        cached = self._no_signal_cache
        if cached is None or cached[0] != reason:
            image = render_no_signal(self.name, reason, self.config.width, self.config.height)
            ok, buf = cv2.imencode(".jpg", image, [int(cv2.IMWRITE_JPEG_QUALITY), 70])
            cached = (reason, buf.tobytes())
            self._no_signal_cache = cached
        with self._publish_lock:
            self._seq += 1
            frame = Frame(
                self.name,
                self._seq,
                cached[1],
                self.config.width,
                self.config.height,
                time.monotonic(),
                time.time(),
                signal=False,
            )
            self.frames.publish(frame)
            self._signal, self._reason = False, reason
            self._no_signal_mono = time.monotonic()

    def _watchdog_loop(self) -> None:
        """Show NO SIGNAL when an open source stops delivering (its read is stuck)."""
        # A slow camera (fps < 1.5) must not look stalled between two of its own frames.
        stall_s = max(self.config.stall_s, 3.0 / self.config.fps)
        # It sleeps until the newest frame would be `stall_s` old, not a fixed tick: while
        # frames flow it wakes once per `stall_s` (every wake-up of a thread costs the Pi,
        # docs/PERFORMANCE.md), and a stall is seen when it begins, not up to a tick later.
        wait_s = stall_s
        while not self._stop.wait(wait_s):
            last = self._last_good_mono
            now = time.monotonic()
            if last is None or now - last < stall_s:
                wait_s = stall_s if last is None else last + stall_s - now
                continue
            if self._signal or now - self._no_signal_mono >= NO_SIGNAL_REFRESH_S:
                if self._signal or (self._reason or "").startswith("stalled"):
                    self._publish_no_signal(f"stalled: no frame for {now - last:.0f} s")
            # Stalled: look again when the NO SIGNAL frame is due for its refresh.
            wait_s = max(self._no_signal_mono + NO_SIGNAL_REFRESH_S - time.monotonic(), 0.01)

    # -- figures -------------------------------------------------------------------------
    def delivered_fps(self) -> float:
        now = time.monotonic()
        with self._publish_lock:
            recent = [t for t in self._recent if now - t <= FPS_WINDOW_S]
        if len(recent) < 2 or recent[-1] == recent[0]:
            return 0.0
        return (len(recent) - 1) / (recent[-1] - recent[0])

    def stats(self) -> CameraStats:
        last_mono, last_wall = self._last_good_mono, self._last_good_wall
        return CameraStats(
            name=self.name,
            source=self.spec.raw,
            description=self.source.describe() if self.source is not None else "none",
            signal=self._signal,
            reason=self._reason,
            width=self._width,
            height=self._height,
            configured_fps=self.config.fps,
            delivered_fps=round(self.delivered_fps(), 2),
            frames=self._frames,
            frames_dropped=self._dropped,
            encodes=self.encoder.encodes,
            encode_ms=round(self.encoder.recent_encode_ms, 3),
            passthrough_frames=self._passthrough,
            clients=self.clients,
            last_frame_time=last_wall,
            last_frame_age_s=None if last_mono is None else time.monotonic() - last_mono,
            opens=self._opens,
            tilt_up_deg=self.config.tilt_up_deg,
            vfov_deg=self.config.vfov_deg,
        )


def _one_line(reason: str, limit: int = 160) -> str:
    line = reason.strip().splitlines()[0] if reason.strip() else "unknown failure"
    return line if len(line) <= limit else line[: limit - 3] + "..."

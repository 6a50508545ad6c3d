"""The twin running in real time: the sim paced in its own thread, its MAVLink vehicle, and
its cameras rendered on demand from the latest true pose.

    twin = Twin(mavlink="udpout:127.0.0.1:14550")
    twin.start()
    frame = twin.render("front")   # (480, 640, 3) BGR uint8, any thread
    pose = twin.pose()             # true pose (ENU world), any thread
    twin.stop()

`step_for(seconds)` runs the same loop faster than real time without a thread (tests).
"""

from __future__ import annotations

import logging
import tempfile
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from fpv_station.companion.cameras.source import Optics
from fpv_station.companion.latest import Latest
from fpv_station.core.scene import Scene, load_scene
from fpv_station.twin.flight_log import FlightLogger
from fpv_station.twin.log_server import LogServer
from fpv_station.twin.settings import TwinSettings
from fpv_station.twin.sim import Pose, Sim, SimConfig
from fpv_station.twin.vehicle import MavlinkVehicle

if TYPE_CHECKING:  # imported on first use: its textures take a while to build
    from fpv_station.twin.render import Renderer

log = logging.getLogger(__name__)


class Twin:
    def __init__(
        self,
        scene: Scene | None = None,
        config: SimConfig | None = None,
        mavlink: str | None = None,
        rates_hz: dict[str, float] | None = None,
        realtime_factor: float = 1.0,
        tick_hz: float = 100.0,
        render_options: dict[str, Any] | None = None,
        signing_key: bytes | None = None,
        flight_log: bool = True,
        flight_log_dir: Path | None = None,
    ) -> None:
        if realtime_factor <= 0:
            raise ValueError("realtime_factor must be > 0")
        self.scene = scene or load_scene()
        self.sim = Sim(self.scene, config)
        self.mavlink_url = mavlink
        self.rates_hz = rates_hz
        self.signing_key = signing_key  # MAVLink 2 signing of its vehicle (None: off)
        self.realtime_factor = realtime_factor
        self.tick_s = 1.0 / tick_hz
        self.vehicle: MavlinkVehicle | None = None
        self.lock = threading.RLock()  # guards `sim` between the loop and callers
        self.poses: Latest[Pose] = Latest(self.sim.pose())
        self.slips = 0  # ticks where the loop fell behind and dropped sim time
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._render_options = render_options or {}
        self._renderer: Renderer | None = None
        self._render_lock = threading.Lock()
        self.error: str | None = None
        # Its own flight log (a ULog per armed period, `twin.flight_log`), on its "SD
        # card": `flight_log_dir`, or a private folder removed when the twin stops.
        self._log_tmp: tempfile.TemporaryDirectory[str] | None = None
        self.flight_log: FlightLogger | None = None
        if flight_log:
            if flight_log_dir is None:
                self._log_tmp = tempfile.TemporaryDirectory(prefix="fpv-twin-logs-")
                flight_log_dir = Path(self._log_tmp.name)
            self.flight_log = FlightLogger(flight_log_dir)
            self.sim.on_physics_step = self.flight_log.on_step

    # ---- lifecycle ----
    def _open_vehicle(self) -> None:
        if self.mavlink_url and self.vehicle is None:
            self.vehicle = MavlinkVehicle(
                self.mavlink_url, self.rates_hz, signing_key=self.signing_key
            )
            if self.flight_log is not None:
                self.vehicle.logs = LogServer(self.vehicle.mav, self.flight_log)

    def start(self) -> None:
        if self._thread is not None:
            raise RuntimeError("The twin is already running.")
        self._open_vehicle()
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="twin", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
            self._thread = None
        if self.vehicle is not None:
            if self.vehicle.logs is not None:
                self.vehicle.logs.close()
            self.vehicle.close()
            self.vehicle = None
        if self.flight_log is not None:
            self.flight_log.close()
        if self._log_tmp is not None:
            self._log_tmp.cleanup()
        self.poses.close()

    def __enter__(self) -> Twin:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def _run(self) -> None:
        try:
            t0 = time.monotonic()
            sim_t0 = self.sim.t_s
            next_tick = t0
            while not self._stop.is_set():
                now = time.monotonic()
                target = sim_t0 + (now - t0) * self.realtime_factor
                with self.lock:
                    behind = int((target - self.sim.t_s) / self.sim.dt_s)
                    limit = int(0.25 / self.sim.dt_s)  # never try to catch up more than 0.25 s
                    if behind > limit:
                        self.slips += 1
                        sim_t0 -= (behind - limit) * self.sim.dt_s
                        behind = limit
                    if behind > 0:
                        self.sim.step(behind)
                    if self.vehicle is not None:
                        self.vehicle.poll(self.sim, self.sim.t_s)
                    self.poses.publish(self.sim.pose())
                next_tick += self.tick_s
                delay = next_tick - time.monotonic()
                if delay < -1.0:
                    next_tick = time.monotonic()
                self._stop.wait(max(delay, 0.0))
        except Exception as exc:  # a dead twin must say so, not vanish
            self.error = f"{type(exc).__name__}: {exc}"
            log.exception("twin loop died")

    def step_for(self, seconds: float) -> None:
        """Advance sim time by `seconds` as fast as possible, polling MAVLink every tick.

        Telemetry goes out at sim-time rates, so a long call bursts many packets at once:
        a peer reading UDP slower than that loses the excess in its socket buffer.
        """
        self._open_vehicle()
        per_tick = max(1, int(round(self.tick_s / self.sim.dt_s)))
        for _ in range(int(round(seconds / (per_tick * self.sim.dt_s)))):
            with self.lock:
                self.sim.step(per_tick)
                if self.vehicle is not None:
                    self.vehicle.poll(self.sim, self.sim.t_s)
        self.poses.publish(self.sim.pose())

    # ---- state and commands (any thread) ----
    def pose(self) -> Pose:
        """The latest true pose: position/velocity ENU (m, m/s) in the scene's world frame."""
        return self.poses.current()

    def local_position_enu_m(self) -> np.ndarray:
        return self.pose().pos_enu_m

    def true_geodetic(self) -> tuple[float, float, float]:
        """The true position as (lat_deg, lon_deg, alt_m MSL), georeferenced at the scene's
        home: compare recorded GPS tracks with it through the same geodesy."""
        from fpv_station.core.geodesy import enu_to_geodetic

        home = self.scene.home
        lat, lon, alt = enu_to_geodetic(
            self.pose().pos_enu_m, home.lat_deg, home.lon_deg, home.alt_m
        )
        return float(lat), float(lon), float(alt)

    def set_sticks(self, roll: float, pitch: float, yaw: float, throttle: float) -> None:
        with self.lock:
            self.sim.set_sticks(roll, pitch, yaw, throttle)

    def arm(self, arm: bool = True) -> tuple[bool, str]:
        with self.lock:
            return self.sim.arm(arm)

    def set_mode(self, name: str) -> tuple[bool, str]:
        with self.lock:
            return self.sim.set_mode(name)

    def reset(self) -> None:
        """Back on the start pad, disarmed, battery full (after a crash, for another try).

        The vehicle is carried back, not rebooted: its clock runs on. Rewinding the sim
        clock to 0 left the real-time loop and the telemetry schedule (both in sim time)
        waiting until the clock caught up again: silent for as long as the twin had run."""
        with self.lock:
            self.sim.reset_vehicles(np.ones(self.sim.n, bool))
            self.poses.publish(self.sim.pose())

    # ---- cameras ----
    def render(self, camera: str) -> np.ndarray:
        """(480, 640, 3) BGR uint8 of camera "front" or "bottom" at the latest true pose."""
        renderer = self._get_renderer()
        return renderer.render(camera, self.pose())

    def optics(self, camera: str) -> Optics | None:
        """The tilt and vertical field of view `render(camera)` draws with (None: no such
        camera)."""
        from fpv_station.twin.render import Renderer

        options = self._render_options
        model = Renderer.camera_models(options.get("front"), options.get("bottom")).get(camera)
        if model is None:
            return None
        return Optics(tilt_up_deg=model.tilt_up_deg, vfov_deg=model.vfov_deg)

    def _get_renderer(self) -> Renderer:
        with self._render_lock:
            if self._renderer is None:
                from fpv_station.twin.render import Renderer  # textures are built on first use only

                self._renderer = Renderer(self.scene, **self._render_options)
            return self._renderer


def twin_from_settings(
    ts: TwinSettings, mavlink: str | None, signing_key: bytes | None = None
) -> Twin:
    """Build a Twin from its settings section (`[twin]`); `signing_key` signs its MAVLink
    (the link's key, `link.signing_key_file`)."""
    from fpv_station.twin.control import ControlGains
    from fpv_station.twin.dynamics import Wind
    from fpv_station.twin.sensors import SensorParams

    wind = Wind(
        mean_enu_mps=(ts.wind_east_mps, ts.wind_north_mps, 0.0),
        gust_std_mps=ts.gust_std_mps,
        turbulence_std_mps=ts.turbulence_std_mps,
    )
    config = SimConfig(
        physics_hz=ts.physics_hz,
        seed=ts.seed,
        wind=wind if not wind.calm else None,  # calm settings: the scene's [wind]
        sensors=SensorParams(enabled=ts.sensor_noise, gps_rate_hz=ts.gps_rate_hz),
        gains=ControlGains(max_vel_xy_mps=ts.max_vel_xy_mps),
    )
    return Twin(
        load_scene(ts.scene),
        config,
        mavlink=mavlink,
        rates_hz=dict(ts.rates_hz),
        realtime_factor=ts.realtime_factor,
        render_options={"fpv_noise": ts.fpv_noise, "seed": ts.seed},
        signing_key=signing_key,
        flight_log=ts.flight_log,
        flight_log_dir=ts.flight_log_dir,
    )

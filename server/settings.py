"""The station's one settings object: defaults, then a TOML file, then the environment,
then the command line, each overriding the one before.

Environment variables are `FPV_<SECTION>__<KEY>` (for example `FPV_SERVER__PORT=9000`,
`FPV_LINK__SOURCE=udpin:0.0.0.0:14550`); values are parsed as TOML literals when they
can be (numbers, booleans, lists), as plain strings otherwise.
"""

from __future__ import annotations

import os
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from companion.cameras.spec import parse_spec


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid", validate_assignment=True)


class ServerSettings(_Section):
    host: str = "0.0.0.0"
    port: int = Field(8000, ge=1, le=65535)
    # When set, control endpoints (recording, delete, twin control) need
    # `Authorization: Bearer <token>`; reading stays open, as on a field network.
    token: str | None = None
    # "token": `fpv-station serve` with no token set makes one on first start, keeps it in
    # `token_file` and prints the URL that carries it (as Jupyter does). "open": no
    # control token at all (only for a network where nobody else is).
    control: Literal["token", "open"] = "token"
    token_file: Path | None = None  # None: $XDG_CONFIG_HOME/fpv-station/token
    # Browser origins besides the station's own that may change things (scheme://host:port).
    allowed_origins: list[str] = Field(default_factory=list)
    # Request bodies: larger ones are refused (413) before they are read. Every body the
    # API takes is a small JSON document.
    max_body_bytes: int = Field(64 * 1024, ge=1024, le=64 * 1024 * 1024)


class LinkSettings(_Section):
    # serial (/dev/serial0:921600, /dev/ttyACM0), udpin:/udpout:/tcp: strings,
    # replay:FILE.tlog[?speed=N], or "sim" for the embedded digital twin.
    source: str = "sim"
    sysid: int | None = Field(None, ge=1, le=255)  # pin the autopilot; None = auto-detect
    forward: list[str] = Field(default_factory=list)  # raw MAVLink copies (udpout:HOST:PORT)
    link_lost_s: float = Field(2.0, gt=0)
    heartbeat_hz: float = Field(1.0, gt=0)
    reconnect_s: float = Field(1.0, gt=0)
    # Our own identity on the link. Not QGroundControl's or Mission Planner's 255/190 (nor
    # MAVProxy's 255): with --forward both talk to one vehicle, and a shared identity
    # sends one's command acknowledgements and sequence numbers to the other.
    gcs_sysid: int = Field(254, ge=1, le=255)
    gcs_compid: int = Field(190, ge=1, le=255)  # MAV_COMP_ID_MISSIONPLANNER: a GCS
    # What the station asks the autopilot for (SET_MESSAGE_INTERVAL, or REQUEST_DATA_STREAM
    # on older firmware); 0 leaves a message at the autopilot's own rate.
    message_rates_hz: dict[str, float] = Field(
        default_factory=lambda: {
            "ATTITUDE": 50.0,
            "GLOBAL_POSITION_INT": 25.0,
            "LOCAL_POSITION_NED": 25.0,
            "VFR_HUD": 10.0,
            "GPS_RAW_INT": 5.0,
            "RC_CHANNELS": 10.0,
            "SERVO_OUTPUT_RAW": 10.0,
            "SYS_STATUS": 2.0,
            "BATTERY_STATUS": 1.0,
        }
    )
    request_streams: bool = True  # False: listen only (another GCS already asks)


class RecordingSettings(_Section):
    """Synchronized flight recording (companion.recording); format in docs/SESSION_FORMAT.md."""

    sessions_dir: Path = Path("./sessions")
    rate_hz: float = Field(30.0, ge=1, le=100)  # telemetry.csv rows per second
    auto_record_on_arm: bool = True
    post_disarm_tail_s: float = Field(5.0, ge=0, le=600)
    min_free_mb: float = Field(200.0, ge=0)  # stop cleanly under this much free disk
    row_queue: int = Field(2000, ge=10)  # bounded writer buffers (items)
    frame_queue: int = Field(90, ge=2)  # per camera
    packet_queue: int = Field(20000, ge=100)
    flush_interval_s: float = Field(0.5, gt=0, le=1.0)  # at most 1 s: kill -9 keeps all but it


class CameraConfig(_Section):
    # A camera spec (see companion/cameras/spec.py): v4l2:/dev/video0, v4l2:0, file:X.mp4,
    # folder:DIR, sim:front, airsim:HOST:PORT/CAMERA, none. None = sim:<name> when
    # link.source is "sim", else none. Spec options (?width=..&fps=..) override the rest.
    spec: str | None = None
    width: int = Field(640, ge=16, le=8192)
    height: int = Field(480, ge=16, le=8192)
    fps: float = Field(30.0, gt=0, le=240)
    jpeg_quality: int = Field(80, ge=1, le=100)

    @field_validator("spec")
    @classmethod
    def _spec_is_usable(cls, value: str | None) -> str | None:
        if value is not None:
            parse_spec(value)  # CameraSpecError (a ValueError) says what is wrong
        return value


class CameraSettings(_Section):
    front: CameraConfig = Field(default_factory=CameraConfig)
    bottom: CameraConfig = Field(default_factory=CameraConfig)
    stall_s: float = Field(2.0, gt=0)  # no frame for this long = NO SIGNAL (stalled)
    retry_min_s: float = Field(0.5, gt=0)  # reopen back-off, doubling up to retry_max_s
    retry_max_s: float = Field(5.0, gt=0)


class ViserSettings(_Section):
    """The 3D trajectory panel (a viser server on its own port)."""

    enabled: bool = True
    host: str | None = None  # None = the same address as the web server
    port: int = Field(8080, ge=0, le=65535)  # 0 = any free port (tests)
    update_hz: float = Field(15.0, ge=1.0, le=60.0)  # scene refresh cap
    chunk_segments: int = Field(50, ge=2, le=1000)  # trail segments per scene handle
    gap_s: float = Field(1.0, gt=0)  # a fix older than this breaks the trail
    max_points: int = Field(200_000, ge=100)  # oldest chunks are dropped beyond this
    color_by: Literal["height", "speed"] = "height"
    height_range_m: tuple[float, float] = (0.0, 10.0)
    speed_range_mps: tuple[float, float] = (0.0, 5.0)
    bottom_hfov_deg: float = Field(90.0, gt=1, lt=179)  # bottom camera's footprint
    bottom_vfov_deg: float = Field(70.0, gt=1, lt=179)
    field_file: Path | None = (
        None  # a twin scene TOML to draw; None = the twin's scene with --source sim
    )
    # The replay panel's own viser server: None = port + 1 (any free port when port is 0).
    replay_port: int | None = Field(None, ge=0, le=65535)

    @property
    def replay_port_resolved(self) -> int:
        if self.replay_port is not None:
            return self.replay_port
        return 0 if self.port == 0 else min(self.port + 1, 65535)


class TwinSettings(_Section):
    """The embedded digital twin (`--source sim` and `fpv-station sim`)."""

    scene: Path | None = None  # scene TOML; None = the built-in field of the paper
    seed: int = 0
    physics_hz: float = Field(250.0, ge=250.0, le=2000.0)
    realtime_factor: float = Field(1.0, gt=0, le=100.0)
    wind_east_mps: float = 0.0
    wind_north_mps: float = 0.0
    gust_std_mps: float = Field(0.0, ge=0)
    sensor_noise: bool = True
    gps_rate_hz: float = Field(5.0, ge=1.0, le=20.0)
    max_vel_xy_mps: float = Field(5.0, gt=0, le=20.0)
    rates_hz: dict[str, float] = Field(default_factory=dict)  # MAVLink stream rates by name
    fpv_noise: bool = False  # analog-FPV look on the rendered cameras (rate: cameras.*.fps)

    @field_validator("scene")
    @classmethod
    def _scene_loads(cls, value: Path | None) -> Path | None:
        if value is not None:
            from core.scene import load_scene

            load_scene(value)  # SceneError (a ValueError) says which file and key
        return value


class Settings(_Section):
    server: ServerSettings = Field(default_factory=ServerSettings)
    link: LinkSettings = Field(default_factory=LinkSettings)
    recording: RecordingSettings = Field(default_factory=RecordingSettings)
    cameras: CameraSettings = Field(default_factory=CameraSettings)
    viser: ViserSettings = Field(default_factory=ViserSettings)
    twin: TwinSettings = Field(default_factory=TwinSettings)


class SettingsError(ValueError):
    """A settings file, variable or flag that cannot be used; the message says which."""


ENV_PREFIX = "FPV_"


def load_settings(
    config_file: Path | None = None,
    overrides: Mapping[str, Any] | None = None,
    environ: Mapping[str, str] | None = None,
) -> Settings:
    """Build the settings: defaults < TOML file < environment < `overrides`.

    `overrides` maps dotted keys (`"server.port"`) to values, as the CLI gives them;
    None values are skipped so that absent flags do not override anything.
    """
    data: dict[str, Any] = {}
    if config_file is not None:
        try:
            data = tomllib.loads(Path(config_file).read_text())
        except FileNotFoundError:
            raise SettingsError(f"Config file '{config_file}' does not exist.") from None
        except tomllib.TOMLDecodeError as exc:
            raise SettingsError(f"Config file '{config_file}' is not valid TOML: {exc}") from None
    env = os.environ if environ is None else environ
    for name, raw in env.items():
        if name.startswith(ENV_PREFIX) and "__" in name:
            keys = name[len(ENV_PREFIX) :].lower().split("__")
            _set_dotted(data, keys, _parse_env_value(raw))
    for dotted, value in (overrides or {}).items():
        if value is not None:
            _set_dotted(data, dotted.split("."), value)
    try:
        return Settings.model_validate(data)
    except ValidationError as exc:
        problems = "; ".join(
            f"'{'.'.join(str(p) for p in err['loc'])}': {err['msg']}" for err in exc.errors()
        )
        raise SettingsError(f"Invalid settings: {problems}") from None


def _set_dotted(data: dict[str, Any], keys: list[str], value: Any) -> None:
    node = data
    for key in keys[:-1]:
        node = node.setdefault(key, {})
        if not isinstance(node, dict):
            raise SettingsError(f"Setting '{'.'.join(keys)}' collides with a plain value.")
    node[keys[-1]] = value


def _parse_env_value(raw: str) -> Any:
    try:
        return tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        return raw

"""The station's one settings object: defaults, then a TOML file, then the environment,
then the command line, each overriding the one before.

Each part declares its own section next to its code (`companion.link_settings`,
`companion.recording.settings`, `companion.cameras.settings`, `twin.settings`); the
server's own sections are here, and `Settings` composes them all.

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

from pydantic import Field, ValidationError

from fpv_station.companion.cameras.settings import CameraSettings
from fpv_station.companion.link_settings import LinkSettings
from fpv_station.companion.onboard_log import OnboardLogSettings
from fpv_station.companion.recording.settings import RecordingSettings
from fpv_station.core.settings_section import Section
from fpv_station.twin.settings import TwinSettings


class ServerSettings(Section):
    """The web server: where it listens, who may control the station, client limits."""

    host: str = Field("0.0.0.0", description="Address to listen on (0.0.0.0: every interface).")
    port: int = Field(8000, ge=1, le=65535, description="HTTP port of the pages and the API.")
    token: str | None = Field(
        None,
        description="The control token. When set, control endpoints (recording, delete, "
        "twin control) need `Authorization: Bearer <token>`; reading stays open, as on a "
        'field network. Unset with control = "token": made on first start and kept in '
        "token_file.",
    )
    control: Literal["token", "open"] = Field(
        "token",
        description='"token": `fpv-station serve` with no token set makes one on first '
        "start, keeps it in token_file and prints the URL that carries it (as Jupyter "
        'does). "open": no control token at all (only for a network where nobody else is).',
    )
    token_file: Path | None = Field(
        None,
        description="Where a generated token is kept; None: $XDG_CONFIG_HOME/fpv-station/token.",
    )
    allowed_origins: list[str] = Field(
        default_factory=list,
        description="Browser origins besides the station's own that may change things "
        "(scheme://host:port).",
    )
    allowed_hosts: list[str] = Field(
        default_factory=list,
        description="Names the station may be reached by besides IP literals, localhost and "
        "the machine's own name (NAME, NAME.local): any other Host is refused (DNS "
        "rebinding, server/guard.py).",
    )
    max_body_bytes: int = Field(
        8 * 1024,
        ge=1024,
        le=64 * 1024 * 1024,
        description="Larger request bodies are refused (413) before they are read; every "
        "body the API takes is a small JSON document.",
    )
    max_ws_clients: int = Field(
        200,
        ge=1,
        le=100_000,
        description="Concurrent WebSocket clients (server/client_limits.py): beyond this an "
        "upgrade is refused with 503. Each holds a file descriptor; the caps are lowered at "
        "start so that fd_reserve descriptors always remain for the recorder and the link, "
        "whatever the process's RLIMIT_NOFILE. The control socket has 8 places of its own.",
    )
    telemetry_rate_hz: float = Field(
        50.0,
        ge=1,
        le=1000,
        description="Telemetry messages a second for a client that does not ask "
        "(`?max_rate=`): the pages and the goggles. 50 draws the horizon as often as "
        "ATTITUDE comes; a small Pi takes 25 (the commented lines of deploy/config.toml).",
    )
    max_video_clients: int = Field(
        40,
        ge=1,
        le=10_000,
        description="MJPEG streams and `/ws/video` pages together (a page takes one place "
        "for its cameras); beyond this a stream is refused with 503.",
    )
    max_3d_viewers: int = Field(
        20,
        ge=1,
        le=10_000,
        description="Viewers of the 3D panels, both viser servers together, under the same "
        "descriptor budget.",
    )
    fd_reserve: int = Field(
        128,
        ge=32,
        le=100_000,
        description="File descriptors always kept free of clients, for the recorder, the "
        "link and the cameras.",
    )
    malloc_trim_s: float = Field(
        60.0,
        ge=0,
        le=86_400,
        description="Seconds between handing the heap's free pages back to the system "
        "(glibc's malloc_trim, server/memory_trim.py); 0 never does. Keeps a long-running "
        "station's resident memory from creeping up with buffers freed by its threads.",
    )


class ViserSettings(Section):
    """The 3D trajectory panels: viser servers on loopback ports, reached by browsers
    through the web server's /3d/live and /3d/replay (server/trajectory3d/gate.py)."""

    enabled: bool = Field(True, description="Run the 3D panels (they start on the first visit).")
    port: int = Field(
        8080, ge=0, le=65535, description="The live panel's port on 127.0.0.1; 0: any free port."
    )
    update_hz: float = Field(15.0, ge=1.0, le=60.0, description="The most scene updates a second.")
    chunk_segments: int = Field(
        50, ge=2, le=1000, description="Trail segments per scene handle (older chunks stay put)."
    )
    gap_s: float = Field(
        1.0, gt=0, description="A fix older than this (s) breaks the trail: drawn as a gap."
    )
    max_points: int = Field(
        200_000, ge=100, description="Trail points kept; the oldest chunks are dropped beyond."
    )
    trail_min_step_m: float = Field(
        0.05,
        ge=0,
        le=5,
        description="A new trail point only once the vehicle is this far (m) from the "
        "trail's last point: a parked vehicle (its jitter included) adds none, so the "
        "trail's memory grows with the distance flown, not with the station's uptime. "
        "Under the distance a moving vehicle covers in 1 / update_hz s; 0 keeps every "
        "sample.",
    )
    color_by: Literal["height", "speed"] = Field(
        "height", description="What the trail's colour shows."
    )
    height_range_m: tuple[float, float] = Field(
        (0.0, 10.0), description="Heights (m) at the two ends of the colour ramp."
    )
    speed_range_mps: tuple[float, float] = Field(
        (0.0, 5.0), description="Speeds (m/s) at the two ends of the colour ramp."
    )
    bottom_hfov_deg: float = Field(
        90.0,
        gt=1,
        lt=179,
        description="The bottom camera's horizontal field of view, for its footprint.",
    )
    bottom_vfov_deg: float = Field(
        70.0,
        gt=1,
        lt=179,
        description="The bottom camera's vertical field of view, for its footprint.",
    )
    field_file: Path | None = Field(
        None,
        description="A twin scene TOML to draw as the field (real flights on a known "
        "field); None: the twin's scene with --source sim, else no field.",
    )
    replay_port: int | None = Field(
        None,
        ge=0,
        le=65535,
        description="The replay panel's own viser port; None: port + 1 (any free port when "
        "port is 0).",
    )

    @property
    def replay_port_resolved(self) -> int:
        if self.replay_port is not None:
            return self.replay_port
        return 0 if self.port == 0 else min(self.port + 1, 65535)


class Settings(Section):
    """Every setting of the station; `fpv-station config --dump` prints them."""

    server: ServerSettings = Field(default_factory=ServerSettings, description="The web server.")
    link: LinkSettings = Field(default_factory=LinkSettings, description="The vehicle link.")
    recording: RecordingSettings = Field(
        default_factory=RecordingSettings, description="Flight recording."
    )
    cameras: CameraSettings = Field(default_factory=CameraSettings, description="The cameras.")
    viser: ViserSettings = Field(
        default_factory=ViserSettings, description="The 3D trajectory panels."
    )
    twin: TwinSettings = Field(default_factory=TwinSettings, description="The digital twin.")
    onboard_log: OnboardLogSettings = Field(
        default_factory=OnboardLogSettings, description="The autopilot's own flight log."
    )


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

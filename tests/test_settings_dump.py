"""Settings are documented once, in the code: every field carries a description, and
`fpv-station config --dump` prints the effective settings as TOML that loads back into
the same settings."""

import os
import subprocess
import sys
import tomllib
from pathlib import Path

from pydantic import BaseModel

from fpv_station.server.settings import Settings, load_settings

ROOT = Path(__file__).resolve().parents[1]


def _fields(model: type[BaseModel], prefix: str = ""):
    for name, info in model.model_fields.items():
        yield prefix + name, info
        if isinstance(info.annotation, type) and issubclass(info.annotation, BaseModel):
            yield from _fields(info.annotation, f"{prefix}{name}.")


def test_every_setting_has_a_description():
    names = [name for name, _ in _fields(Settings)]
    assert "cameras.front.spec" in names and "link.message_rates_hz" in names  # the walk
    missing = [name for name, info in _fields(Settings) if not (info.description or "").strip()]
    assert not missing, f"settings without Field(description=...): {missing}"


def test_dump_loads_back_into_the_effective_settings(tmp_path):
    cfg = tmp_path / "station.toml"
    cfg.write_text(
        '[server]\nport = 9100\nallowed_hosts = ["fpv.local", "pïlot \\"q\\" 😀 \\u007f"]\n'
        "[link]\nmessage_rates_hz = { ATTITUDE = 20.0, SYS_STATUS = 0.5 }\n"
        '[cameras.front]\nspec = "v4l2:/dev/video0?fps=15&width=320"\n'
        "[viser]\nheight_range_m = [1.5, 12.0]\n"
    )
    env = {"FPV_LINK__LINK_LOST_S": "3.5", "FPV_SERVER__TOKEN": "secret-token-value"}
    flags = ["--config", str(cfg), "--source", "udpin:0.0.0.0:14551", "--no-3d"]
    out = subprocess.run(
        [sys.executable, "-m", "fpv_station.server", "config", "--dump", *flags],
        cwd=ROOT,
        env={k: v for k, v in os.environ.items() if not k.startswith("FPV_")} | env,
        capture_output=True,
        text=True,
        timeout=60,
        check=True,
    ).stdout

    effective = load_settings(
        cfg, {"link.source": "udpin:0.0.0.0:14551", "viser.enabled": False}, environ=env
    )
    assert effective.link.link_lost_s == 3.5 and effective.server.port == 9100
    loaded = Settings.model_validate(tomllib.loads(out))
    # The token is the one value a dump never shows; everything else comes back equal.
    assert "secret-token-value" not in out and "token = (set; not shown)" in out
    assert loaded.server.token is None
    loaded.server.token = effective.server.token
    assert loaded == effective
    # Each key is preceded by its description, and a changed one by its default.
    assert "# No heartbeat for this long (s): LINK LOST.\n# default: 2.0\nlink_lost_s = 3.5" in out


def test_config_without_dump_says_what_it_does():
    p = subprocess.run(
        [sys.executable, "-m", "fpv_station.server", "config"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert p.returncode == 2 and "--dump" in p.stderr

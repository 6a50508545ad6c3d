import httpx
import pytest

from fpv_station.server.app import create_app
from fpv_station.server.settings import SettingsError, load_settings
from tests.helpers import run_uvicorn


def test_settings_layers(tmp_path):
    cfg = tmp_path / "s.toml"
    cfg.write_text('[server]\nport = 9001\nhost = "127.0.0.1"\n[link]\nsysid = 3\n')
    s = load_settings(cfg, {"server.port": 9002}, environ={"FPV_LINK__SYSID": "7"})
    assert s.server.port == 9002  # CLI beats file
    assert s.server.host == "127.0.0.1"  # file beats default
    assert s.link.sysid == 7  # environment beats file


def test_settings_errors_are_clear(tmp_path):
    with pytest.raises(SettingsError, match="server.port"):
        load_settings(None, {"server.port": 70000}, environ={})
    with pytest.raises(SettingsError, match="does not exist"):
        load_settings(tmp_path / "missing.toml", environ={})


def test_health_and_openapi_on_real_server():
    app = create_app(load_settings(environ={}, overrides={"link.source": "none"}))
    with run_uvicorn(app) as base:
        r = httpx.get(f"{base}/api/health")
        assert r.status_code == 200 and r.json()["ok"] is True
        spec = httpx.get(f"{base}/openapi.json", timeout=60).json()  # built on first ask
        assert "/api/health" in spec["paths"]
        missing = httpx.get(f"{base}/api/does-not-exist")
        assert missing.status_code == 404 and missing.json()["error"] == "HTTPError"

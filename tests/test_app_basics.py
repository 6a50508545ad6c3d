import pytest

from fpv_station.server.settings import SettingsError, load_settings


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

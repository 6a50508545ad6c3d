"""No token in any log line: the whole log of a station whose pilot page flew the twin
with the control token (server/guard.py: RedactTokens, server/cli.py)."""

from __future__ import annotations

import httpx
from playwright.sync_api import expect
from websockets.sync.client import connect

from tests.helpers import wait_until
from tests.station_process import serve_station


def test_no_token_in_any_log_line_of_a_run_whose_pilot_page_connected(tmp_path, browser):
    """uvicorn logs each WebSocket's full target (`"WebSocket /ws/control?token=..."
    [accepted]`) and each request's; the CLI printed the URL that carries the token. A
    real pilot page takes the printed token, opens the control socket with it and arms
    the twin; a script sends it in a query too. Then the whole log is read."""
    config = tmp_path / "config"
    log_path = tmp_path / "server.log"
    args = ["--source", "sim", "--front", "none", "--bottom", "none", "--no-3d"]
    args += ["--sessions-dir", str(tmp_path / "sessions")]
    env = {"XDG_CONFIG_HOME": str(config), "FPV_RECORDING__MIN_FREE_MB": "0"}
    with serve_station(args, env, log_path=log_path) as station:
        token = (config / "fpv-station" / "token").read_text().strip()
        assert len(token) >= 32
        page = browser.new_page()
        page.goto(f"{station.base}/?token={token}")
        page.locator("#ctl-toggle").click()
        page.locator("#ctl-arm").click()
        expect(page.locator("#control-widget")).to_contain_text("arm", timeout=30_000)
        assert wait_until(lambda: "/ws/control?token=" in log_path.read_text(), 30)
        ws = station.base.replace("http", "ws")
        with connect(f"{ws}/ws/telemetry?token={token}", open_timeout=10) as client:
            client.recv(timeout=10)
        r = httpx.post(f"{station.base}/api/recording/stop?token={token}", timeout=10)
        assert r.status_code == 200, r.text
        assert httpx.get(f"{station.base}/api/status?token=x{token}", timeout=10).is_success
        page.close()
    log = log_path.read_text()
    assert token not in log
    # The lines are there, redacted: the page's control socket, the script's requests.
    assert '"WebSocket /ws/control?token=<redacted>" [accepted]' in log, log[-3000:]
    assert "/api/recording/stop?token=<redacted>" in log
    assert "/ws/telemetry?token=<redacted>" in log

"""The pilot page in real headless chromium against a real server and test vehicle."""

from playwright.sync_api import expect

from fpv_station.server.app import create_app
from fpv_station.server.settings import load_settings
from tests.helpers import run_uvicorn
from tests.mav_vehicle import MavVehicle


def test_page_shows_live_values_and_link_lost(browser, tmp_path):
    with MavVehicle("udp") as vehicle:
        settings = load_settings(
            environ={},
            overrides={
                "link.source": vehicle.station_source,
                "link.link_lost_s": 1.0,
                # Arming starts a recording: keep it out of the working directory.
                "recording.sessions_dir": str(tmp_path / "sessions"),
                "viser.port": 0,
            },
        )
        with run_uvicorn(create_app(settings)) as base:
            page = browser.new_page()
            page.goto(base + "/")
            for el in ("#front-view", "#bottom-view", "#toolbar", "#panel-3d"):
                expect(page.locator(el)).to_have_count(1)
            expect(page.locator("#panel-3d")).to_be_hidden()
            expect(page.locator("#v-mode")).to_have_text("POSCTL", timeout=30_000)
            expect(page.locator("#link-banner")).to_be_hidden()
            expect(page.locator("#v-armed")).to_have_text("disarmed")

            vehicle.arm()
            vehicle.alt_m += 4.2
            vehicle.vx_mps, vehicle.vy_mps = 3.0, 4.0
            vehicle.vz_mps = -1.5  # NED: climbing
            expect(page.locator("#v-armed")).to_have_text("ARMED", timeout=30_000)
            expect(page.locator("#v-rel-alt")).to_have_text("4.2", timeout=30_000)
            expect(page.locator("#v-ground-speed")).to_have_text("5.0", timeout=30_000)
            expect(page.locator("#v-climb")).to_have_text("1.5", timeout=30_000)
            expect(page.locator("#v-rel-alt-ref")).to_have_text("from arming")
            expect(page.locator("#v-gps")).to_have_text("3D, 12 sats")

            vehicle.silent = True
            expect(page.locator("#link-banner")).to_be_visible(timeout=30_000)
            expect(page.locator("#link-banner")).to_contain_text("LINK LOST")

            vehicle.silent = False
            expect(page.locator("#link-banner")).to_be_hidden(timeout=30_000)

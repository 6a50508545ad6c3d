"""The pilot page's steps of a place hold only while the vehicle is there, in headless
Chromium on a real station flying the twin: task 2's "Passed obstacle 1" lights past the
obstacle and goes out when the vehicle flies back before it, and "Landed" lights at a
touch-and-go and goes out when the vehicle climbs again, lighting for the real landing.
(The hold step counts only while the height is held: tests/test_score_pages.py.)"""

from __future__ import annotations

import threading

import pytest
from playwright.sync_api import expect

from fpv_station.twin.pilot import Leg, Pilot, fly_twin
from tests.twin_flights import task_page_on_the_twin

CRUISE_M = 4.5  # above the field's 3 m obstacles
LEGS = [
    Leg("arm"),  # 0
    Leg("hold", alt_m=0.0, seconds=1.5),  # 1
    Leg("climb", alt_m=CRUISE_M),  # 2
    Leg("goto", (-4.0, 0.0), CRUISE_M),  # 3: past obstacle 1 (x = -7, 1 m wide)
    Leg("goto", (-12.0, 0.0), CRUISE_M),  # 4: back before it
    Leg("hold", alt_m=CRUISE_M, seconds=2.0),  # 5
    Leg("hold", alt_m=0.2, seconds=7.0),  # 6: down to the grass, still armed
    Leg("climb", alt_m=2.0),  # 7
    Leg("hold", alt_m=2.0, seconds=3.0),  # 8: up again
    Leg("land"),  # 9
]


@pytest.mark.timeout(300)
def test_passed_and_landed_hold_only_while_there(tmp_path, browser):
    with task_page_on_the_twin(browser, tmp_path, 2) as (app, _, page):
        steps = page.locator("#task-steps li")
        passed = steps.filter(has_text="Passed obstacle 1")
        landed = steps.filter(has_text="Landed")
        expect(passed).to_have_count(1)
        # Brisker than the scripted pilot's defaults, well within the vehicle's limits
        # (5 m/s across, 1.5 m/s down): the places and the heights are what count here.
        pilot = Pilot(list(LEGS), cruise_mps=2.5, descent_mps=1.0)
        flyer = threading.Thread(target=fly_twin, args=(app.state.station.twin, pilot, 150.0))
        flyer.start()
        seen: dict[int, set[tuple[bool, bool]]] = {}
        try:
            while flyer.is_alive():
                leg = pilot.leg
                lit = (
                    passed.get_attribute("class") == "done",
                    landed.get_attribute("class") == "done",
                )
                seen.setdefault(leg, set()).add(lit)
                page.wait_for_timeout(200)
        finally:
            flyer.join(160)
        assert pilot.done, pilot.log

        def was(leg: int, k: int) -> set[bool]:
            return {lit[k] for lit in seen.get(leg, set())}

        assert True in was(4, 0), seen  # passed obstacle 1 on the way out ...
        assert was(5, 0) == {False}, seen  # ... and back before it: not passed
        assert True in was(6, 1), seen  # the touch-and-go lit "Landed" ...
        assert was(8, 1) == {False}, seen  # ... and climbing again put it out
        expect(landed).to_have_class("done", timeout=20_000)  # the real landing

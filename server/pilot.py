"""The one pilot at the sticks of the digital twin: their newest sticks and the dead-man
rule. The station holds it while a pilot is connected (`Station.pilot`); the control
route (`server.routes.control`) fills it and sends from it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

DEADMAN_S = 0.5  # no sticks for this long = sticks centred
Sticks = tuple[float, float, float, float]  # roll, pitch, yaw in [-1, 1], throttle in [0, 1]
CENTRED: Sticks = (0.0, 0.0, 0.0, 0.5)


@dataclass
class Pilot:
    """The newest sticks of one connection and when (monotonic) they arrived."""

    sticks: Sticks = CENTRED
    at: float = -math.inf

    def current(self, now: float) -> Sticks:
        return self.sticks if now - self.at <= DEADMAN_S else CENTRED

"""`--source sim`: the digital twin inside the station, reached over a real loopback socket.

The twin listens on an ephemeral UDP port (`udpin:127.0.0.1:0`, so there is no port race)
and the station's ordinary `MavlinkLink` connects to it with `udpout:`, exactly as it
would to a vehicle: the link's first GCS heartbeat tells the twin where to send its
telemetry. With `link.signing_key_file` both ends sign with that key, as a vehicle set up
for signing would. `open_twin_link` returns both; the station keeps them (`station.twin` is what the
sim cameras render from).
"""

from __future__ import annotations

import contextlib
import logging

from fpv_station.companion.link import MavlinkLink
from fpv_station.server.settings import Settings
from fpv_station.twin.runner import Twin, twin_from_settings

log = logging.getLogger(__name__)


def open_twin_link(
    settings: Settings, stack: contextlib.AsyncExitStack
) -> tuple[Twin, MavlinkLink]:
    """Start the twin and the link to it; both stop with `stack`, the link first."""
    twin = twin_from_settings(
        settings.twin, "udpin:127.0.0.1:0", signing_key=settings.link.signing_key()
    )
    twin.start()
    stack.callback(twin.stop)
    if twin.vehicle is None:
        raise RuntimeError("the twin opened no MAVLink endpoint")
    port = twin.vehicle.sock.getsockname()[1]
    link = MavlinkLink(settings.link, source=f"udpout:127.0.0.1:{port}")
    link.start()
    stack.callback(link.stop)
    log.info("digital twin '%s' on udp 127.0.0.1:%d", twin.scene.name, port)
    return twin, link

"""Every connection counted (server/client_limits.py, server/listen.py): one descriptor
budget for the main server's connections and the 3D panels' viewers, with the recorder's
reserve kept."""

from __future__ import annotations

import threading

from server.client_limits import BASELINE_FDS, CONTROL_CLIENTS, HTTP_ROOM, ClientLimits


def test_every_kind_of_client_fits_under_the_descriptor_limit_with_the_reserve_kept():
    limits = ClientLimits.fitted(200, 40, reserve=128, nofile=256, max_3d=300)
    held = limits.connections.limit + limits.viewers3d.limit
    assert held <= 256 - BASELINE_FDS - 128
    streaming = limits.websocket.limit + limits.video.limit + CONTROL_CLIENTS
    assert streaming + HTTP_ROOM <= limits.connections.limit
    assert min(limits.websocket.limit, limits.video.limit, limits.viewers3d.limit) >= 1
    # A roomy limit keeps the configured caps.
    roomy = ClientLimits.fitted(200, 40, reserve=128, nofile=65536, max_3d=20)
    assert (roomy.websocket.limit, roomy.video.limit, roomy.viewers3d.limit) == (200, 40, 20)


def test_a_cap_counts_places_taken_from_many_threads():
    """viser accepts its viewers on its own threads: the count must not lose one."""
    cap = ClientLimits.fitted(200, 40, reserve=128, nofile=65536, max_3d=50).viewers3d
    taken = []

    def crowd() -> None:
        for _ in range(1000):
            if cap.try_take():
                taken.append(1)
                cap.give_back()

    threads = [threading.Thread(target=crowd) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert cap.active == 0 and len(taken) + cap.refused == 8000
    assert all(cap.try_take() for _ in range(50)) and not cap.try_take()
    assert cap.active == 50 and cap.refused >= 1

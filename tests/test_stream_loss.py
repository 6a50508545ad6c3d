"""Loss per sender from sequence numbers (pure)."""

from fpv_station.companion.stream_loss import MAX_STREAMS, StreamLossCounter


def figures(counter, autopilot=(1, 1)):
    return {(s.sysid, s.compid): s for s in counter.report(autopilot)}


def test_gaps_across_the_wrap_repeats_as_duplicates_and_roles():
    c = StreamLossCounter()
    for seq in (250, 251, 254, 255, 2, 3):  # 2 lost before 254, 2 lost across the wrap
        c.on_packet(1, 1, seq)
    for seq in (7, 7, 8, 8, 9, 9):  # a SiK radio: two messages under one number
        c.on_packet(51, 68, seq)
    c.note_gcs(255, 190)
    c.on_packet(255, 190, 0)
    c.on_packet(42, 1, 0)
    f = figures(c)
    ap = f[(1, 1)]
    assert (ap.role, ap.packets, ap.lost, ap.duplicates) == ("autopilot", 6, 4, 0)
    assert ap.loss_ratio == 0.4
    radio = f[(51, 68)]
    assert (radio.role, radio.lost, radio.duplicates, radio.loss_ratio) == ("radio", 0, 3, 0.0)
    assert f[(255, 190)].role == "gcs" and f[(42, 1)].role == "other"
    assert [s.packets for s in c.report(None)] == [6, 6, 1, 1]  # most packets first


def test_a_new_connection_starts_new_sequences_and_senders_are_bounded():
    c = StreamLossCounter()
    c.on_packet(1, 1, 100)
    c.restart()
    c.on_packet(1, 1, 0)  # a rebooted autopilot, a new TCP connection: no 156 lost
    assert figures(c)[(1, 1)].lost == 0
    for sysid in range(2, MAX_STREAMS + 11):  # MAX_STREAMS + 10 senders with (1, 1)
        c.on_packet(sysid, 1, 0)
    assert len(c.report(None)) == MAX_STREAMS and c.untracked == 10

"""Cutting byte streams into packets: garbage, bad checksums, unknown ids, resync."""

import random

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.mav_framer import MavFramer

ENC = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)


def packets(n):
    out = []
    for i in range(n):
        ENC.seq = i % 256
        out.append(bytes(ENC.attitude_encode(i, 0.1, 0.2, 0.3, 0, 0, 0).pack(ENC)))
    return out


def test_bad_crc_and_unknown_id_are_counted_and_skipped():
    good = packets(2)
    bad = bytearray(good[0])
    bad[-1] ^= 0xFF  # checksum no longer holds
    unknown = bytearray(good[1])
    unknown[7:10] = (60000).to_bytes(3, "little")  # msgid our dialect lacks
    f = MavFramer()
    msgs = f.feed(bytes(bad) + good[1] + bytes(unknown) + b"hello" + good[0])
    types = [m.get_type() for m in msgs]
    assert types == ["ATTITUDE", "UNKNOWN_60000", "ATTITUDE"]
    assert f.counters.bad_crc >= 1 and f.counters.unknown_ids == 1
    assert f.counters.garbage_bytes >= 5


def test_false_start_marker_in_garbage_does_not_swallow_a_packet():
    good = packets(1)[0]
    # 0xFD, length 200: a false frame that would eat the real packet behind it.
    junk = bytes([0xFD, 200, 0, 0, 0, 0, 0, 0, 0, 0])
    f = MavFramer()
    msgs = f.feed(junk + good + b"\x00" * 250)
    assert [m.get_type() for m in msgs] == ["ATTITUDE"]


def test_random_garbage_interleaved_byte_by_byte():
    rng = random.Random(7)
    good = packets(300)
    stream = bytearray()
    for p in good:
        stream += bytes(rng.randrange(256) for _ in range(rng.randrange(0, 40)))
        stream += p
    stream += b"\x00" * 300  # flush a false frame started by trailing junk
    f = MavFramer()
    got = []
    i = 0
    while i < len(stream):  # odd chunk sizes: packets split across reads
        n = rng.randrange(1, 64)
        got += f.feed(bytes(stream[i : i + n]))
        i += n
    seqs = [m.get_seq() for m in got if m.get_type() == "ATTITUDE"]
    assert seqs == [i % 256 for i in range(300)]
    assert f.counters.garbage_bytes > 0


def test_mavlink1_packets():
    ENC.seq = 3
    p = bytes(ENC.heartbeat_encode(2, 12, 0, 0, 3).pack(ENC, force_mavlink1=True))
    assert p[0] == 0xFE
    (m,) = MavFramer().feed(p)
    assert m.get_type() == "HEARTBEAT" and m.get_seq() == 3

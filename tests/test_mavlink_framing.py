"""Cutting byte streams into packets (garbage, bad checksums, unknown ids, resync) and the
.tlog records built on the same header rules (MAVLink 1 and 2 mixed, signed packets)."""

import random

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from fpv_station.core.mavlink.framing import MavFramer, frame_length, message_id
from fpv_station.core.mavlink.tlog_records import TlogReader, encode_record, write_record

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


def test_datagram_by_datagram_as_the_stream_in_one_piece():
    """One whole frame per feed (a UDP datagram) is decoded as it is; a bad one, an
    unknown id, one hiding a real packet inside, a cut one: as the stream in one piece."""
    good = packets(3)
    bad = bytearray(good[0])
    bad[-1] ^= 0xFF
    unknown = bytearray(good[1])
    unknown[7:10] = (60000).to_bytes(3, "little")
    # An "unknown id" frame whose payload holds a real packet: junk, not a packet.
    inner = packets(1)[0]
    hiding = bytearray([0xFD, len(inner) + 2, 0, 0, 0, 1, 1]) + (60001).to_bytes(3, "little")
    hiding += b"\x00" + inner + b"\x00" + b"\x00\x00"
    signed_flag = bytearray(good[2])
    signed_flag[2] = 0x02  # an incompat flag the protocol does not know: no frame start
    datagrams = [
        good[0],
        bytes(bad),
        good[1],
        bytes(unknown),
        bytes(hiding),
        good[2],
        bytes(signed_flag),
        good[0][:7],  # cut: the rest comes in the next datagram
        good[0][7:],
        good[1],
        ENC.heartbeat_encode(2, 12, 0, 0, 4, 3).pack(ENC, force_mavlink1=True),  # MAVLink 1
    ]
    one_piece, by_datagram = MavFramer(), MavFramer()
    whole = [
        (m.get_type(), m.get_seq(), bytes(m.get_msgbuf()))
        for m in one_piece.feed(b"".join(datagrams))
    ]
    split = [
        (m.get_type(), m.get_seq(), bytes(m.get_msgbuf()))
        for d in datagrams
        for m in by_datagram.feed(d)
    ]
    assert split == whole
    assert [t for t, _, _ in split].count("ATTITUDE") == 6  # inner is the one hidden
    assert "UNKNOWN_60000" in [t for t, _, _ in split]
    assert "UNKNOWN_60001" not in [t for t, _, _ in split]
    assert split[-1][0] == "HEARTBEAT"
    assert by_datagram.counters == one_piece.counters
    assert by_datagram.counters.bad_crc >= 2 and by_datagram.counters.unknown_ids == 1
    assert by_datagram.pending == 0


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


def signed_packet(seq):
    enc = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    enc.signing.secret_key = bytes(range(32))
    enc.signing.sign_outgoing = True
    enc.signing.link_id = 1
    enc.signing.timestamp = 1
    enc.seq = seq
    return bytes(enc.gps_raw_int_encode(0, 3, 1, 2, 3, 0, 0, 0, 0, 9).pack(enc))


def test_header_fields_of_v1_v2_and_signed_packets():
    v1 = bytes(ENC.heartbeat_encode(2, 12, 0, 0, 3).pack(ENC, force_mavlink1=True))
    v2 = packets(1)[0]
    signed = signed_packet(0)
    assert signed[2] & 0x01 and len(signed) == signed[1] + 12 + 13  # signed indeed
    assert [frame_length(p) for p in (v1, v2, signed)] == [len(v1), len(v2), len(signed)]
    assert [message_id(p) for p in (v1, v2, signed)] == [
        mavlink.MAVLINK_MSG_ID_HEARTBEAT,
        mavlink.MAVLINK_MSG_ID_ATTITUDE,
        mavlink.MAVLINK_MSG_ID_GPS_RAW_INT,
    ]
    assert frame_length(bytes([0xFD, 9, 0x02])) == -1  # unknown incompat flag: no frame
    assert frame_length(bytes([0x00, 9, 0])) == -1  # no start marker
    assert frame_length(bytes([0xFD, 9])) is None  # header not complete yet
    (m,) = MavFramer().feed(signed)
    assert m.get_type() == "GPS_RAW_INT"


def test_tlog_records_mixed_versions_signed_garbage_and_cut_tail(tmp_path):
    v1 = bytes(ENC.heartbeat_encode(2, 12, 0, 0, 3).pack(ENC, force_mavlink1=True))
    v2 = packets(1)[0]
    signed = signed_packet(5)
    path = tmp_path / "mixed.tlog"
    with open(path, "wb") as f:
        write_record(f, 1000.000001, v1)
        write_record(f, 1000.5, signed)
        f.write(b"\x00\x01\x02")  # junk between records (a corrupted log)
        f.write(encode_record(1001.25, v2))
        f.write(bytes([0, 0, 0, 0, 0, 0, 0, 1, 0xFD, 4, 0x80]))  # impossible v2 header
        write_record(f, 1002.0, v2)
        f.write(encode_record(1003.0, v2)[:-5])  # cut by a power loss
    reader = TlogReader(path)
    got = list(reader)
    assert [p for _, p in got] == [v1, signed, v2, v2]
    assert [round(t, 6) for t, _ in got] == [1000.000001, 1000.5, 1001.25, 1002.0]
    assert reader.truncated == 1
    assert reader.skipped_bytes == 3 + 11


def _values(cls, rng, zero):
    """Field values for `cls`'s constructor: random in each field's type, or all zero
    (so that MAVLink 2 drops the payload's trailing zeros on the wire)."""
    ints = {"int8_t": 7, "uint8_t": 8, "int16_t": 15, "uint16_t": 16, "int32_t": 31}
    ints |= {"uint32_t": 32, "int64_t": 63, "uint64_t": 64}
    out = []
    lengths = dict(zip(cls.ordered_fieldnames, cls.array_lengths, strict=True))  # wire order
    for name, ftype in zip(cls.fieldnames, cls.fieldtypes, strict=True):
        n = lengths[name]
        if ftype == "char":
            out.append(b"" if zero else bytes(rng.choice(b"abcXYZ, 019") for _ in range(n or 1)))
            continue
        if ftype in ("float", "double"):
            one = (lambda: 0.0) if zero else (lambda: rng.uniform(-1e4, 1e4))
        else:
            bits = ints[ftype]
            lo, hi = (-(1 << bits), (1 << bits) - 1) if ftype[0] == "i" else (0, (1 << bits) - 1)
            one = (lambda: 0) if zero else (lambda lo=lo, hi=hi: rng.randint(lo, hi))
        out.append([one() for _ in range(n)] if n else one())
    return out


def _assert_same_message(got, want, what) -> None:
    """The same type and every attribute alike, the header's too."""
    assert type(got) is type(want), what
    mine, theirs = dict(vars(got)), dict(vars(want))
    assert vars(mine.pop("_header")) == vars(theirs.pop("_header")), what
    assert mine == theirs, what


def test_the_fast_decoder_gives_pymavlinks_messages_for_every_message_of_the_dialect():
    """core.mavlink.fast_decode against pymavlink's own decode, attribute for attribute
    (the header's too), for every message type in MAVLink 2 and, where its id allows,
    MAVLink 1, with random and all-zero payloads (MAVLink 2 drops trailing zeros); and a
    bad checksum, a signed packet and an unknown id raise or decode as pymavlink does."""
    from fpv_station.core.mavlink.fast_decode import _LAYOUTS, FastDecoder

    rng = random.Random(7)
    enc = mavlink.MAVLink(None, srcSystem=42, srcComponent=191)
    fast, reference = FastDecoder(), mavlink.MAVLink(None)
    fast_paths = 0
    for msg_id, cls in mavlink.mavlink_map.items():
        for zero in (False, True):
            for v1 in (False, True) if msg_id < 256 else (False,):
                enc.seq = rng.randrange(256)
                wire = bytes(cls(*_values(cls, rng, zero)).pack(enc, force_mavlink1=v1))
                got = fast.decode(bytearray(wire))
                want = reference.decode(bytearray(wire))
                _assert_same_message(got, want, (cls.msgname, v1, zero))
                fast_paths += msg_id in _LAYOUTS
    assert fast_paths > 300  # most of the dialect took the fast path

    wire = bytearray(ENC.attitude_encode(1, 0.1, 0.2, 0.3, 0, 0, 0).pack(ENC))
    wire[-1] ^= 0xFF
    for decoder in (fast, reference):
        try:
            decoder.decode(bytearray(wire))
        except mavlink.MAVError as exc:
            assert "CRC" in str(exc)
        else:
            raise AssertionError("a bad checksum decoded")
    signer = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    signer.signing.secret_key, signer.signing.sign_outgoing = bytes(32), True
    signed = bytes(signer.attitude_encode(1, 0.1, 0.2, 0.3, 0, 0, 0).pack(signer))
    _assert_same_message(  # signed: _signed and _link_id are the packet's
        fast.decode(bytearray(signed)), reference.decode(bytearray(signed)), "signed"
    )
    unknown = bytearray(packets(1)[0])
    unknown[7:10] = (60000).to_bytes(3, "little")
    assert isinstance(fast.decode(unknown), mavlink.MAVLink_unknown)

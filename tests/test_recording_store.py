import os
import time
from pathlib import Path

import pytest

from fpv_station.companion.recording import layout
from fpv_station.companion.recording.meta import SessionMeta, write_meta
from fpv_station.companion.recording.store import (
    InvalidPath,
    InvalidSessionId,
    SessionFileNotFound,
    SessionNotFound,
    SessionStore,
    create_session_dir,
)

START = 1795000000.0  # 2026-11-18T11:06:40Z


def make_session(root: Path, start: float = START, source: str = "sim") -> tuple[str, Path]:
    sid, path = create_session_dir(root, start, source)
    (path / "front").mkdir()
    (path / "front" / "00000001.jpg").write_bytes(b"\xff\xd8jpeg\xff\xd9")
    (path / layout.TELEMETRY_CSV).write_text("t_s,wall_time\n0.0,1.0\n")
    write_meta(
        path / layout.SESSION_JSON,
        SessionMeta(id=sid, start_wall=start, start_utc=layout.utc_label(start), source=source),
    )
    return sid, path


def test_session_ids_from_time_and_source():
    assert layout.session_id_for(START, "sim") == "20261118T110640Z_sim"
    assert layout.session_id_for(START, "/dev/serial0:921600").endswith("_serial")
    assert layout.session_id_for(START, "udpin:0.0.0.0:14550").endswith("_udp")
    assert layout.session_id_for(START, "replay:/x/y.tlog", 2).endswith("_replay-2")
    assert layout.session_start_from_id("20261118T110640Z_sim") == START
    for sid in (layout.session_id_for(START, s) for s in ("sim", "tcp:1.2.3.4:5", "Weird Src!")):
        assert layout.is_valid_session_id(sid), sid


def test_create_session_dir_never_reuses(tmp_path):
    a, _ = create_session_dir(tmp_path, START, "sim")
    b, _ = create_session_dir(tmp_path, START, "sim")
    assert a != b and b == a + "-1"


def test_columns_flatten_vehicle_state_generically():
    cols = layout.telemetry_columns()
    assert cols[:2] == ("t_s", "wall_time")
    for c in (
        "gps.lat_deg",
        "altitude.relative_alt_m",
        "rc.pwm_us.0",
        "rc.pwm_us.17",
        "servo.pwm_us.15",
        "heartbeat.armed",
        "heartbeat.mode",
        "attitude.roll_rad",
        "front.seq",
        "front.file",
        "front.t_wall",
        "front.skew_s",
        "bottom.skew_s",
    ):
        assert c in cols, c
    assert "rc.pwm_us.18" not in cols and "rc.pwm_us" not in cols
    assert len(set(cols)) == len(cols)


def test_list_and_meta(tmp_path):
    store = SessionStore(tmp_path)
    sid, _ = make_session(tmp_path)
    sid2, p2 = make_session(tmp_path, START + 60)
    (p2 / layout.SESSION_JSON).write_text("{broken")
    (tmp_path / "not-a-session").mkdir()
    listed = store.list()
    assert [s.id for s in listed] == [sid2, sid]  # newest first
    assert listed[0].status == "unreadable" and listed[0].start_wall == START + 60
    assert listed[1].status == layout.STATUS_RECORDING and listed[1].size_bytes > 0
    assert store.meta(sid).id == sid


@pytest.mark.parametrize(
    "bad",
    [
        "../etc",
        "..",
        ".",
        "",
        "a/b",
        "x\x00y",
        "/etc",
        "20261118T110640Z_sim/..",
        "20261118T021320Z_SIM",
        "a" * 300,
    ],
)
def test_bad_ids_rejected(tmp_path, bad):
    store = SessionStore(tmp_path)
    make_session(tmp_path)
    with pytest.raises(InvalidSessionId):
        store.resolve(bad)


def test_unknown_id_not_found(tmp_path):
    with pytest.raises(SessionNotFound):
        SessionStore(tmp_path).resolve("20200101T000000Z_sim")


@pytest.mark.parametrize(
    "bad",
    [
        "../../etc/passwd",
        "../20261118T110640Z_sim/telemetry.csv",
        "/etc/passwd",
        "front/../../x",
        "front//x",
        "a\x00b",
        "..\\..\\etc\\passwd",
        "C:/x",
        "./telemetry.csv",
        "",
    ],
)
def test_traversal_rejected(tmp_path, bad):
    store = SessionStore(tmp_path)
    sid, _ = make_session(tmp_path)
    with pytest.raises(InvalidPath):
        store.file(sid, bad)


def test_symlinks_pointing_out_rejected(tmp_path):
    root = tmp_path / "sessions"
    store = SessionStore(root)
    sid, path = make_session(root)
    secret = tmp_path / "secret.txt"
    secret.write_text("secret")
    os.symlink(secret, path / "link.txt")
    os.symlink(tmp_path, path / "front" / "up")
    with pytest.raises(InvalidPath):
        store.file(sid, "link.txt")
    with pytest.raises(InvalidPath):
        store.file(sid, "front/up/secret.txt")
    # A session folder that is itself a symlink is not a session.
    other = tmp_path / "elsewhere"
    other.mkdir()
    os.symlink(other, root / "20300101T000000Z_sim")
    with pytest.raises(SessionNotFound):
        store.resolve("20300101T000000Z_sim")
    assert "link.txt" not in [rel for rel, _ in store.files(sid)]


def test_file_inside_session(tmp_path):
    store = SessionStore(tmp_path)
    sid, path = make_session(tmp_path)
    assert store.file(sid, "front/00000001.jpg").read_bytes() == b"\xff\xd8jpeg\xff\xd9"
    with pytest.raises(SessionFileNotFound):
        store.file(sid, "front/00000002.jpg")
    with pytest.raises(SessionFileNotFound):
        store.file(sid, "front")  # a folder is not a file
    rels = [rel for rel, _ in store.files(sid)]
    assert rels == ["front/00000001.jpg", "session.json", "telemetry.csv"]
    store.delete(sid)
    assert not path.exists()


def test_the_folder_of_a_session_being_recorded_is_walked_at_most_every_refresh(
    tmp_path, monkeypatch
):
    """The sessions page lists every 5 s. The size of a finished session is kept while its
    session.json is unchanged; the recorder rewrites a live session's every 2 s, and a
    walk of a long flight's folder (70,000 JPEGs after 20 min) costs a Pi about a second.
    So a live session's size (and flags) are taken again at most every LIVE_REFRESH_S."""
    from fpv_station.companion.recording import store as store_module

    monkeypatch.setattr(store_module, "LIVE_REFRESH_S", 0.5)
    store = SessionStore(tmp_path)
    live, live_dir = make_session(tmp_path)
    done, done_dir = make_session(tmp_path, START + 60)
    meta = store.meta(done).model_copy(update={"status": layout.STATUS_COMPLETE})
    write_meta(done_dir / layout.SESSION_JSON, meta)

    def sizes() -> dict[str, int]:
        return {s.id: s.size_bytes for s in store.list()}

    before = sizes()
    for folder in (live_dir, done_dir):  # frames written, session.json rewritten
        (folder / "front" / "00000002.jpg").write_bytes(bytes(1000))
        stamp = (folder / layout.SESSION_JSON).stat().st_mtime_ns + 10_000_000
        os.utime(folder / layout.SESSION_JSON, ns=(stamp, stamp))
    after = sizes()
    assert after[done] == before[done] + 1000  # a changed session.json: walked again
    assert after[live] == before[live]  # within the refresh: not walked
    time.sleep(0.6)
    assert sizes()[live] == before[live] + 1000  # after it: walked


def test_a_frame_index_reads_what_is_appended_and_rereads_a_rewritten_file(tmp_path):
    """The index of a growing frames.csv (a session being recorded) is extended from where
    it stopped: a row still being written is read once whole; a damaged row is skipped;
    a file replaced by recovery (a new inode) is read again from its start."""
    import os

    from fpv_station.companion.recording import frame_pack

    cam = tmp_path / "front"
    cam.mkdir()
    path = cam / layout.FRAMES_CSV
    header = ",".join(layout.FRAME_COLUMNS) + "\n"

    def row(seq: int) -> str:
        return f"{seq},{layout.frame_relpath('front', seq)},{seq / 30},{1.7e9 + seq / 30},320,240,{1000 + seq},{seq * 2000}\n"

    path.write_text(header + row(1) + row(2) + row(3)[:9])
    first = frame_pack.read_index(tmp_path, "front")
    assert first.packed and first.seq.tolist() == [1, 2] and first.find(3) is None
    assert frame_pack.read_index(tmp_path, "front", first) is first  # nothing new
    with open(path, "a") as f:
        f.write(row(3)[9:] + "x,front/oops.jpg,1,2,3,4,5,6\n" + row(4))
    grown = frame_pack.read_index(tmp_path, "front", first)
    assert grown.seq.tolist() == [1, 2, 3, 4] and first.seq.tolist() == [1, 2]
    k = grown.find(4)
    assert (grown.offset[k], grown.size[k], grown.width[k]) == (8000, 1004, 320)
    assert grown.name(k) == "front/00000004.jpg"
    tmp = cam / "frames.csv.tmp"
    tmp.write_text(header + row(1) + row(4))
    os.replace(tmp, path)
    again = frame_pack.read_index(tmp_path, "front", grown)
    assert again.seq.tolist() == [1, 4]
    # Format 1: no offset column, a file per frame.
    path.write_text(
        ",".join(layout.FRAME_COLUMNS_V1)
        + "\n"
        + "".join(row(s)[: row(s).rfind(",")] + "\n" for s in (5, 6))
    )
    v1 = frame_pack.read_index(tmp_path, "front")
    assert not v1.packed and v1.seq.tolist() == [5, 6] and v1.offset.tolist() == [0, 0]
    (cam / "00000006.jpg").write_bytes(b"\xff\xd8six\xff\xd9")
    assert frame_pack.on_disk(tmp_path, v1).tolist() == [False, True]
    assert frame_pack.frame_bytes(tmp_path, v1, 1) == b"\xff\xd8six\xff\xd9"
    with pytest.raises(frame_pack.FrameNotOnDisk):
        frame_pack.frame_bytes(tmp_path, v1, 0)

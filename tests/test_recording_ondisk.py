"""Counting a cut-off session's files and reconciling frames.csv with the frames on disk
(companion.recording.ondisk), on real files: what a power loss can leave, beyond kill -9.
Session format 2 (a frame pack per camera) first; then format 1 (a JPEG file per frame,
frames.csv without `offset`), which sessions recorded before the pack still are."""

from __future__ import annotations

import csv
import io
import shutil
from pathlib import Path

import pytest

from fpv_station.companion.recording import layout
from fpv_station.companion.recording.meta import (
    CameraQuality,
    Quality,
    SessionMeta,
    read_meta,
    write_meta,
)
from fpv_station.companion.recording.ondisk import TELEMETRY_TAIL_BYTES, take_census
from fpv_station.companion.recording.recovery import mark_interrupted
from fpv_station.companion.recording.store import SessionStore
from tests.recording_fakes import make_jpegs

START = 1_700_000_000.0


def frames_csv(rows: list[tuple], columns: tuple[str, ...] = layout.FRAME_COLUMNS_V1) -> bytes:
    """A frames.csv as the recorder writes it (format 1's columns unless told)."""
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(columns)
    w.writerows(rows)
    return buf.getvalue().encode()


def packed(cam: Path, jpegs: list[bytes], seqs: list[int]) -> list[tuple]:
    """`cam`/frames.mjpeg holding `jpegs` back to back; their format 2 frames.csv rows."""
    rows, offset = [], 0
    for seq, jpeg in zip(seqs, jpegs, strict=True):
        rel = layout.frame_relpath(cam.name, seq)
        rows.append((seq, rel, 0.1 * seq, START + 0.1 * seq, 160, 120, len(jpeg), offset))
        offset += len(jpeg)
    cam.mkdir(exist_ok=True)
    (cam / layout.FRAMES_PACK).write_bytes(b"".join(jpegs))
    return rows


def test_a_pack_is_cut_after_its_last_whole_listed_frame(tmp_path):
    """Format 2 after a power loss or kill: a row past the pack's end (its frame cut
    mid-write), a row whose bytes are not a whole JPEG, a cut last row, and bytes no row
    names after the last frame. The rows of whole frames stay, in order; the others go;
    the pack ends with the last kept frame, and the bytes cut off are counted."""
    jpegs = make_jpegs(5, 160, 120)
    cam = tmp_path / "front"
    rows = packed(cam, jpegs, [1, 2, 3, 4, 5])
    pack = cam / layout.FRAMES_PACK
    end_of_4 = rows[3][7] + rows[3][6]
    # Frame 5 was being written: half of it reached the disk, and its row did.
    pack.write_bytes(pack.read_bytes()[: end_of_4 + len(jpegs[4]) // 2])
    bad = list(rows[2])
    bad[6] += 1  # frame 3's row names one byte too many: it does not end with EOI
    listed = [rows[0], rows[1], tuple(bad), rows[3], rows[4]]
    (cam / layout.FRAMES_CSV).write_bytes(frames_csv(listed, layout.FRAME_COLUMNS) + b"6,front/0")

    front = take_census(tmp_path, ["front"], START).frames["front"]

    assert front.rows_removed == 2 and front.added == 0 and front.partial_removed == []
    assert front.pack_tail_removed == len(jpegs[4]) // 2
    assert pack.read_bytes() == b"".join(jpegs[:4])
    text = (cam / layout.FRAMES_CSV).read_text()
    on_disk = list(csv.DictReader(io.StringIO(text)))
    assert tuple(on_disk[0]) == layout.FRAME_COLUMNS and text.endswith("\n")
    assert [int(r["seq"]) for r in on_disk] == [1, 2, 4]
    assert [r[c] for r in on_disk for c in ("offset", "bytes")] == [
        str(v) for row in (rows[0], rows[1], rows[3]) for v in (row[7], row[6])
    ]
    assert [f[0] for f in front.rows] == ["1", "2", "4"] and front.achieved_fps is not None
    # A second look finds nothing to do.
    again = take_census(tmp_path, ["front"], START).frames["front"]
    assert (again.rows_removed, again.pack_tail_removed) == (0, 0)
    assert (cam / layout.FRAMES_CSV).read_text() == text


def test_an_interrupted_packed_session_says_what_was_cut(tmp_path):
    """The next start's recovery of a format 2 session: frames.csv listed every frame but
    the last batch, whose bytes a kill left in the pack; they are cut off and counted in
    session.json `recovery.pack_tail_removed`, and the quality counts are the rows'."""
    jpegs = make_jpegs(4, 160, 120)
    folder = _cut_off_session(tmp_path, "20261122T035500Z_sim", rows=30)
    cam = folder / "front"
    rows = packed(cam, jpegs, [7, 8, 9, 10])
    (cam / layout.FRAMES_CSV).write_bytes(frames_csv(rows[:2], layout.FRAME_COLUMNS))

    assert mark_interrupted(SessionStore(tmp_path)) == [folder.name]

    meta = read_meta(folder / layout.SESSION_JSON)
    assert meta.status == layout.STATUS_INTERRUPTED
    assert meta.recovery.pack_tail_removed == {"front": len(jpegs[2]) + len(jpegs[3])}
    assert meta.recovery.frame_rows_removed == {"front": 0}
    q = meta.quality.cameras["front"]
    assert (q.frames_written, q.first_seq, q.last_seq) == (2, 7, 8)
    assert (cam / layout.FRAMES_PACK).read_bytes() == jpegs[0] + jpegs[1]


def test_frames_csv_lists_exactly_the_complete_jpegs(tmp_path):
    jpegs = make_jpegs(6, 160, 120)
    cam = tmp_path / "front"
    cam.mkdir()
    for seq in (1, 2, 3, 5, 6):
        (cam / f"{seq:08d}.jpg").write_bytes(jpegs[seq - 1])
    (cam / "00000007.jpg").write_bytes(jpegs[5][:500])  # cut mid-write
    rows = [
        (s, layout.frame_relpath("front", s), 0.1 * s, START + 0.1 * s, 160, 120, len(jpegs[s - 1]))
        for s in (1, 2, 3, 4)  # 4: listed, but the power loss took its blocks
    ]
    # Frame 5 and 6 were written after the last flush; the file ends in a partial row.
    (cam / "frames.csv").write_bytes(frames_csv(rows) + b"5,front/000")
    header = ",".join(layout.telemetry_columns(("front",)))
    telemetry = (
        header + "\n" + _row(header, t_s=0.61, wall=START + 0.61, seq=6, t_wall=START + 0.6)
    ).encode()
    (tmp_path / layout.TELEMETRY_CSV).write_bytes(telemetry + b"0.64,17000")

    census = take_census(tmp_path, ["front"], START)

    assert census.telemetry_rows == 1 and census.telemetry_cut_line
    front = census.frames["front"]
    assert (front.added, front.rows_removed) == (2, 1)
    assert front.partial_removed == ["front/00000007.jpg"]
    assert not (cam / "00000007.jpg").exists()
    on_disk = list(csv.DictReader(io.StringIO((cam / "frames.csv").read_text())))
    assert [int(r["seq"]) for r in on_disk] == [1, 2, 3, 5, 6]
    six = on_disk[-1]
    assert float(six["t_wall"]) == START + 0.6  # from the telemetry row that named it
    assert abs(float(six["t_s"]) - 0.6) < 1e-6
    assert (six["width"], six["height"], six["bytes"]) == ("160", "120", str(len(jpegs[5])))
    five = on_disk[-2]  # no row named it: the file's time
    assert abs(float(five["t_wall"]) - (cam / "00000005.jpg").stat().st_mtime) < 1e-5
    # A second look finds nothing to do.
    again = take_census(tmp_path, ["front"], START).frames["front"]
    assert (again.added, again.rows_removed, again.partial_removed) == (0, 0, [])


def test_a_cut_last_row_alone_is_trimmed_and_new_frames_appended(tmp_path):
    jpegs = make_jpegs(3, 160, 120)
    cam = tmp_path / "bottom"
    cam.mkdir()
    for seq in (10, 11, 12):
        (cam / f"{seq:08d}.jpg").write_bytes(jpegs[seq - 10])
    rows = [(10, layout.frame_relpath("bottom", 10), 0.0, START, 160, 120, len(jpegs[0]))]
    (cam / "frames.csv").write_bytes(frames_csv(rows) + b"11,bot")
    bottom = take_census(tmp_path, ["bottom"], START).frames["bottom"]
    assert bottom.added == 2 and bottom.rows_removed == 0
    text = (cam / "frames.csv").read_bytes().decode()
    assert text.startswith(frames_csv(rows).decode()) and "bot\r" not in text
    assert [int(r["seq"]) for r in csv.DictReader(io.StringIO(text))] == [10, 11, 12]


def _row(header: str, t_s: float, wall: float, seq: int, t_wall: float) -> str:
    cols = header.split(",")
    values = dict.fromkeys(cols, "")
    values.update(
        {
            "t_s": repr(t_s),
            "wall_time": repr(wall),
            "front.seq": str(seq),
            "front.t_wall": repr(t_wall),
            "front.skew_s": repr(round(t_s - (t_wall - START), 6)),
        }
    )
    return ",".join(values[c] for c in cols) + "\n"


def test_a_long_telemetry_file_is_counted_without_reading_it_whole(tmp_path):
    """Rows are counted in chunks; the frame times come from the newest rows (a tail of
    the file that starts mid-line); the count and the last row are exact."""
    jpegs = make_jpegs(2, 160, 120)
    cam = tmp_path / "front"
    cam.mkdir()
    n = 12_000  # ~2 MB of rows, more than the tail kept in memory
    for seq in (n - 1, n):
        (cam / f"{seq:08d}.jpg").write_bytes(jpegs[seq % 2])
    (cam / "frames.csv").write_bytes(frames_csv([]))
    header = ",".join(layout.telemetry_columns(("front",)))
    rows = [
        _row(header, t_s=k / 30, wall=START + k / 30, seq=k, t_wall=START + k / 30)
        for k in range(1, n + 1)
    ]
    (tmp_path / layout.TELEMETRY_CSV).write_text(header + "\n" + "".join(rows) + "1.0,17")
    assert (tmp_path / layout.TELEMETRY_CSV).stat().st_size > 1.5 * TELEMETRY_TAIL_BYTES

    census = take_census(tmp_path, ["front"], START)

    assert census.telemetry_rows == n and census.telemetry_cut_line
    assert census.last_row_wall == START + n / 30
    on_disk = list(csv.DictReader(io.StringIO((cam / "frames.csv").read_text())))
    assert [int(r["seq"]) for r in on_disk] == [n - 1, n]
    # From the rows that named them (rounded to the microsecond), not the files' times.
    assert [float(r["t_wall"]) for r in on_disk] == [
        round(START + (n - 1) / 30, 6),
        round(START + n / 30, 6),
    ]


def _cut_off_session(root, sid: str, rows: int) -> Path:
    """A session a kill left in status "recording", whose session.json last said `rows`
    (format 1, no frame yet: a format 2 test adds its pack)."""
    folder = root / sid
    (folder / "front").mkdir(parents=True)
    header = ",".join(layout.telemetry_columns(("front",)))
    lines = [
        _row(header, t_s=k / 30, wall=START + k / 30, seq=0, t_wall=START) for k in range(rows)
    ]
    (folder / layout.TELEMETRY_CSV).write_text(header + "\n" + "".join(lines))
    (folder / "front" / "frames.csv").write_bytes(frames_csv([]))
    meta = SessionMeta(
        id=sid,
        start_wall=START,
        start_utc=layout.utc_label(START),
        cameras=["front"],
        quality=Quality(telemetry_rows=rows, cameras={"front": CameraQuality()}),
    )
    write_meta(folder / layout.SESSION_JSON, meta)
    return folder


@pytest.mark.parametrize("unreadable", ["front", layout.TELEMETRY_CSV])
def test_a_session_whose_files_cannot_be_read_is_still_marked_and_not_zeroed(tmp_path, unreadable):
    """Recovery runs before the station serves. A session whose files cannot be read (a
    damaged card's EIO; here a file where the camera folder was, a folder where
    telemetry.csv was) once raised out of the recorder's open, and the station did not
    start; or, for telemetry.csv, it was counted as holding no rows. It is marked
    interrupted with the counts it last wrote, and the next session is recovered too."""
    bad = _cut_off_session(tmp_path, "20261122T035500Z_sim", rows=40)
    good = _cut_off_session(tmp_path, "20261122T045500Z_sim", rows=30)
    target = bad / unreadable
    shutil.rmtree(target) if target.is_dir() else target.unlink()
    if unreadable == "front":
        target.write_text("not a folder")
    else:
        target.mkdir()

    marked = mark_interrupted(SessionStore(tmp_path))

    assert marked == [bad.name, good.name]
    meta = read_meta(bad / layout.SESSION_JSON)
    assert meta.status == layout.STATUS_INTERRUPTED
    assert meta.quality.telemetry_rows == 40  # not counted again, not zero
    assert meta.recovery is None  # says the files were not counted
    assert read_meta(good / layout.SESSION_JSON).quality.telemetry_rows == 30

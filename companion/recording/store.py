"""The sessions directory: list sessions, and turn untrusted ids and paths into safe paths.

Every id and relative path that comes from a request goes through `resolve`, `file` or
`file_or_frame`; they never return a path outside the sessions directory (traversal,
absolute paths, NUL bytes, symlinks that point out are refused with a typed error), nor
bytes from one. A frame's name (`front/00000042.jpg`) is a file in a format 1 session
and a slice of the camera's frame pack in format 2 (`companion.recording.frame_pack`):
`file_or_frame` serves both.

    SessionStoreError          (base)
    ├── InvalidSessionId       not a session id by its syntax         -> 400
    ├── InvalidPath            a file path that could leave the session -> 400
    ├── SessionNotFound        a well-formed id with no such session  -> 404
    └── SessionFileNotFound    a safe path to a file that does not exist -> 404
"""

from __future__ import annotations

import builtins
import contextlib
import logging
import os
import shutil
import stat
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import Generic, TypeVar

from fpv_station.companion.recording import frame_pack, layout
from fpv_station.companion.recording.flags import QualityFlag, session_flags
from fpv_station.companion.recording.meta import SessionMeta, read_meta

log = logging.getLogger(__name__)

T = TypeVar("T")


class SessionStoreError(Exception):
    """Base of the store's errors; the message says what was wrong."""


class InvalidSessionId(SessionStoreError):
    pass


class InvalidPath(SessionStoreError):
    pass


class SessionNotFound(SessionStoreError):
    pass


class SessionFileNotFound(SessionStoreError):
    pass


@dataclass(frozen=True, slots=True)
class SessionSummary:
    """One line of the session list."""

    id: str
    start_wall: float | None
    end_wall: float | None
    duration_s: float | None
    source: str
    status: str  # layout.STATUS_*, or "unreadable" when session.json is missing or broken
    stop_reason: str | None
    size_bytes: int
    telemetry_rows: int | None
    frames_written: dict[str, int]
    frames_dropped: dict[str, int]
    meta: SessionMeta | None  # None when session.json is missing or unreadable
    flags: list[QualityFlag] = field(default_factory=list)  # flags.session_flags


class SessionStore:
    """Read access to `root`, the configurable sessions directory (created by the first
    session, so that a station that never records leaves no empty folder behind)."""

    def __init__(self, root: Path) -> None:
        self.root = Path(root)
        self._real_root = Path(os.path.realpath(self.root))
        # Folder sizes by id, valid while session.json keeps its mtime: a finished session
        # does not change, and walking thousands of frames on every list costs a Pi.
        self._sizes: dict[str, _Cached[int]] = {}
        # Quality flags by id, valid while session.json and messages.csv keep their mtimes.
        self._flags: dict[str, _Cached[list[QualityFlag]]] = {}
        # Frame indexes by (id, camera), the most recently used FRAME_INDEXES_KEPT: a replay
        # asks for a frame of each camera many times a second. Request threads share it.
        self._indexes: OrderedDict[tuple[str, str], frame_pack.FrameIndex] = OrderedDict()
        self._indexes_lock = threading.Lock()

    # -- untrusted input -> safe paths -----------------------------------------------

    def resolve(self, session_id: str) -> Path:
        """The folder of session `session_id`; raises InvalidSessionId or SessionNotFound."""
        if not isinstance(session_id, str) or "\x00" in session_id:
            raise InvalidSessionId("A session id must be a string without NUL bytes.")
        if not layout.is_valid_session_id(session_id):
            raise InvalidSessionId(
                f"'{session_id[:80]}' is not a session id (expected e.g. '20261122T035500Z_sim')."
            )
        path = self._real_root / session_id
        try:
            st = os.lstat(path)
        except FileNotFoundError:
            raise SessionNotFound(f"No session '{session_id}'.") from None
        if not stat.S_ISDIR(st.st_mode):  # a symlink or a stray file is not a session
            raise SessionNotFound(f"No session '{session_id}'.")
        return path

    def file(self, session_id: str, relpath: str) -> Path:
        """A regular file inside a session; raises InvalidPath or SessionFileNotFound."""
        folder = self.resolve(session_id)
        parts = _safe_parts(relpath)
        candidate = folder.joinpath(*parts)
        # Symlinks anywhere on the way are resolved and must stay inside the session.
        real = Path(os.path.realpath(candidate))
        if not real.is_relative_to(folder):
            raise InvalidPath(f"'{relpath[:200]}' leads outside the session.")
        try:
            st = os.stat(real)
        except (FileNotFoundError, NotADirectoryError):
            raise SessionFileNotFound(
                f"Session '{session_id}' has no file '{relpath[:200]}'."
            ) from None
        except OSError as exc:  # ENAMETOOLONG, ELOOP ...: still the client's path
            raise InvalidPath(f"'{relpath[:200]}' cannot be a file here: {exc.strerror}.") from None
        if not stat.S_ISREG(st.st_mode):
            raise SessionFileNotFound(f"'{relpath}' in session '{session_id}' is not a file.")
        return real

    def file_or_frame(self, session_id: str, relpath: str) -> Path | bytes:
        """`file(session_id, relpath)`, or when no such file exists and `relpath` names a
        frame kept in its camera's frame pack (format 2: `front/00000042.jpg`), that
        frame's JPEG bytes. Raises as `file` does."""
        try:
            return self.file(session_id, relpath)
        except SessionFileNotFound:
            data = self._packed_frame(session_id, relpath)
            if data is None:
                raise
            return data

    def _packed_frame(self, session_id: str, relpath: str) -> bytes | None:
        """The bytes of frame `relpath` from its camera's pack; None when it is none."""
        parts = _safe_parts(relpath)
        m = layout.FRAME_NAME_RE.fullmatch(parts[-1]) if len(parts) == 2 else None
        if m is None:
            return None
        camera, seq = parts[0], int(m.group(1))
        try:
            pack = self.file(session_id, layout.frames_pack_relpath(camera))
        except SessionFileNotFound:  # format 1, or no such camera
            return None
        index = self.frame_index(session_id, camera)
        if index is None or not index.packed:
            return None
        k = index.find(seq)
        if k is None:
            return None
        try:
            return frame_pack.read_packed(pack, int(index.offset[k]), int(index.size[k]))
        except frame_pack.FrameNotOnDisk:  # cut off by a recovery since it was listed
            return None

    def frame_index(self, session_id: str, camera: str) -> frame_pack.FrameIndex | None:
        """The index of a camera's frames.csv (None: there is none), kept for the next
        request and extended as the file grows (a session being recorded)."""
        try:
            path = self.file(session_id, layout.frames_csv_relpath(camera))
        except SessionFileNotFound:
            return None
        key = (session_id, camera)
        with self._indexes_lock:
            index = frame_pack.read_index_file(path, camera, self._indexes.get(key))
            if index is None:
                self._indexes.pop(key, None)
                return None
            self._indexes[key] = index
            self._indexes.move_to_end(key)
            while len(self._indexes) > FRAME_INDEXES_KEPT:
                self._indexes.popitem(last=False)
        return index

    def frame_counts(self, session_id: str, files: Iterable[str]) -> dict[str, int]:
        """Frames on disk per camera, given the session's `files` (relative paths, as
        `files` returns them): format 1 counts its JPEG files, format 2 the rows of
        frames.csv (the pack's frames)."""
        counts: dict[str, int] = {}
        for rel in files:
            camera, _, name = rel.partition("/")
            if name == layout.FRAMES_PACK:
                index = self.frame_index(session_id, camera)
                counts[camera] = counts.get(camera, 0) + (len(index) if index is not None else 0)
            elif is_frame_file(rel):
                counts[camera] = counts.get(camera, 0) + 1
        return counts

    # -- listing -------------------------------------------------------------------------

    def ids(self) -> list[str]:
        """Ids of every session folder, oldest first (ids sort by start time)."""
        out: list[str] = []
        if not self._real_root.is_dir():
            return out
        with os.scandir(self._real_root) as it:
            for entry in it:
                if layout.is_valid_session_id(entry.name) and entry.is_dir(follow_symlinks=False):
                    out.append(entry.name)
        return sorted(out)

    def list(self) -> list[SessionSummary]:
        """A summary of every session, newest first."""
        return [self.summary(sid) for sid in reversed(self.ids())]

    def summary(self, session_id: str) -> SessionSummary:
        folder = self.resolve(session_id)
        meta = self.meta_or_none(session_id)
        live = meta is not None and meta.status == layout.STATUS_RECORDING
        size = self._size(session_id, folder, live)
        if meta is None:
            return SessionSummary(
                id=session_id,
                start_wall=layout.session_start_from_id(session_id),
                end_wall=None,
                duration_s=None,
                source="unknown",
                status="unreadable",
                stop_reason=None,
                size_bytes=size,
                telemetry_rows=None,
                frames_written={},
                frames_dropped={},
                meta=None,
            )
        q = meta.quality
        return SessionSummary(
            id=session_id,
            start_wall=meta.start_wall,
            end_wall=meta.end_wall,
            duration_s=meta.duration_s,
            source=meta.source,
            status=meta.status,
            stop_reason=meta.stop_reason,
            size_bytes=size,
            telemetry_rows=q.telemetry_rows,
            frames_written={c: cq.frames_written for c, cq in q.cameras.items()},
            frames_dropped={c: cq.frames_dropped for c, cq in q.cameras.items()},
            meta=meta,
            flags=_cached(
                self._flags,
                session_id,
                tuple(_mtime_ns(folder / n) for n in (layout.SESSION_JSON, layout.MESSAGES_CSV)),
                live,
                lambda: session_flags(meta, folder),
            ),
        )

    def _size(self, session_id: str, folder: Path, live: bool) -> int:
        stamp = _mtime_ns(folder / layout.SESSION_JSON)
        return _cached(self._sizes, session_id, stamp, live, lambda: folder_size(folder))

    def meta(self, session_id: str) -> SessionMeta:
        """session.json of a session; raises SessionFileNotFound if missing or unreadable."""
        path = self.resolve(session_id) / layout.SESSION_JSON
        try:
            return read_meta(path)
        except ValueError as exc:
            raise SessionFileNotFound(str(exc)) from None

    def meta_or_none(self, session_id: str) -> SessionMeta | None:
        try:
            return self.meta(session_id)
        except SessionFileNotFound:
            return None

    def delete(self, session_id: str) -> None:
        """Remove a session folder (the caller refuses while it is being recorded)."""
        folder = self.resolve(session_id)
        shutil.rmtree(folder)
        self._sizes.pop(session_id, None)
        self._flags.pop(session_id, None)
        with self._indexes_lock:
            for key in [k for k in self._indexes if k[0] == session_id]:
                del self._indexes[key]

    def files(self, session_id: str) -> builtins.list[tuple[str, Path]]:
        """(relative posix path, absolute path) of every regular file, sorted; no symlinks."""
        folder = self.resolve(session_id)
        out: list[tuple[str, Path]] = []
        for dirpath, dirnames, filenames in os.walk(folder, followlinks=False):
            dirnames.sort()
            for name in sorted(filenames):
                p = Path(dirpath) / name
                if p.is_file() and not p.is_symlink() and not name.endswith(".tmp"):
                    out.append((p.relative_to(folder).as_posix(), p))
        return sorted(out)


def is_frame_file(relpath: str) -> bool:
    """Whether a session's file is one frame of format 1 (`front/00000042.jpg`)."""
    camera, _, name = relpath.partition("/")
    return bool(camera) and layout.FRAME_NAME_RE.fullmatch(name) is not None


# Indexes kept by the store: a 20-minute flight's is about 1 MB a camera (36,000 frames).
FRAME_INDEXES_KEPT = 4

# The session's own files are short (front/00000042.jpg); longer requests are refused
# before the file system sees them, which would fail with ENAMETOOLONG.
MAX_RELPATH_LEN = 200
MAX_NAME_BYTES = 255


def _safe_parts(relpath: str) -> list[str]:
    """Split a request path into plain names; refuse anything that could climb out."""
    if not isinstance(relpath, str) or not relpath:
        raise InvalidPath("A file path is required.")
    if "\x00" in relpath:
        raise InvalidPath("A file path must not contain NUL bytes.")
    if "\\" in relpath:
        raise InvalidPath("Use '/' to separate folders in a file path.")
    if relpath.startswith("/") or PurePosixPath(relpath).is_absolute() or ":" in relpath:
        raise InvalidPath(f"'{relpath[:200]}' is absolute; give a path inside the session.")
    if len(relpath) > MAX_RELPATH_LEN:
        raise InvalidPath(f"A file path inside a session is at most {MAX_RELPATH_LEN} characters.")
    parts = relpath.split("/")
    for part in parts:
        if part in ("", ".", ".."):
            raise InvalidPath(f"'{relpath[:200]}' is not a plain relative path.")
        if len(part.encode()) > MAX_NAME_BYTES:  # the file system's own limit (NAME_MAX)
            raise InvalidPath(f"'{part[:80]}...' is longer than a file name can be.")
    return parts


# A session being recorded rewrites its session.json every 2 s (and messages.csv as the
# vehicle speaks): its size and flags are taken again at most this often, not at every
# list (the sessions page lists every 5 s; walking a 20-minute flight's 70,000 JPEGs
# costs a Pi about a second).
LIVE_REFRESH_S = 30.0


@dataclass(frozen=True)
class _Cached(Generic[T]):
    stamp: object  # the mtimes it was taken at
    value: T
    taken_mono: float


def _cached(
    cache: dict[str, _Cached[T]], key: str, stamp: object, live: bool, take: Callable[[], T]
) -> T:
    """`cache[key]`'s value while its files keep `stamp` (a missing file, -1, is no
    stamp) or, for a live session, for LIVE_REFRESH_S; else `take()` again."""
    hit = cache.get(key)
    now = time.monotonic()
    if hit is not None and (
        (hit.stamp == stamp and stamp != -1) or (live and now - hit.taken_mono < LIVE_REFRESH_S)
    ):
        return hit.value
    value = take()
    cache[key] = _Cached(stamp, value, now)
    return value


def _mtime_ns(path: Path) -> int:
    """A file's mtime (ns), -1 when it is missing: the stamp of a cached value."""
    try:
        return os.stat(path).st_mtime_ns
    except OSError:
        return -1


def folder_size(folder: Path) -> int:
    """Bytes of regular files under `folder` (symlinks are not followed)."""
    total = 0
    stack = [str(folder)]
    while stack:
        with os.scandir(stack.pop()) as it:
            for entry in it:
                if entry.is_dir(follow_symlinks=False):
                    stack.append(entry.path)
                elif entry.is_file(follow_symlinks=False):
                    total += entry.stat(follow_symlinks=False).st_size
    return total


def create_session_dir(root: Path, start_wall: float, source: str) -> tuple[str, Path]:
    """Create a new session folder under `root`; returns (id, path). Never reuses a folder."""
    root.mkdir(parents=True, exist_ok=True)
    for suffix in range(1000):
        sid = layout.session_id_for(start_wall, source, suffix)
        path = root / sid
        try:
            path.mkdir()
        except FileExistsError:
            continue
        return sid, path
    raise OSError(f"Cannot create a session folder under {root}: too many at one second.")


def discard_session_dir(folder: Path, cameras: Iterable[str]) -> None:
    """Remove a folder from `create_session_dir` that nothing was recorded in (its writer
    could not open its files), with the empty files it got. Name by name, not rmtree:
    rmtree opens each directory, and a start that failed for want of descriptors has none.
    Anything else in it (not ours) keeps the folder."""
    cameras = list(cameras)
    names = [layout.TELEMETRY_CSV, layout.MAVLINK_TLOG, layout.MESSAGES_CSV]
    names += [layout.frames_csv_relpath(c) for c in cameras]
    names += [layout.frames_pack_relpath(c) for c in cameras]
    for name in names:
        with contextlib.suppress(FileNotFoundError):
            (folder / name).unlink()
    try:
        for cam in cameras:
            with contextlib.suppress(FileNotFoundError):
                (folder / cam).rmdir()
        folder.rmdir()
    except OSError as exc:
        log.warning("cannot remove the unused session folder %s: %s", folder, exc)

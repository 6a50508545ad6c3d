"""The export formats, the default dataset rate and LeRobot's file limits, apart from the
exporters: the command line offers them without importing the exporters (the `learn`
extra, absent on a Pi)."""

from __future__ import annotations

from dataclasses import dataclass

FORMATS = ("lerobot", "minari", "mcap")
DEFAULT_FPS = 10  # the twin env's control rate: a dataset step is an env step

# LeRobot v3.0's defaults (its DEFAULT_CHUNK_SIZE, DEFAULT_DATA_FILE_SIZE_IN_MB and
# DEFAULT_VIDEO_FILE_SIZE_IN_MB).
CHUNKS_SIZE = 1000
DATA_FILES_SIZE_IN_MB = 100
VIDEO_FILES_SIZE_IN_MB = 200


@dataclass(frozen=True)
class FileLimits:
    """A LeRobot dataset's file layout (info.json): files per chunk, and the sizes (MiB,
    as LeRobot measures them) at which data and video files roll over."""

    chunks_size: int = CHUNKS_SIZE
    data_files_size_in_mb: float = DATA_FILES_SIZE_IN_MB
    video_files_size_in_mb: float = VIDEO_FILES_SIZE_IN_MB

    def __post_init__(self) -> None:
        if self.chunks_size < 1:
            raise ValueError(f"chunks_size must be at least 1, not {self.chunks_size}")
        for name in ("data_files_size_in_mb", "video_files_size_in_mb"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive, not {getattr(self, name)}")

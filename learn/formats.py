"""The export formats and the default dataset rate, apart from the exporters: the command
line offers them without importing the exporters (the `learn` extra, absent on a Pi)."""

from __future__ import annotations

FORMATS = ("lerobot", "minari", "mcap")
DEFAULT_FPS = 10  # the twin env's control rate: a dataset step is an env step

"""What can go wrong when analysing a flight; every message says what happened and what
to try.

    AnalysisError            (base, a ValueError)
    ├── TrackLoadError       the file is missing, unreadable or not a known format
    ├── NoGpsFixError        the recording holds no sample with a GPS fix
    ├── TooFewPointsError    too few fixed samples (or window samples) to say anything
    ├── TaskWindowError      the task's analysis window never happens (never reached 4 m)
    └── UnknownTaskError     a task name that is not one of the paper's four

The REST layer maps TrackLoadError to 404/400 and the others to 422; the CLI prints the
message and exits with status 2.
"""

from __future__ import annotations

import re


class AnalysisError(ValueError):
    """Base of every analysis error."""


class TrackLoadError(AnalysisError):
    pass


class NoGpsFixError(AnalysisError):
    pass


class TooFewPointsError(AnalysisError):
    pass


class TaskWindowError(AnalysisError):
    pass


class UnknownTaskError(AnalysisError):
    pass


# An absolute path: a slash-separated run of names starting at the root (no spaces).
_ABSOLUTE_PATH = re.compile(r"(?<![\w.~-])/(?:[^\s'\"/]+/)*([^\s'\"/]*)")


def without_dirs(message: str) -> str:
    """`message` with each absolute path cut to its last name (a session folder to its id,
    a file to its name): what a remote client may read. The CLI keeps full paths."""
    return _ABSOLUTE_PATH.sub(lambda m: m.group(1) or "/", message)

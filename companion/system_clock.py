"""Is this computer's clock synchronised? The kernel's own answer, from adjtimex(2).

A Pi has no real-time clock: until NTP (or chrony, or systemd-timesyncd) has set it, its
clock starts where it stopped last time, so sessions would be named last week. The
kernel keeps the answer: adjtimex() returns TIME_ERROR while no time service has
disciplined the clock. Read-only (`modes = 0`): any user may ask.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
from collections.abc import Callable
from typing import Any

TIME_ERROR = 5  # adjtimex(2): the clock is not synchronised


class _Timex(ctypes.Structure):
    # struct timex begins with `unsigned int modes`; the rest (~200 bytes) we do not read.
    _fields_ = [("modes", ctypes.c_uint), ("rest", ctypes.c_byte * 512)]


@functools.cache
def _adjtimex() -> Callable[[Any], int] | None:
    try:
        return ctypes.CDLL(ctypes.util.find_library("c"), use_errno=True).adjtimex
    except (OSError, AttributeError):  # not Linux (or no libc): the answer is unknown
        return None


def clock_synchronised() -> bool | None:
    """True when a time service keeps the clock, False when not, None when unknown."""
    adjtimex = _adjtimex()
    if adjtimex is None:
        return None
    state = adjtimex(ctypes.byref(_Timex()))
    if state < 0:
        return None
    return state != TIME_ERROR

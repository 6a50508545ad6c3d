"""A frame counter and render time coded in the top-left corner of a rendered frame.

The digital twin's cameras carry it (`twin_cameras.SimSource`), so that a page can tell,
when it draws a frame, how long ago that frame was rendered (web/video.js reads it from
the decoded picture: render-to-screen latency, benchmarks/glass_to_glass.py).

The code is a grid of `COLS` x `ROWS` cells, each `1/CELLS_PER_WIDTH` of the frame's
width and `1/CELLS_PER_HEIGHT` of its height (square on a 4:3 frame; it survives the
capture's resize to any size), black for 0 and white for 1, row by row, most significant
bit first:

    4 bits marker 1010 | 16 bits frame counter | 32 bits render time, Unix ms mod 2^32 |
    4 bits check: the XOR of the 13 nibbles before it

A cell is flat and at least 8 px wide at 512 px and more, so JPEG keeps it (a block's mean
is what JPEG keeps best); a reader takes each cell's middle half and thresholds its mean
at mid-grey.
"""

from __future__ import annotations

import numpy as np

COLS, ROWS = 14, 4
CELLS_PER_WIDTH, CELLS_PER_HEIGHT = 64, 48
MARKER = 0b1010
_BLACK, _WHITE = 16, 240
TIME_MODULUS_MS = 1 << 32


def _nibbles(counter: int, t_ms32: int) -> list[int]:
    value = (MARKER << 48) | ((counter & 0xFFFF) << 32) | (t_ms32 & 0xFFFFFFFF)
    return [(value >> shift) & 0xF for shift in range(48, -4, -4)]


def stamp_bits(counter: int, t_wall: float) -> np.ndarray:
    """The code's `COLS * ROWS` bits for frame `counter` rendered at Unix time `t_wall`."""
    nibbles = _nibbles(counter, int(round(t_wall * 1000)) % TIME_MODULUS_MS)
    check = 0
    for n in nibbles:
        check ^= n
    nibbles.append(check)
    return np.array([(n >> b) & 1 for n in nibbles for b in (3, 2, 1, 0)], np.uint8)


def _edges(width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    xs = np.round(np.arange(COLS + 1) * width / CELLS_PER_WIDTH).astype(int)
    ys = np.round(np.arange(ROWS + 1) * height / CELLS_PER_HEIGHT).astype(int)
    return xs, ys


def stamp(image: np.ndarray, counter: int, t_wall: float) -> None:
    """Draw the code into `image` (HxWx3 uint8, in place)."""
    bits = stamp_bits(counter, t_wall).reshape(ROWS, COLS)
    xs, ys = _edges(image.shape[1], image.shape[0])
    cells = np.where(bits, _WHITE, _BLACK).astype(np.uint8)
    # Each cell's value repeated over its pixels, in one assignment.
    col_of = np.repeat(np.arange(COLS), np.diff(xs))
    row_of = np.repeat(np.arange(ROWS), np.diff(ys))
    image[: ys[-1], : xs[-1]] = cells[row_of[:, None], col_of[None, :], None]


def read_stamp(image: np.ndarray) -> tuple[int, int] | None:
    """(frame counter, render time in Unix ms mod 2^32) of a stamped frame (HxWx3 or HxW
    uint8, decoded), or None when the corner holds no valid code."""
    gray = image.mean(axis=2) if image.ndim == 3 else image.astype(float)
    xs, ys = _edges(gray.shape[1], gray.shape[0])
    bits = []
    for r in range(ROWS):
        for c in range(COLS):
            x0, x1, y0, y1 = xs[c], xs[c + 1], ys[r], ys[r + 1]
            qx, qy = max((x1 - x0) // 4, 0), max((y1 - y0) // 4, 0)
            cell = gray[y0 + qy : y1 - qy, x0 + qx : x1 - qx]
            bits.append(int(cell.mean() > 128))
    nibbles = [int("".join(map(str, bits[i : i + 4])), 2) for i in range(0, len(bits), 4)]
    check = 0
    for n in nibbles[:-1]:
        check ^= n
    if nibbles[0] != MARKER or check != nibbles[-1]:
        return None
    value = 0
    for n in nibbles[1:-1]:
        value = (value << 4) | n
    return value >> 32, value & 0xFFFFFFFF


def unwrap_ms(t_ms32: int, near_ms: float) -> int:
    """The Unix time in ms whose value mod 2^32 is `t_ms32`, nearest to `near_ms`."""
    base = int(near_ms) - (int(near_ms) % TIME_MODULUS_MS)
    candidates = (base - TIME_MODULUS_MS + t_ms32, base + t_ms32, base + TIME_MODULUS_MS + t_ms32)
    return min(candidates, key=lambda t: abs(t - near_ms))

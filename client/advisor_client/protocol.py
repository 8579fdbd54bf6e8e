"""The websocket's binary answer: a batch of decisions in one compact frame.

A stream opened with ``?format=binary`` answers each text frame of events with one binary frame
(errors stay JSON text frames, as on a JSON stream). It carries the same decisions as the JSON
answer, every float at full precision, in about 25 bytes a decision plus 32 for each piece of
advice, where JSON takes about 280; writing and reading it costs no per-decision formatting.
Both sides use this module (the client imports nothing of the server).

Layout, little-endian; ``n`` decisions of which ``k`` advise::

    offset          size   field
    0               4      magic b"HGA1" (format 1)
    4               4      uint32 n
    8               4      uint32 k
    12              4      uint32 flags: 0, or FLOORS (1) on a map of several floors
    16              8      int64  first_step: decision i is step first_step + i
    24              8      float64 kappa: the session's cost of one piece of advice
    32              8      int64  advice_count before this batch
    40              8      float64 benefit before this batch
    48              8n     float64 kl[n]
    48 + 8n         8n     float64 p_normal[n]
    48 + 16n        32k    float64 advice[k][4] (N, E, S, W), for the advising decisions in order
    48 + 16n + 32k  8n     int32 cell[n][2] (row, col): where each decision was made
    48 + 24n + 32k  n      uint8 advise[n] (1: advice given)

With the flag ``FLOORS`` (a map of several floors, whose actions are six and cells three
coordinates) the same columns are wider: advice[k][6] (N, E, S, W, U, D), 48 bytes a row, and
cell[n][3] (floor, row, col), 12 bytes; a one-floor map's frames are as above, byte for byte.

The running figures are not sent but follow exactly, as the service computes them:
``advice_count[i]`` = count before + the number of advising decisions up to i,
``total[i] = kappa * advice_count[i]``, and ``benefit[i]`` = benefit before + the KL of each
advising decision up to i, summed in order (``numpy.cumsum`` adds in order, so the bits are
the service's). :func:`unpack` does this; ``tests/service/test_binary.py`` checks that the
decoded decisions equal the JSON answers.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

MAGIC = b"HGA1"
#: the flag of a frame of a map of several floors: six actions, cells [floor, row, col]
FLOORS = 1
#: (actions, a cell's coordinates) of a frame without and with FLOORS
WIDTHS = {0: (4, 2), FLOORS: (6, 3)}
HEADER = struct.Struct("<4sIIIqdqd")
FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]


class FrameError(ValueError):
    """Bytes that are not a binary decision frame of this format."""


def frame_size(n: int, k: int, flags: int = 0) -> int:
    actions, coordinates = WIDTHS[flags]
    return HEADER.size + (17 + 4 * coordinates) * n + 8 * actions * k


def pack(
    first_step: int, kappa: float, count_before: int, benefit_before: float,
    kl: FloatArray, p_normal: FloatArray, advice: FloatArray, cells: npt.NDArray[np.int32],
    advise: BoolArray,
) -> bytes:  # fmt: skip
    """The frame for ``n`` decisions: ``advice`` holds the ``k`` rows of the advising ones
    (4 actions, or 6 on a map of several floors), ``cells`` the (n, 2) int32 cells (or
    (n, 3)); a frame of six actions carries the flag :data:`FLOORS`."""
    n, k = len(kl), len(advice)
    flags = FLOORS if np.shape(cells)[1:] == (3,) else 0
    parts = [HEADER.pack(MAGIC, n, k, flags, first_step, kappa, count_before, benefit_before)]
    columns = ((kl, "<f8"), (p_normal, "<f8"), (advice, "<f8"), (cells, "<i4"), (advise, "u1"))
    parts += [np.ascontiguousarray(column, dtype=dtype).tobytes() for column, dtype in columns]
    frame = b"".join(parts)
    assert len(frame) == frame_size(n, k, flags), "columns of the wrong lengths"
    return frame


@dataclass(frozen=True, slots=True)
class DecisionFrame:
    """The decisions of one binary frame, as arrays (index i: the i-th event's decision)."""

    step: IntArray
    cell: npt.NDArray[np.int32]  # (n, 2) row, col; (n, 3) floor, row, col with FLOORS
    advise: BoolArray
    advice: FloatArray  # (n, 4) N, E, S, W (n, 6 with U, D); NaN where no advice was given
    kl: FloatArray
    p_normal: FloatArray
    advice_count: IntArray
    total: FloatArray
    benefit: FloatArray

    def __len__(self) -> int:
        return len(self.step)

    def to_dicts(self) -> list[dict[str, Any]]:
        """The decisions in the JSON answer's shape (equal to it, float for float)."""
        columns = zip(
            self.step.tolist(), self.cell.tolist(), self.advise.tolist(), self.advice.tolist(),
            self.kl.tolist(), self.p_normal.tolist(), self.advice_count.tolist(),
            self.total.tolist(), self.benefit.tolist(), strict=True,
        )  # fmt: skip
        return [
            {
                "step": step,
                "state": cell,
                "advise": advise,
                "advice": dict(zip("NESWUD", advice, strict=False)) if advise else None,
                "kl": kl,
                "p_normal": p,
                "cost": {"advice_count": count, "total": total, "benefit": benefit},
            }
            for step, cell, advise, advice, kl, p, count, total, benefit in columns
        ]


def unpack(frame: bytes) -> DecisionFrame:
    """A binary frame's decisions; FrameError if the bytes are not one."""
    if len(frame) < HEADER.size:
        raise FrameError(f"{len(frame)} bytes: shorter than the {HEADER.size}-byte header")
    magic, n, k, flags, first, kappa, count0, benefit0 = HEADER.unpack_from(frame)
    if magic != MAGIC:
        raise FrameError(f"not a decision frame of format 1 (magic {magic!r})")
    if flags not in WIDTHS:
        raise FrameError(f"flags {flags}: this client reads 0 and {FLOORS} (FLOORS)")
    actions, coordinates = WIDTHS[flags]
    if k > n or len(frame) != frame_size(n, k, flags):
        raise FrameError(f"{len(frame)} bytes for {n} decisions with {k} advising")
    at = HEADER.size

    def column(dtype: type[np.generic], count: int) -> Any:
        nonlocal at
        out = np.frombuffer(frame, dtype=np.dtype(dtype).newbyteorder("<"), count=count, offset=at)
        at += out.nbytes
        return out

    kl, p_normal = column(np.float64, n), column(np.float64, n)
    given = column(np.float64, actions * k).reshape(k, actions)
    cell = column(np.int32, coordinates * n).reshape(n, coordinates)
    advise = column(np.uint8, n).astype(bool)
    if int(advise.sum()) != k:
        raise FrameError(f"{int(advise.sum())} advising flags for {k} rows of advice")
    advice = np.full((n, actions), np.nan)
    advice[advise] = given
    count = count0 + np.cumsum(advise, dtype=np.int64)
    gains = np.concatenate(([benefit0], np.where(advise, kl, 0.0)))
    return DecisionFrame(
        first + np.arange(n, dtype=np.int64), cell, advise, advice, kl, p_normal, count,
        kappa * count, np.cumsum(gains)[1:],
    )  # fmt: skip

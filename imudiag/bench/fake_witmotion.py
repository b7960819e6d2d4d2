"""A fake WitMotion WT901 on a pty: the protocol's frames from the project's simulator.

:func:`encode_frames` writes each sample as the device does: a time frame (0x50,
optional), an acceleration frame (0x51: v = g / 16 x 32768, temperature in 0.01 degC)
and an angular-rate frame (0x52: v = deg/s / 2000 x 32768), each ``0x55, type, 4 x
int16 LE, low byte of the sum``. :func:`simulated_chunks` feeds a
:class:`~imudiag.bench.pty.BoardWriter` from :func:`.simulated.simulated_blocks` (a
certificate in deg/s and g, e.g. ``config/datasheets/witmotion-wt901.yaml``). It never
imports the driver it stands in for.
"""

from __future__ import annotations

import datetime as dt
from collections.abc import Iterable, Iterator

import numpy as np

from imudiag.samples import SampleBlock

HEAD = 0x55
_EPOCH = dt.datetime(2026, 1, 1)


def _frames(ftype: int, words: np.ndarray) -> np.ndarray:
    """(N, 11) frames of type ``ftype`` from (N, 8) payload bytes."""
    n = words.shape[0]
    out = np.zeros((n, 11), np.uint8)
    out[:, 0] = HEAD
    out[:, 1] = ftype
    out[:, 2:10] = words
    out[:, 10] = out[:, :10].sum(axis=1, dtype=np.int64) & 0xFF
    return out


def _int16_bytes(values: np.ndarray) -> np.ndarray:
    v = np.clip(np.rint(values), -32768, 32767).astype("<i2")
    return np.ascontiguousarray(v).view(np.uint8).reshape(v.shape[0], -1)


def encode_frames(block: SampleBlock, with_time: bool = True, start: dt.datetime = _EPOCH) -> bytes:
    """The device's bytes for ``block`` (gyro deg/s, accel g, temp degC, t s)."""
    n = len(block)
    temp = block.temp if block.temp is not None else np.full(n, 25.0)
    acc = _frames(0x51, _int16_bytes(np.column_stack([block.accel / 16.0 * 32768.0, temp * 100])))
    gyr = _frames(
        0x52, _int16_bytes(np.column_stack([block.gyro / 2000.0 * 32768.0, np.full(n, 3300)]))
    )
    parts = [acc, gyr]
    if with_time:
        payload = np.zeros((n, 8), np.uint8)
        for i, t in enumerate(block.t.tolist()):
            w = start + dt.timedelta(milliseconds=round(t * 1000))
            payload[i, :6] = [w.year - 2000, w.month, w.day, w.hour, w.minute, w.second]
            ms = w.microsecond // 1000
            payload[i, 6:8] = [ms & 0xFF, ms >> 8]
        parts.insert(0, _frames(0x50, payload))
    return np.stack(parts, axis=1).tobytes()


def simulated_chunks(blocks: Iterable[SampleBlock], with_time: bool = True) -> Iterator[bytes]:
    """Byte chunks for a BoardWriter, one per simulated block."""
    for block in blocks:
        yield encode_frames(block, with_time)

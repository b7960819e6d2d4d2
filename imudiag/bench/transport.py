"""Transport faults on wire-protocol bytes, built so the receiver's counters are exact.

Each function returns the bytes to send and the counter increments a
receiver following spec/wire-protocol.md must show for them:

- garbage: ``n`` random bytes that never contain the sync's first byte 0xAA
  (a chance sync inside the garbage could pass for a frame header and add a CRC
  error), so ``skipped_bytes`` grows by exactly ``n``; fully random garbage
  still adds exactly ``n`` skipped bytes (a failed candidate is rescanned from
  its second byte) but an unknown number of CRC errors;
- corrupted frames: one payload byte of each sample frame flipped, choosing a
  byte whose flip leaves no sync pattern inside the frame, so each one adds a
  CRC error, 40 skipped bytes and, at the next good frame, one lost frame;
- lost frames: frames never sent (any type) add one lost frame each;
- duplicates: the last frame sent again adds one duplicate each.
"""

from __future__ import annotations

import numpy as np

from imudiag.drivers.wire import SAMPLE_FRAME_SIZE, SYNC, TYPE_SAMPLE

HEADER_SIZE = 4  #: sync, type, length
CRC_SIZE = 2
_SYNC0 = SYNC[0]


def frame_spans(data: bytes) -> list[tuple[int, int, int]]:
    """(offset, type, size in bytes) of each frame of a clean, frame-aligned byte string.

    Walks the length fields frame by frame: for the short pieces an injection
    touches, never for the whole stream. ValueError if ``data`` is not whole frames.
    """
    spans: list[tuple[int, int, int]] = []
    pos = 0
    while pos < len(data):
        if data[pos : pos + 2] != SYNC or pos + HEADER_SIZE > len(data):
            raise ValueError(f"no frame at byte {pos} of a {len(data)}-byte piece")
        size = HEADER_SIZE + data[pos + 3] + CRC_SIZE
        if pos + size > len(data):
            raise ValueError(f"frame at byte {pos} runs past the end of the piece")
        spans.append((pos, data[pos + 2], size))
        pos += size
    return spans


def garbage(n: int, rng: np.random.Generator, sync_free: bool = True) -> bytes:
    """``n`` uniformly random bytes: from 0x00..0xFF without 0xAA when ``sync_free``
    (the counters are then exact), else any byte (sync patterns included)."""
    if not sync_free:
        return rng.integers(0, 256, size=int(n), dtype=np.uint16).astype(np.uint8).tobytes()
    x = rng.integers(0, 255, size=int(n), dtype=np.uint16)
    x[x >= _SYNC0] += 1
    return x.astype(np.uint8).tobytes()


def corrupt_sample_frames(data: bytes) -> tuple[bytes, int]:
    """``data`` (whole frames) with every sample frame's CRC broken; returns (bytes, frames
    corrupted). A sample frame whose every possible flip would leave a sync pattern inside
    it is sent intact (not counted)."""
    out = bytearray(data)
    corrupted = 0
    for pos, ftype, size in frame_spans(data):
        if ftype != TYPE_SAMPLE or size != SAMPLE_FRAME_SIZE:
            continue
        for offset in range(10, SAMPLE_FRAME_SIZE - CRC_SIZE):  # the six raw outputs first
            trial = bytearray(out[pos : pos + size])
            trial[offset] ^= 0xFF
            if bytes(trial).find(SYNC, 1) < 0:
                out[pos : pos + size] = trial
                corrupted += 1
                break
    return bytes(out), corrupted


def count_frames(data: bytes) -> tuple[int, int]:
    """(frames of any type, sample frames) in ``data`` (whole frames)."""
    spans = frame_spans(data)
    return len(spans), sum(1 for _, t, s in spans if t == TYPE_SAMPLE and s == SAMPLE_FRAME_SIZE)


def last_frame(data: bytes) -> bytes:
    """The last whole frame of ``data`` (whole frames); b"" when empty."""
    spans = frame_spans(data)
    if not spans:
        return b""
    pos, _, size = spans[-1]
    return data[pos : pos + size]


__all__ = ["corrupt_sample_frames", "count_frames", "frame_spans", "garbage", "last_frame"]

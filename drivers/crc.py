"""CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, xorout 0).

The wire protocol's frame check (spec/wire-protocol.md). Two forms: a scalar
one for a single message (device-info frames, tests) and a vectorised one
checking many equal-length frames at once for the decoder's hot path. The
vectorised form consumes 16 bits per step through a 65536-entry table: for a
16-bit CRC the register after 16 message bits is a function of
``register ^ next 16 bits`` alone, so each step is one XOR and one gather over
all frames. For a single message and for a few frames (a daemon's read at
1 kHz holds about 5) the standard library's ``binascii.crc_hqx`` with init
0xFFFF, which is this CRC in C, costs less than one numpy call.
"""

from __future__ import annotations

import binascii

import numpy as np

POLY = 0x1021
INIT = 0xFFFF
CHECK_VALUE = 0x29B1  #: CRC of b"123456789"


def _byte_table() -> np.ndarray:
    """T8[b]: the register after shifting byte ``b`` (as the high byte) through 8 steps."""
    c = np.arange(256, dtype=np.uint32) << 8
    for _ in range(8):
        c = np.where(c & 0x8000, (c << 1) ^ POLY, c << 1) & 0xFFFF
    return c.astype(np.uint16)


def _word_table_swapped(t8: np.ndarray) -> np.ndarray:
    """Table for 16 bits per step, with register and index in byte-swapped form.

    With ``s = swap(register)`` and ``w`` a little-endian u16 read of the next
    two message bytes, the update is ``s = T[s ^ w]`` (no byte swapping of the
    data needed); the CRC is ``swap(s)`` at the end.
    """
    v = np.arange(65536, dtype=np.uint32)
    c = v.copy()
    for _ in range(2):
        c = ((c << 8) & 0xFFFF) ^ t8[(c >> 8) & 0xFF]
    swap = ((v >> 8) | (v << 8)) & 0xFFFF
    t16 = c.astype(np.uint32)
    out = t16[swap]
    return (((out >> 8) | (out << 8)) & 0xFFFF).astype(np.uint16)


_T8 = _byte_table()
_T8_LIST = [int(x) for x in _T8]
_T16S = _word_table_swapped(_T8)
#: Rows per pass of :func:`crc16_rows`: ~2.6 MB of 40-byte frames, so that the
#: column-by-column passes hit the cache instead of memory.
_BLOCK_ROWS = 65536
#: Up to this many rows :func:`crc16_rows` checks frame by frame with ``binascii.crc_hqx``
#: (about 0.3 us a frame, against some 40 numpy calls for the table passes).
_FEW_ROWS = 32


def crc16_ccitt_false(data: bytes | bytearray | memoryview) -> int:
    """CRC-16/CCITT-FALSE of ``data`` (one message), 0..65535."""
    return binascii.crc_hqx(bytes(data), INIT)


def crc16_ccitt_false_python(data: bytes | bytearray | memoryview) -> int:
    """The same CRC one table step per byte in Python (the reference the C one is tested on)."""
    crc = INIT
    table = _T8_LIST
    for b in bytes(data):
        crc = ((crc << 8) & 0xFFFF) ^ table[(crc >> 8) ^ b]
    return crc


def _swap16(x: np.ndarray) -> np.ndarray:
    return (x >> 8) | (x << 8)


def crc16_rows(rows: np.ndarray) -> np.ndarray:
    """CRC-16/CCITT-FALSE of each row of ``rows`` (M, L) uint8 -> (M,) uint16.

    Vectorised over rows: L/2 table steps, each one XOR and one gather over M.
    Rows may be a strided view (e.g. ``frames[:, 2:38]``) as long as the last
    axis is contiguous.
    """
    rows = np.asarray(rows)
    if rows.dtype != np.uint8 or rows.ndim != 2:
        raise ValueError(f"crc16_rows needs a 2-D uint8 array, got {rows.dtype} {rows.shape}")
    m, length = rows.shape
    if m > _BLOCK_ROWS:  # column passes stay in cache: one block of rows at a time
        out = np.empty(m, dtype=np.uint16)
        for i in range(0, m, _BLOCK_ROWS):
            out[i : i + _BLOCK_ROWS] = crc16_rows(rows[i : i + _BLOCK_ROWS])
        return out
    if m <= _FEW_ROWS:
        data = np.ascontiguousarray(rows).tobytes()
        return np.array(
            [binascii.crc_hqx(data[i : i + length], INIT) for i in range(0, m * length, length)],
            dtype=np.uint16,
        )
    crc = np.full(m, INIT, dtype=np.uint16)
    if rows.strides[1] != 1:
        rows = np.ascontiguousarray(rows)
    start = 0
    if length % 2:
        # odd length: the first byte through the byte table, then 16 bits per step
        idx = ((crc >> 8) ^ rows[:, 0]).astype(np.uint8)
        crc = ((crc << 8) ^ _T8[idx]).astype(np.uint16)
        start = 1
    s = _swap16(crc)
    if length - start:
        try:
            words = rows[:, start:].view("<u2")
        except ValueError:  # a strided layout numpy cannot reinterpret
            words = np.ascontiguousarray(rows[:, start:]).view("<u2")
        tmp = np.empty(m, dtype=np.uint16)
        for k in range(words.shape[1]):
            np.bitwise_xor(s, words[:, k], out=tmp)
            _T16S.take(tmp, out=s, mode="wrap")
    return _swap16(s)

"""The IMU-USB wire protocol, version 1 (spec/wire-protocol.md): encoder and decoder.

Frames: ``AA 55 | type | length | seq u16 | time_us u32 | payload | crc u16``,
little-endian, CRC-16/CCITT-FALSE over offsets 2 .. 4+length-1. A sample frame
(type 0x01, length 34) is 40 bytes and carries six i32 raw ADC outputs (gyro
x y z, accel x y z, counts), temperature (i16, 0.01 degC) and flags (u16).

:class:`Decoder` is incremental and vectorised: runs of 40-byte-aligned sample
frames are checked and decoded with one structured-dtype view and one table CRC
pass; only resynchronisation events (garbage, bad CRC, device-info or unknown
frames) take a Python step each.

Byte accounting (exact, see :attr:`Decoder.frame_bytes`)::

    counters.bytes == frame_bytes + counters.skipped_bytes + pending_bytes

where ``frame_bytes`` are the bytes of every frame whose CRC was good (sample,
info, unknown, duplicates included) and ``skipped_bytes`` every other byte the
decoder stepped over, including the bytes of frames whose CRC failed (a bad
frame is rescanned from its second byte, so a false sync inside garbage never
hides a real frame).
"""

from __future__ import annotations

import binascii
import json
import struct
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from imudiag.samples import SampleBlock

from .crc import crc16_ccitt_false, crc16_rows


@dataclass
class Counters:
    """Receiver counters of spec/wire-protocol.md, cumulative since the source was made."""

    bytes: int = 0  #: bytes read from the transport
    frames: int = 0  #: good sample frames delivered
    crc_errors: int = 0  #: frames dropped for a bad CRC
    skipped_bytes: int = 0  #: bytes skipped while resynchronising
    lost: int = 0  #: frames missing by seq
    duplicates: int = 0  #: repeated seq, dropped

    def as_dict(self) -> dict[str, int]:
        """The counters as the status JSON ``counters`` object."""
        # built by hand: dataclasses.asdict deep-copies recursively and was a tenth of
        # the daemon's per-turn cost (benchmarks/latency.py profile)
        return {
            "bytes": self.bytes,
            "frames": self.frames,
            "crc_errors": self.crc_errors,
            "skipped_bytes": self.skipped_bytes,
            "lost": self.lost,
            "duplicates": self.duplicates,
        }


SYNC = b"\xaa\x55"
TYPE_SAMPLE = 0x01
TYPE_INFO = 0x02
SAMPLE_LENGTH = 34  #: the length field of a sample frame, bytes
SAMPLE_FRAME_SIZE = 40  #: bytes of a whole sample frame
HEADER_SIZE = 4  #: sync, type, length
CRC_SIZE = 2
MIN_SEQ_LENGTH = 6  #: a frame whose length is at least this carries seq and time_us
MAX_LENGTH = 255  #: the length field is one byte
TEMP_SCALE_C = 0.01  #: degC per count of the temp field
SEQ_MODULUS = 1 << 16
TIME_MODULUS = 1 << 32  #: time_us wraps after 2**32 us (about 71.6 min)

#: One sample frame as a numpy structured dtype (little-endian, packed, 40 bytes).
FRAME_DTYPE = np.dtype(
    [
        ("sync", "<u2"),
        ("type", "u1"),
        ("length", "u1"),
        ("seq", "<u2"),
        ("time_us", "<u4"),
        ("raw", "<i4", (6,)),
        ("temp", "<i2"),
        ("flags", "<u2"),
        ("crc", "<u2"),
    ]
)
assert FRAME_DTYPE.itemsize == SAMPLE_FRAME_SIZE
_SAMPLE_HEADER = SYNC + bytes([TYPE_SAMPLE, SAMPLE_LENGTH])
#: a sample frame's header, seq, time_us and CRC (the 28 bytes between are read by numpy)
_FRAME_FIELDS = struct.Struct("<4sHI28xH")
assert _FRAME_FIELDS.size == SAMPLE_FRAME_SIZE
#: reads up to this many bytes (a daemon's read) are decoded frame by frame in plain
#: Python when they hold nothing but sample frames: fewer calls than the vectorised path
_FEW_FRAMES_BYTES = 128 * SAMPLE_FRAME_SIZE

_SAMPLE_HEADER_U32 = int.from_bytes(_SAMPLE_HEADER, "little")

_I32 = np.iinfo(np.int32)
_I16 = np.iinfo(np.int16)


def _int_array(values: Any, name: str, shape_tail: tuple[int, ...] = ()) -> np.ndarray:
    """``values`` as int64, rounding floats; a NaN/inf names the argument."""
    a = np.asarray(values)
    if a.dtype.kind == "f":
        if not np.all(np.isfinite(a)):
            raise ValueError(f"encode: {name} has non-finite values")
        a = np.rint(a)
    elif a.dtype.kind not in "iub":
        raise ValueError(f"encode: {name} must be numeric, got {a.dtype}")
    return a.astype(np.int64)


def encode_samples(
    seq_start: int,
    time_us: np.ndarray,
    raw: np.ndarray,
    temp_c: np.ndarray | None = None,
    flags: np.ndarray | None = None,
) -> bytes:
    """Sample frames for N samples, as the board sends them.

    seq_start: seq of the first frame (then +1 per frame, wrapping at 65536).
    time_us: (N,) device clock, microseconds (taken modulo 2**32, as the board wraps).
    raw: (N, 6) raw ADC outputs gx gy gz ax ay az, counts, within int32.
    temp_c: (N,) board temperature, degC (sent in 0.01 degC; 0 when None).
    flags: (N,) flag bits (0 when None).
    """
    raw_i = _int_array(raw, "raw")
    if raw_i.ndim != 2 or raw_i.shape[1] != 6:
        raise ValueError(f"encode: raw must be (N, 6), got {raw_i.shape}")
    n = raw_i.shape[0]
    t = _int_array(time_us, "time_us").reshape(-1)
    if t.shape[0] != n:
        raise ValueError(f"encode: time_us has {t.shape[0]} values, raw has {n} rows")
    if raw_i.size and (raw_i.min() < _I32.min or raw_i.max() > _I32.max):
        raise ValueError("encode: raw outputs outside the int32 range of the wire format")
    frames = np.zeros(n, dtype=FRAME_DTYPE)
    frames["sync"] = int.from_bytes(SYNC, "little")
    frames["type"] = TYPE_SAMPLE
    frames["length"] = SAMPLE_LENGTH
    frames["seq"] = (int(seq_start) + np.arange(n, dtype=np.int64)) % SEQ_MODULUS
    frames["time_us"] = t % TIME_MODULUS
    frames["raw"] = raw_i
    if temp_c is not None:
        temp = _int_array(np.asarray(temp_c, dtype=float) / TEMP_SCALE_C, "temp_c").reshape(-1)
        if temp.shape[0] != n:
            raise ValueError(f"encode: temp_c has {temp.shape[0]} values, expected {n}")
        if temp.size and (temp.min() < _I16.min or temp.max() > _I16.max):
            raise ValueError("encode: temp_c outside -327.68 .. 327.67 degC")
        frames["temp"] = temp
    if flags is not None:
        fl = _int_array(flags, "flags").reshape(-1)
        if fl.shape[0] != n:
            raise ValueError(f"encode: flags has {fl.shape[0]} values, expected {n}")
        if fl.size and (fl.min() < 0 or fl.max() > 0xFFFF):
            raise ValueError("encode: flags outside 0 .. 0xFFFF")
        frames["flags"] = fl
    rows = frames.view(np.uint8).reshape(n, SAMPLE_FRAME_SIZE)
    frames["crc"] = crc16_rows(rows[:, 2 : SAMPLE_FRAME_SIZE - CRC_SIZE])
    return frames.tobytes()


def encode_frame(frame_type: int, seq: int, time_us: int, payload: bytes) -> bytes:
    """One frame of any type: header, seq, time_us (us, mod 2**32), ``payload``, CRC."""
    length = MIN_SEQ_LENGTH + len(payload)
    if length > MAX_LENGTH:
        raise ValueError(f"encode: frame payload of {len(payload)} bytes exceeds the 249 maximum")
    body = (
        bytes([frame_type & 0xFF, length])
        + (int(seq) % SEQ_MODULUS).to_bytes(2, "little")
        + (int(time_us) % TIME_MODULUS).to_bytes(4, "little")
        + bytes(payload)
    )
    return SYNC + body + crc16_ccitt_false(body).to_bytes(2, "little")


def encode_info(seq: int, time_us: int, info: dict[str, Any]) -> bytes:
    """A device-info frame (type 0x02) carrying ``info`` as compact UTF-8 JSON."""
    payload = json.dumps(info, separators=(",", ":"), ensure_ascii=False).encode("utf-8")
    return encode_frame(TYPE_INFO, seq, time_us, payload)


# -- decoder -----------------------------------------------------------------

_KIND_SAMPLE, _KIND_INFO, _KIND_OTHER = 0, 1, 2


class PendingBytes:
    """The bytes a decoder holds back between reads (a frame cut by the read), with the
    byte counters: shared by the native decoder and the device protocols' decoders."""

    counters: Counters
    _pending: bytes

    @property
    def pending_bytes(self) -> int:
        """Bytes held back waiting for the rest of a frame."""
        return len(self._pending)

    def _joined(self, data: bytes | bytearray | memoryview) -> bytes:
        """The held-back bytes and ``data``, counted as read."""
        data = bytes(data)
        self.counters.bytes += len(data)
        return self._pending + data if self._pending else data

    def drop_pending(self) -> None:
        """Discard held-back bytes (after a reconnect), counting them as skipped."""
        self.counters.skipped_bytes += len(self._pending)
        self._pending = b""


class Decoder(PendingBytes):
    """Incremental wire-protocol decoder: bytes in, :class:`SampleBlock` out.

    Feed chunks of any size; frames may straddle chunks. Keeps the receiver
    counters of the spec in :attr:`counters` (a :class:`Counters`, which may be
    shared with the owning source). Output samples carry ``t`` = unwrapped
    device time in seconds, raw outputs in counts (float), ``temp`` in degC,
    ``flags`` and ``seq`` unwrapped (monotonic int).

    Sequence rules, over frames of every type in stream order: a seq step of
    +1 is normal; +k counts k-1 lost frames; a repeated seq is a duplicate and
    dropped. A seq or time_us that goes backwards (board restart, or a clock
    step) re-anchors the timeline: the frame gets the previous unwrapped time
    plus the last normal frame interval, the unwrapped seq continues by one,
    nothing is counted as lost, and :attr:`restarts` counts the event.
    """

    def __init__(self, counters: Counters | None = None) -> None:
        self.counters = counters if counters is not None else Counters()
        self.device_info: dict[str, Any] = {}
        self.info_frames = 0  #: device-info frames received (CRC good, not duplicates)
        self.info_errors = 0  #: info frames with a good CRC whose payload is not a JSON object
        self.unknown_frames = 0  #: frames of other types, skipped by their length
        self.restarts = 0  #: seq/time discontinuities (see class doc)
        self.frame_bytes = 0  #: bytes of good-CRC frames of any type, duplicates included
        self.resync_steps = 0  #: steps taken off the vectorised path (0 for a clean aligned stream)
        self._pending = b""
        self._scan_buf = b""  # the buffer being decoded (info/unknown frame payloads)
        self._last_seq: int | None = None  # raw u16 of the last accepted frame
        self._last_time = 0  # raw u32 of the last accepted frame
        self._seq_abs = 0  # unwrapped seq of the last accepted frame
        self._time_abs = 0  # unwrapped time, us, of the last accepted frame
        self._last_dt_us = 0  # last normal frame interval, us

    def feed(self, data: bytes | bytearray | memoryview) -> SampleBlock:
        """Decode ``data`` (plus any held-back bytes); returns the complete good samples."""
        return self._decode(self._joined(data), final=False)

    def finish(self) -> SampleBlock:
        """End of stream: decode what can be decoded and count the rest as skipped."""
        buf, self._pending = self._pending, b""
        return self._decode(buf, final=True)

    # -- byte level --------------------------------------------------------

    def _decode_few(self, buf: bytes) -> SampleBlock | None:
        """A daemon's read (a few sample frames, maybe the start of the next) in plain
        Python: the header, the C CRC and the seq/time steps frame by frame, then one
        structured view. The result is the general path's; None (nothing changed) when
        the bytes need it: anything but good sample frames in steady order, or a tail
        that is not the start of a sample frame."""
        size = SAMPLE_FRAME_SIZE
        m = len(buf) // size
        tail = buf[m * size :]
        if m == 0 or not _SAMPLE_HEADER.startswith(tail[:HEADER_SIZE]):
            return None
        last_seq, last_time = self._last_seq, self._last_time
        if last_seq is None:
            return None
        crc_hqx = binascii.crc_hqx
        header = _SAMPLE_HEADER
        t_abs = self._time_abs
        times = []
        last_dt = self._last_dt_us
        p = 2
        for head, seq, time_us, crc in _FRAME_FIELDS.iter_unpack(buf[: m * size]):
            if head != header or crc_hqx(buf[p : p + size - 4], 0xFFFF) != crc:
                return None
            p += size
            dt = (time_us - last_time) % TIME_MODULUS
            if (seq - last_seq) % SEQ_MODULUS != 1 or dt >= TIME_MODULUS // 2:
                return None
            last_seq, last_time = seq, time_us
            t_abs += dt
            times.append(t_abs)
            if dt > 0:
                last_dt = dt
        # every frame good and in order: commit, as _scan and _timeline_steady would
        if tail:
            self.resync_steps += 1  # the general path's one step that keeps the tail
        self._pending = tail
        self.frame_bytes += m * size
        self._last_seq, self._last_time = last_seq, last_time
        self._seq_abs += m
        self._time_abs = t_abs
        self._last_dt_us = last_dt
        frames = np.frombuffer(buf, FRAME_DTYPE, count=m)
        self.counters.frames += m
        raw = frames["raw"].astype(np.float64)
        return SampleBlock(
            t=np.array(times, dtype=np.float64) * 1e-6,
            gyro=raw[:, :3],
            accel=raw[:, 3:],
            temp=frames["temp"] * TEMP_SCALE_C,
            flags=frames["flags"].astype(np.uint16),
            seq=np.arange(self._seq_abs - m + 1, self._seq_abs + 1, dtype=np.int64),
        )

    def _decode(self, buf: bytes, final: bool) -> SampleBlock:
        if len(buf) <= _FEW_FRAMES_BYTES and not final:
            block = self._decode_few(buf)
            if block is not None:
                return block
        items, pos = self._scan(buf, final)
        self._pending = buf[pos:]
        if final:
            self.counters.skipped_bytes += len(self._pending)
            self._pending = b""
        if not items:
            return SampleBlock.empty()
        self._scan_buf = buf
        try:
            return self._assemble(items)
        finally:
            self._scan_buf = b""

    def _scan(self, buf: bytes, final: bool) -> tuple[list[tuple[int, Any]], int]:
        """Split ``buf`` into accepted frames, in stream order.

        Returns items ``(kind, payload)``: for samples a (k, 40) uint8 array of
        consecutive good sample frames, for info/other frames ``(offset, length)``;
        and the position up to which ``buf`` is consumed.
        """
        c = self.counters
        arr = np.frombuffer(buf, dtype=np.uint8)
        n = len(buf)
        pos = 0
        items: list[tuple[int, Any]] = []
        while pos < n:
            m = (n - pos) // SAMPLE_FRAME_SIZE
            if m and buf.startswith(_SAMPLE_HEADER, pos):
                pos = self._scan_aligned(buf, arr, pos, m, items)
                continue
            # one resynchronisation step
            self.resync_steps += 1
            idx = buf.find(SYNC, pos)
            if idx < 0:
                end = n - 1 if (not final and buf[-1] == SYNC[0]) else n
                c.skipped_bytes += end - pos
                pos = end
                break
            c.skipped_bytes += idx - pos
            pos = idx
            if n - pos < HEADER_SIZE:
                if final:
                    c.skipped_bytes += n - pos
                    pos = n
                break
            ftype, length = buf[pos + 2], buf[pos + 3]
            if (ftype == TYPE_SAMPLE and length != SAMPLE_LENGTH) or (
                ftype == TYPE_INFO and length < MIN_SEQ_LENGTH
            ):
                c.skipped_bytes += 1
                pos += 1
                continue
            total = HEADER_SIZE + length + CRC_SIZE
            if n - pos < total:
                if final:  # never completed: not a frame
                    c.skipped_bytes += 1
                    pos += 1
                    continue
                break
            end_body = pos + HEADER_SIZE + length
            stored = buf[end_body] | (buf[end_body + 1] << 8)
            if crc16_ccitt_false(buf[pos + 2 : end_body]) != stored:
                c.crc_errors += 1
                c.skipped_bytes += 1
                pos += 1
                continue
            self.frame_bytes += total
            if ftype == TYPE_SAMPLE:
                items.append((_KIND_SAMPLE, arr[pos : pos + total].reshape(1, total)))
            else:
                kind = _KIND_INFO if ftype == TYPE_INFO else _KIND_OTHER
                items.append((kind, (pos, length)))
            pos += total
        return items, pos

    def _scan_aligned(
        self, buf: bytes, arr: np.ndarray, pos: int, m: int, items: list[tuple[int, Any]]
    ) -> int:
        """Vectorised path over up to ``m`` consecutive sample frames at ``pos``."""
        c = self.counters
        size = SAMPLE_FRAME_SIZE
        block = arr[pos : pos + m * size].reshape(m, size)
        hdr = block[:, :HEADER_SIZE].view("<u4")[:, 0]
        bad_hdr = np.flatnonzero(hdr != _SAMPLE_HEADER_U32)
        run = int(bad_hdr[0]) if bad_hdr.size else m
        rows = block[:run]
        crc = crc16_rows(rows[:, 2 : size - CRC_SIZE])
        stored = rows[:, size - CRC_SIZE :].view("<u2")[:, 0]
        bad = np.flatnonzero(crc != stored)
        start = 0
        for j in bad.tolist():
            if j > start:
                items.append((_KIND_SAMPLE, rows[start:j]))
                self.frame_bytes += (j - start) * size
            c.crc_errors += 1
            p = pos + j * size
            inner = buf.find(SYNC, p + 1, p + size + 1)
            # a failed frame ending the buffer on 0xAA may hold the first sync byte of a
            # frame whose 0x55 is in the next chunk (found by fuzz/: the output depended
            # on the chunking): rescan it byte by byte too, which keeps that byte pending
            straddles = p + size == len(buf) and buf[-1] == SYNC[0]
            if (inner != -1 and inner < p + size) or straddles:
                # a sync inside the failed frame: rescan from there byte by byte
                c.skipped_bytes += 1
                return p + 1
            c.skipped_bytes += size
            start = j + 1
        if run > start:
            items.append((_KIND_SAMPLE, rows[start:run]))
            self.frame_bytes += (run - start) * size
        return pos + run * size

    # -- frame level -------------------------------------------------------

    def _assemble(self, items: Sequence[tuple[int, Any]]) -> SampleBlock:
        """Sequence accounting over all accepted frames, then the sample block."""
        if len(items) == 1 and items[0][0] == _KIND_SAMPLE:
            frames = items[0][1].view(FRAME_DTYPE)[:, 0]
            seq16 = frames["seq"]
            time32 = frames["time_us"]
            is_sample = None
            others: list[tuple[int, int, Any]] = []
        else:
            sample_rows = [p for k, p in items if k == _KIND_SAMPLE]
            frames = (
                np.concatenate(sample_rows).view(FRAME_DTYPE)[:, 0]
                if sample_rows
                else np.zeros(0, dtype=FRAME_DTYPE)
            )
            seq_parts: list[np.ndarray] = []
            time_parts: list[np.ndarray] = []
            kind_parts: list[np.ndarray] = []
            others = []  # (index among sequenced frames or -1, kind, (offset, length))
            n_seq = 0
            offset = 0
            for kind, payload in items:
                if kind == _KIND_SAMPLE:
                    f = frames[offset : offset + payload.shape[0]]
                    offset += payload.shape[0]
                    seq_parts.append(f["seq"])
                    time_parts.append(f["time_us"])
                    kind_parts.append(np.zeros(f.shape[0], dtype=np.uint8))
                    n_seq += f.shape[0]
                else:
                    others.append((n_seq if payload[1] >= MIN_SEQ_LENGTH else -1, kind, payload))
                    if payload[1] >= MIN_SEQ_LENGTH:
                        s, t = self._frame_seq_time(payload)
                        seq_parts.append(np.array([s], dtype=np.uint16))
                        time_parts.append(np.array([t], dtype=np.uint32))
                        kind_parts.append(np.array([kind], dtype=np.uint8))
                        n_seq += 1
            seq16 = np.concatenate(seq_parts) if seq_parts else np.zeros(0, np.uint16)
            time32 = np.concatenate(time_parts) if time_parts else np.zeros(0, np.uint32)
            kinds = np.concatenate(kind_parts) if kind_parts else np.zeros(0, np.uint8)
            is_sample = kinds == _KIND_SAMPLE
        keep, seq_abs, t_us = self._timeline(seq16, time32)
        if is_sample is not None:
            self._handle_other_frames(others, keep)
            sample_keep = keep[is_sample]
            seq_abs = seq_abs[is_sample[keep]]
            t_us = t_us[is_sample[keep]]
        else:
            sample_keep = keep
        if not sample_keep.all():
            frames = frames[sample_keep]
        if frames.shape[0] == 0:
            return SampleBlock.empty()
        self.counters.frames += int(frames.shape[0])
        raw = frames["raw"]
        return SampleBlock(
            t=t_us * 1e-6,
            gyro=raw[:, :3].astype(np.float64),
            accel=raw[:, 3:].astype(np.float64),
            temp=frames["temp"] * TEMP_SCALE_C,
            flags=frames["flags"].astype(np.uint16),
            seq=seq_abs,
        )

    def _frame_seq_time(self, payload: tuple[int, int]) -> tuple[int, int]:
        off = payload[0]
        b = self._scan_buf
        return (
            int.from_bytes(b[off + 4 : off + 6], "little"),
            int.from_bytes(b[off + 6 : off + 10], "little"),
        )

    def _handle_other_frames(self, others: list[tuple[int, int, Any]], keep: np.ndarray) -> None:
        """Info and unknown frames: update device_info from each kept info frame."""
        b = self._scan_buf
        for index, kind, (off, length) in others:
            if index >= 0 and not keep[index]:
                continue  # a duplicate
            if kind == _KIND_OTHER:
                self.unknown_frames += 1
                continue
            self.info_frames += 1
            text = b[off + HEADER_SIZE + 6 : off + HEADER_SIZE + length]
            try:
                info = json.loads(text.decode("utf-8"))
            except (UnicodeDecodeError, ValueError):
                info = None
            if isinstance(info, dict):
                self.device_info = info
            else:
                self.info_errors += 1

    def _timeline_steady(
        self, seq16: np.ndarray, time32: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """The common case in a few passes: every seq +1 and time_us moving forward.

        Wrapping differences come for free in uint16/uint32 arithmetic. Returns
        None (nothing changed) when the general rules are needed.
        """
        k = seq16.shape[0]
        last_seq = self._last_seq
        if last_seq is None:  # the first frame: the general rules start the timeline
            return None
        seq_d = np.empty(k, np.uint16)
        seq_d[0] = (int(seq16[0]) - last_seq) % SEQ_MODULUS
        np.subtract(seq16[1:], seq16[:-1], out=seq_d[1:])
        if not (seq_d == 1).all():
            return None
        dt = np.empty(k, np.uint32)
        dt[0] = (int(time32[0]) - self._last_time) % TIME_MODULUS
        np.subtract(time32[1:], time32[:-1], out=dt[1:])
        if (dt >= TIME_MODULUS // 2).any():  # time went backwards: general rules
            return None
        t_abs = np.cumsum(dt, dtype=np.int64)
        t_abs += self._time_abs
        seq_abs = np.arange(self._seq_abs + 1, self._seq_abs + 1 + k, dtype=np.int64)
        self._last_seq = int(seq16[-1])
        self._last_time = int(time32[-1])
        self._seq_abs = int(seq_abs[-1])
        self._time_abs = int(t_abs[-1])
        last_dt = int(dt[-1])
        if last_dt > 0:
            self._last_dt_us = last_dt
        elif dt.any():
            self._last_dt_us = int(dt[np.flatnonzero(dt)[-1]])
        return np.ones(k, bool), seq_abs, t_abs

    def _timeline(
        self, seq16: np.ndarray, time32: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Duplicates, lost frames and unwrapping over sequenced frames in stream order.

        Returns ``keep`` (K,) bool and, for the kept frames, the unwrapped seq
        (int64) and device time (int64 microseconds).
        """
        c = self.counters
        k = seq16.shape[0]
        if k == 0:
            return np.zeros(0, bool), np.zeros(0, np.int64), np.zeros(0, np.int64)
        first_ever = self._last_seq is None
        if first_ever:  # as if preceded by seq-1 at the same time: t starts at time_us
            self._last_seq = (int(seq16[0]) - 1) % SEQ_MODULUS
            self._last_time = int(time32[0])
            self._seq_abs = int(seq16[0]) - 1
            self._time_abs = int(time32[0])
        fast = self._timeline_steady(seq16, time32)
        if fast is not None:
            return fast
        if first_ever:
            self._last_seq = None
        s = seq16.astype(np.int64)
        tm = time32.astype(np.int64)
        last_seq = self._last_seq
        first = last_seq is None
        prev = np.empty(k, np.int64)
        prev[1:] = s[:-1]
        prev[0] = s[0] - 1 if last_seq is None else last_seq
        d = ((s - prev + SEQ_MODULUS // 2) % SEQ_MODULUS) - SEQ_MODULUS // 2
        keep = d != 0
        n_dup = k - int(np.count_nonzero(keep))
        if n_dup:
            c.duplicates += n_dup
            s, tm, d = s[keep], tm[keep], d[keep]
            if s.shape[0] == 0:
                return keep, np.zeros(0, np.int64), np.zeros(0, np.int64)
        pt = np.empty(s.shape[0], np.int64)
        pt[1:] = tm[:-1]
        pt[0] = tm[0] if first else self._last_time
        dts = ((tm - pt + TIME_MODULUS // 2) % TIME_MODULUS) - TIME_MODULUS // 2
        restart = (d < 0) | (dts < 0)
        if restart.any():
            idx = np.flatnonzero(restart)
            self.restarts += int(idx.size)
            d[idx] = 1
            for r in idx.tolist():  # one step per discontinuity
                dts[r] = dts[r - 1] if r > 0 else self._last_dt_us
        gaps = d[d > 1]
        if gaps.size:
            c.lost += int(np.sum(gaps - 1))
        base_seq = s[0] - 1 if first else self._seq_abs
        base_t = tm[0] if first else self._time_abs
        seq_abs = base_seq + np.cumsum(d)
        t_abs = base_t + np.cumsum(dts)
        self._last_seq = int(s[-1])
        self._last_time = int(tm[-1])
        self._seq_abs = int(seq_abs[-1])
        self._time_abs = int(t_abs[-1])
        positive = dts[dts > 0]
        if positive.size:
            self._last_dt_us = int(positive[-1])
        return keep, seq_abs, t_abs

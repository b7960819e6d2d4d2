"""``isensor://DEVICE``: ADI iSensor IMUs (ADIS16xxx) on the iSensor SPI Buffer board.

The board (``ajn96/iSensor-SPI-Buffer``) is a USB CDC device with an ASCII command
line (its USB_CLI.md): ``read ADDR [END]``, ``write ADDR BYTE``, ``stream 0|1``,
``delim C``, ``echo 0|1``, ``cmd VALUE``, all values in hexadecimal. Registers on
pages 253 (board configuration), 254 (the words sent to the IMU for each capture)
and 255 (buffered output; selecting it starts the capture) are the board's; any
other page passes the SPI traffic to the IMU (REGISTER_DEFINITION.md).

On open the source stops any stream, turns the echo off, sets ``,`` as the
delimiter, reads the board's firmware (FW_REV) and serial (DEV_SN_0..5) and the
IMU's PROD_ID, range model, serial number and firmware, then configures a
buffered IMU burst capture (BUF_CONFIG IMU_BURST, BUF_LEN, the burst command in
BUF_WRITE_0), optionally the IMU's output rate (DEC_RATE), and starts the stream.

Each streamed line is one buffer entry, words in hexadecimal::

    UTC_LWR,UTC_UPR,TS_LWR,TS_UPR,SIG,DATA_0,...,DATA_n

``SIG`` is the sum of every other word (mod 2**16); a line whose signature fails
counts as a checksum error, as does an ADIS1647x/1650x burst whose own checksum
(the byte sum of DIAG_STAT .. DATA_CNTR) fails, and an ADIS1649x burst whose CRC-32
(SYS_E_FLAG .. DATA_CNT, :func:`burst_crc_ok_1649x`) fails: the sample is skipped.
Lines that are not entries (garbage, CLI chatter) are skipped bytes. The timestamp
(microseconds, 32 bits) is the sample time; the IMU's data counter counts lost and
repeated samples.

Scaling: the part's 16-bit output LSB sizes (:data:`MODELS`, sources in
``docs/devices.md``). ADIS1647x/1650x bursts carry the 16-bit outputs; ADIS1649x
bursts carry 32-bit outputs (``_OUT`` and ``_LOW`` words), scaled by the LSB/65536.
DIAG_STAT (SYS_E_FLAG on ADIS1649x) error bits set the ADC-error sample flag.

Commands (daemon: SIGUSR1 sends SELFTEST): ``SELFTEST`` runs the IMU's sensor self
test (GLOB_CMD); the samples of the following ``SELF_TEST_FLAG_S`` seconds carry the
self-test flag, and the next DIAG_STAT says pass or fail (``device_info["self_test"]``).
``START`` / ``STOP`` start and stop the stream; ``INFO`` and ``RATE`` are ignored.

Query keys: ``model`` (e.g. ``adis16495-2``: needed where the registers do not
tell the range model), ``rate`` (Hz: sets DEC_RATE), ``baud`` (ignored by CDC-ACM,
default 921600), ``exclusive``.
"""

from __future__ import annotations

import math
import struct
import time
import zlib
from dataclasses import dataclass
from typing import Any

import numpy as np

from imudiag.samples import (
    FLAG_ACCEL_SATURATED,
    FLAG_ADC_ERROR,
    FLAG_GYRO_SATURATED,
    FLAG_SELF_TEST,
    SampleBlock,
)

from .base import SourceError, SourceURL, register
from .devicestream import DeviceDecoder, DeviceSerialSource, Timeline, saturation_flags
from .wire import Counters

G_FAMILY_1647X = "adis1647x"  #: 16-bit burst (0x6800), DIAG_STAT, checksum
G_FAMILY_1649X = "adis1649x"  #: 32-bit burst (0x7C00 on page 0), SYS_E_FLAG, CRC-32


@dataclass(frozen=True)
class Model:
    """One range model of an iSensor part: how to read and scale its burst."""

    name: str  #: e.g. ``adis16475-2`` (also the bundled data-sheet certificate's name)
    prod_id: int  #: PROD_ID register value
    family: str  #: :data:`G_FAMILY_1647X` or :data:`G_FAMILY_1649X`
    gyro_lsb: float  #: deg/s per LSB of the 16-bit output
    accel_lsb: float  #: ``accel_unit`` per LSB of the 16-bit output
    accel_unit: str  #: ``g`` or ``m/s^2`` (the unit the data sheet states the part in)
    temp_lsb: float  #: degC per LSB of TEMP_OUT
    internal_rate_hz: float  #: output rate with DEC_RATE 0, Hz (rate = this / (DEC_RATE + 1))

    @property
    def units(self) -> dict[str, str]:
        """The units of this model's samples."""
        return {"gyro": "deg/s", "accel": self.accel_unit}


def _models() -> dict[str, Model]:
    """The supported range models. LSB sizes: the data sheets' Table 1 sensitivities for
    the 16-bit outputs, as the Linux kernel's drivers/iio/imu/adis16475.c and adis16480.c
    carry them per part (docs/devices.md lists the source of each)."""
    out: dict[str, Model] = {}
    gyro_1647x = {1: 1 / 160, 2: 1 / 40, 3: 1 / 10}  # deg/s per LSB: +-125, +-500, +-2000
    for part, acc_lsb, unit in (
        (16475, 1 / 4000, "g"),  # +-8 g
        (16477, 1 / 800, "g"),  # +-40 g
        (16505, 78 / 32000, "m/s^2"),  # +-78.4 m/s^2
        (16507, 392 / 32000, "m/s^2"),  # +-392 m/s^2
    ):
        for dash, glsb in gyro_1647x.items():
            name = f"adis{part}-{dash}"
            out[name] = Model(name, part, G_FAMILY_1647X, glsb, acc_lsb, unit, 0.1, 2000.0)
    out["adis16470"] = Model("adis16470", 16470, G_FAMILY_1647X, 0.1, 1 / 800, "g", 0.1, 2000.0)
    for dash, glsb in {1: 125 / 20000, 2: 450 / 18000, 3: 2000 / 20000}.items():
        name = f"adis16495-{dash}"
        out[name] = Model(name, 16495, G_FAMILY_1649X, glsb, 8 / 32000, "g", 0.0125, 4250.0)
    return out


#: every supported range model by name
MODELS: dict[str, Model] = _models()
#: PROD_ID values of the supported parts
PROD_IDS = sorted({m.prod_id for m in MODELS.values()})

#: ADIS1647x/1650x RANG_MDL bits 3:2 -> dash number (00: +-125, 01: +-500, 11: +-2000 deg/s)
_RANGE_DASH = {0b00: 1, 0b01: 2, 0b11: 3}
#: DIAG_STAT bits that make a sample untrustworthy (1647x/1650x data sheets: 1 data path
#: overrun, 2 flash update failure, 3 SPI error, 4 standby, 5 sensor failure, 6 memory
#: failure, 7 clock error)
DIAG_ERROR_BITS = 0x00FE
DIAG_SENSOR_FAILURE = 0x0020  #: DIAG_STAT bit 5: the self test failed
SYS_E_SELF_TEST = 0x0020  #: SYS_E_FLAG bit 5 on the ADIS1649x: the self test failed
SELF_TEST_FLAG_S = 0.05  #: s of samples flagged after a self test (over the parts' 14-30 ms)
#: the 16-bit words of each family's burst in DATA_0.. (DATA_0 is the reply to the command)
BURST_WORDS = {G_FAMILY_1647X: 11, G_FAMILY_1649X: 20}
BURST_COMMAND = {G_FAMILY_1647X: 0x6800, G_FAMILY_1649X: 0x7C00}
HEADER_WORDS = 5  #: UTC_LWR, UTC_UPR, TS_LWR, TS_UPR, SIG
BURST_ID_1649X = 0xA5A5
_MAX_LINE = 1024  #: bytes; a longer unterminated run is garbage
_FEW_LINES = 32  #: reads of at most this many lines take the plain-Python checks
_ENTRY_1647X = struct.Struct(">16H")  #: 5 header words + 11 burst words
_OUTS_1647X = struct.Struct(">7h")  #: gyro x y z, accel x y z, TEMP_OUT (signed), at byte 14


def bcd_version(word: int) -> str:
    """A FIRM_REV / FW_REV word (major.minor in BCD) as ``major.minor``."""
    return f"{(word >> 8) & 0x7F:x}.{word & 0xFF:02x}"


def line_signature(words: np.ndarray) -> np.ndarray:
    """The signature each entry should carry: the sum of its words but SIG, mod 2**16."""
    w = words.astype(np.int64)
    return ((w.sum(axis=1) - w[:, 4]) & 0xFFFF).astype(np.int64)


def burst_checksum_1647x(data: np.ndarray) -> np.ndarray:
    """ADIS1647x/1650x burst checksum of DIAG_STAT .. DATA_CNTR (DATA_1 .. DATA_9): the sum
    of their bytes, mod 2**16."""
    w = data[:, 1:10].astype(np.int64)
    return ((w & 0xFF).sum(axis=1) + (w >> 8).sum(axis=1)) & 0xFFFF


def burst_start_1649x(data: np.ndarray) -> np.ndarray:
    """Per burst (rows of DATA_0..): the index of its last leading BURST_ID (0xA5A5) among
    the first words (the reply may hold one or two, by the SPI clock; SYS_E_FLAG follows
    the last). Rows without one give 0 (the caller rejects them)."""
    is_id = data[:, :4] == BURST_ID_1649X
    first = np.argmax(is_id[:, :3], axis=1)
    rows = np.arange(data.shape[0])
    return first + is_id[rows, first + 1]


def burst_crc_ok_1649x(data: np.ndarray) -> np.ndarray:
    """ADIS1649x burst CRC-32 check per burst (rows of DATA_0..): the 15 words SYS_E_FLAG,
    TEMP_OUT, the six outputs' _LOW and _OUT words and DATA_CNT, each sent as its low byte
    then its high byte, through the CRC-32 of IEEE 802.3 (polynomial 0x04C11DB7 reflected,
    initial value and final XOR 0xFFFFFFFF: ``zlib.crc32``), against CRC_UPR:CRC_LWR,
    the two words after DATA_CNT (ADIS16495 data sheet, burst read; the Linux adis16480
    driver checks it the same way)."""
    start = burst_start_1649x(data)
    idx = start[:, None] + np.arange(1, 18)[None, :]
    f = np.take_along_axis(data, np.minimum(idx, data.shape[1] - 1), axis=1)
    body = np.ascontiguousarray(f[:, :15].astype("<u2"))
    sent = (f[:, 16].astype(np.int64) << 16) | f[:, 15].astype(np.int64)
    calc = np.fromiter((zlib.crc32(row.tobytes()) for row in body), np.int64, len(body))
    return np.asarray(calc == sent)


def _signed16(w: np.ndarray) -> np.ndarray:
    return w.astype(np.int64) - ((w.astype(np.int64) & 0x8000) << 1)


class ISensorDecoder(DeviceDecoder):
    """Streamed buffer entries (lines) of the iSensor SPI Buffer board -> samples."""

    units = {"gyro": "deg/s", "accel": "g"}

    def __init__(self, counters: Counters | None = None, model: Model | None = None) -> None:
        super().__init__(counters)
        self.timeline = Timeline(1e-6, 1 << 32)
        self.model: Model | None = None
        self.other_lines = 0  #: lines that are not buffer entries (skipped)
        self.self_tests = 0  #: self tests requested
        self._flag_self_test_s = 0.0  # flag samples until this much sample time has passed
        self._self_test_t0: float | None = None
        self._self_test_result_due = False
        self._last_cnt: int | None = None
        self.device_info.update(vendor="Analog Devices")
        if model is not None:
            self.set_model(model)

    def set_model(self, model: Model) -> None:
        """The IMU behind the board (read from its registers at open)."""
        self.model = model
        self._meta["units"] = model.units
        self.device_info["units"] = model.units
        self.device_info["datasheet"] = model.name
        self.device_info["product"] = model.name.upper()

    @property
    def words_per_line(self) -> int:
        """Hex words in one buffer entry line for the current model."""
        assert self.model is not None
        return HEADER_WORDS + BURST_WORDS[self.model.family]

    def request_self_test(self) -> None:
        """A self test was commanded: flag the samples that follow it."""
        self.self_tests += 1
        self._flag_self_test_s = SELF_TEST_FLAG_S
        self._self_test_t0 = None
        self._self_test_result_due = True

    # -- bytes -> lines -> words -------------------------------------------

    def _decode(self, buf: bytes) -> tuple[SampleBlock, int]:
        end = buf.rfind(b"\n")
        if end < 0:
            if len(buf) > _MAX_LINE:  # no line end in sight: garbage
                self.counters.skipped_bytes += len(buf)
                return SampleBlock.empty(), len(buf)
            return SampleBlock.empty(), 0
        if self.model is None:  # not configured: nothing is an entry yet
            self.counters.skipped_bytes += end + 1
            return SampleBlock.empty(), end + 1
        width = self.words_per_line
        raws = buf[: end + 1].split(b"\n")[:-1]
        if len(raws) <= _FEW_LINES and self.model.family == G_FAMILY_1647X:
            few = self._few_lines(raws, width)
            if few is not None:
                return few, end + 1
        words_arr = _parse_all(raws, width)
        if words_arr is not None:  # every line an entry of 4-digit words: one conversion
            size_arr = np.array([len(r) + 1 for r in raws], dtype=np.int64)
        else:
            rows: list[list[int]] = []
            sizes: list[int] = []
            for raw in raws:
                size = len(raw) + 1
                line = raw.strip(b"\r \t")
                words = _parse_words(line, width)
                if words is None:
                    self.counters.skipped_bytes += size
                    if line:
                        self.other_lines += 1
                    continue
                rows.append(words)
                sizes.append(size)
            if not rows:
                return SampleBlock.empty(), end + 1
            words_arr = np.array(rows, dtype=np.int64)
            size_arr = np.array(sizes, dtype=np.int64)
        good = line_signature(words_arr) == words_arr[:, 4]
        data = words_arr[:, HEADER_WORDS:]
        if self.model is not None and self.model.family == G_FAMILY_1647X:
            good &= burst_checksum_1647x(data) == data[:, 10]
        else:
            good &= (data[:, :3] == BURST_ID_1649X).any(axis=1)
            good &= burst_crc_ok_1649x(data)
        if good.all():
            self.frame_bytes += int(size_arr.sum())
            return self._samples(words_arr), end + 1
        bad = int(np.count_nonzero(~good))
        self.counters.crc_errors += bad
        self.counters.skipped_bytes += int(size_arr[~good].sum())
        self.frame_bytes += int(size_arr[good].sum())
        return self._samples(words_arr[good]), end + 1

    def _few_lines(self, raws: list[bytes], width: int) -> SampleBlock | None:
        """A daemon's read of ADIS1647x entries in plain Python (the rules of the general
        path, without its fixed numpy cost); None, with nothing changed, when any line is
        not a good 4-digit entry."""
        fast = 5 * width - 1
        lines = [raw[:-1] if raw.endswith(b"\r") else raw for raw in raws]
        for line in lines:
            if len(line) != fast or line.count(b",") != width - 1:
                return None
        try:
            packed = bytes.fromhex(b"".join(lines).replace(b",", b"").decode("ascii"))
        except (ValueError, UnicodeDecodeError):
            return None
        size = _ENTRY_1647X.size
        if len(packed) != size * len(lines):
            return None
        rows = []
        for p in range(0, len(packed), size):
            w = _ENTRY_1647X.unpack_from(packed, p)
            if (sum(w) - w[4]) & 0xFFFF != w[4]:
                return None
            if sum(packed[p + 12 : p + 30]) & 0xFFFF != w[15]:  # DIAG_STAT .. DATA_CNTR bytes
                return None
            rows.append((w, _OUTS_1647X.unpack_from(packed, p + 14)))
        if not rows:
            return None
        self.frame_bytes += sum(len(r) + 1 for r in raws)
        model = self.model
        assert model is not None
        ticks: list[int] = []
        outs: list[tuple[int, ...]] = []
        flags: list[int] = []
        fails: list[bool] = []
        c = self.counters
        last = self._last_cnt
        for w, v in rows:
            cnt = w[14]
            d = 1 if last is None else (cnt - last) % 0x10000
            if d == 0:
                c.duplicates += 1
                continue
            if 1 < d < 0x8000:
                c.lost += d - 1
            last = cnt
            ticks.append(w[2] | (w[3] << 16))
            diag = w[6]
            flag = FLAG_ADC_ERROR if diag & DIAG_ERROR_BITS else 0
            if max(v[0:3]) >= 32767 or min(v[0:3]) <= -32768:
                flag |= FLAG_GYRO_SATURATED
            if max(v[3:6]) >= 32767 or min(v[3:6]) <= -32768:
                flag |= FLAG_ACCEL_SATURATED
            outs.append(v)
            flags.append(flag)
            fails.append(bool(diag & DIAG_SENSOR_FAILURE))
        self._last_cnt = last
        if not outs:
            return SampleBlock.empty()
        keep, t = self.timeline.place(ticks, c)
        vals = np.array(outs, dtype=np.float64)
        flag_a = np.array(flags, dtype=np.uint16)
        fail_a = np.array(fails, dtype=bool)
        if t.shape[0] != vals.shape[0]:
            vals, flag_a, fail_a = vals[keep], flag_a[keep], fail_a[keep]
        flag_a = self._self_test_flags(t, flag_a, fail_a)
        return self._block(
            t,
            vals[:, 0:3] * model.gyro_lsb,
            vals[:, 3:6] * model.accel_lsb,
            vals[:, 6] * model.temp_lsb,
            flag_a,
        )

    # -- words -> samples ----------------------------------------------------

    def _samples(self, words: np.ndarray) -> SampleBlock:
        model = self.model
        if model is None or words.shape[0] == 0:
            return SampleBlock.empty()
        data = words[:, HEADER_WORDS:]
        if model.family == G_FAMILY_1647X:
            diag = data[:, 1]
            outs = _signed16(data[:, 2:9])  # gyro x y z, accel x y z, temperature
            gyro = outs[:, 0:3]
            accel = outs[:, 3:6]
            temp = outs[:, 6] * model.temp_lsb
            cnt = data[:, 9]
            lo16, hi16 = gyro, accel
            err = (diag & DIAG_ERROR_BITS) != 0
            failed = (diag & DIAG_SENSOR_FAILURE) != 0
        else:
            # locate the burst ID (0xA5A5) in the first words; fields follow at fixed offsets
            start = burst_start_1649x(data)
            idx = start[:, None] + np.arange(1, 17)[None, :]
            f = np.take_along_axis(data, np.minimum(idx, data.shape[1] - 1), axis=1)
            diag = f[:, 0]
            temp = _signed16(f[:, 1]) * model.temp_lsb
            low = f[:, 2:14:2]
            out = f[:, 3:14:2]
            v32 = (out << 16) | low
            v32 = v32 - ((v32 & 0x80000000) << 1)
            gyro = v32[:, :3] / 65536.0
            accel = v32[:, 3:] / 65536.0
            cnt = f[:, 14]
            lo16, hi16 = _signed16(out[:, :3]), _signed16(out[:, 3:])
            err = diag != 0
            failed = (diag & SYS_E_SELF_TEST) != 0
        keep = self._count_steps(cnt)
        ticks = words[:, 2] | (words[:, 3] << 16)
        if keep.all():
            tkeep, t = self.timeline.place(ticks, self.counters)
        else:
            tkeep, t = self.timeline.place(ticks[keep], self.counters)
        if t.shape[0] != words.shape[0]:
            idx = np.flatnonzero(keep)[tkeep]
            gyro, accel, temp = gyro[idx], accel[idx], temp[idx]
            lo16, hi16, err, failed = lo16[idx], hi16[idx], err[idx], failed[idx]
        flags = (err * FLAG_ADC_ERROR).astype(np.uint16)
        flags = saturation_flags(lo16, hi16, -32768, 32767, flags)
        flags = self._self_test_flags(t, flags, failed)
        return self._block(t, gyro * model.gyro_lsb, accel * model.accel_lsb, temp, flags)

    def _count_steps(self, cnt: np.ndarray) -> np.ndarray:
        """Lost and repeated samples by the IMU's data counter; False for repeats."""
        n = cnt.shape[0]
        if n <= 32:  # a daemon's read: plain Python
            keep = [True] * n
            last = self._last_cnt
            for i, c in enumerate(cnt.tolist()):
                d = 1 if last is None else (c - last) % 0x10000
                if d == 0:
                    keep[i] = False
                    self.counters.duplicates += 1
                    continue
                if 1 < d < 0x8000:
                    self.counters.lost += d - 1
                last = c
            self._last_cnt = last
            return np.array(keep, dtype=bool)
        prev = np.empty(n, np.int64)
        prev[1:] = cnt[:-1]
        prev[0] = cnt[0] - 1 if self._last_cnt is None else self._last_cnt
        d = (cnt - prev) % 0x10000
        keep = d != 0
        self.counters.duplicates += int(n - np.count_nonzero(keep))
        gaps = d[(d > 1) & (d < 0x8000)]  # a big step back: an IMU reset, not a loss
        if gaps.size:
            self.counters.lost += int(np.sum(gaps - 1))
        self._last_cnt = int(cnt[-1])
        return keep

    def _self_test_flags(self, t: np.ndarray, flags: np.ndarray, failed: np.ndarray) -> np.ndarray:
        if self._flag_self_test_s <= 0.0 or t.shape[0] == 0:
            return flags
        if self._self_test_t0 is None:
            self._self_test_t0 = float(t[0])
        within = t < self._self_test_t0 + self._flag_self_test_s
        flags[within] |= FLAG_SELF_TEST
        after = np.flatnonzero(~within)
        if after.size:
            self._flag_self_test_s = 0.0
            if self._self_test_result_due:
                self._self_test_result_due = False
                self.device_info["self_test"] = {
                    "count": self.self_tests,
                    "result": "fail" if bool(failed[after[0]]) else "pass",
                    "t": float(self._self_test_t0),
                }
        return flags


def _parse_all(raws: list[bytes], width: int) -> np.ndarray | None:
    """(k, width) words of ``raws`` when every one is an entry of 4-digit hex words
    (what the board prints), else None (then each line is parsed on its own)."""
    fast = 5 * width - 1
    lines = [r[:-1] if r.endswith(b"\r") else r for r in raws]
    if not lines or any(len(x) != fast or x.count(b",") != width - 1 for x in lines):
        return None
    try:
        packed = bytes.fromhex(b"".join(lines).replace(b",", b"").decode("ascii"))
    except (ValueError, UnicodeDecodeError):
        return None
    if len(packed) != 2 * width * len(lines):
        return None
    return np.frombuffer(packed, dtype=">u2").reshape(len(lines), width).astype(np.int64)


def _parse_words(line: bytes, width: int) -> list[int] | None:
    """The ``width`` hex words of a buffer entry line, or None if it is not one."""
    if len(line) == 5 * width - 1 and line.count(b",") == width - 1:
        try:  # the common case: every word printed as 4 hex digits
            packed = bytes.fromhex(line.replace(b",", b"").decode("ascii"))
        except (ValueError, UnicodeDecodeError):
            return None
        return list(np.frombuffer(packed, dtype=">u2").astype(np.int64).tolist())
    parts = line.split(b",")
    if len(parts) != width:
        return None
    try:
        words = [int(p, 16) for p in parts]
    except ValueError:
        return None
    if any(w < 0 or w > 0xFFFF for w in words) or any(not p.strip() for p in parts):
        return None
    return words


def model_from_registers(prod_id: int, rang_mdl: int | None, wanted: str | None) -> Model:
    """The range model from PROD_ID, RANG_MDL and the URL's ``model`` (which wins)."""
    if wanted:
        key = wanted.strip().lower()
        if key not in MODELS:
            raise SourceError(
                f"isensor://: unknown model {wanted!r}; known: {', '.join(sorted(MODELS))}"
            )
        model = MODELS[key]
        if prod_id != model.prod_id:
            raise SourceError(
                f"isensor://: model {wanted!r} asked for but the IMU's PROD_ID is {prod_id}"
            )
        return model
    if prod_id == 16470:
        return MODELS["adis16470"]
    if prod_id in (16475, 16477, 16505, 16507) and rang_mdl is not None:
        dash = _RANGE_DASH.get((rang_mdl >> 2) & 0b11)
        if dash is not None:
            return MODELS[f"adis{prod_id}-{dash}"]
        raise SourceError(f"isensor://: ADIS{prod_id} RANG_MDL {rang_mdl:#06x} is not a model")
    if prod_id == 16495:
        raise SourceError(
            "isensor://: an ADIS16495's range model is not read from its registers here: "
            "give it in the URL, e.g. isensor:///dev/ttyACM0?model=adis16495-2"
        )
    raise SourceError(
        f"isensor://: PROD_ID {prod_id} is not a supported part "
        f"(supported: {', '.join(f'ADIS{p}' for p in PROD_IDS)})"
    )


@register("isensor")
class ISensorSource(DeviceSerialSource):
    """An iSensor IMU on the iSensor SPI Buffer board (see the module docstring)."""

    url_keys = ("baud", "rate", "model", "exclusive", "timeout")
    default_baud = 921600
    answer_timeout_s = 1.0  #: longest wait for the board's answer to a read, s

    def __init__(self, url: SourceURL, **options: Any) -> None:
        super().__init__(url, **options)
        self.port_url = url.target
        if not self.port_url:
            raise SourceError(f"{url.url}: no device path (isensor:///dev/ttyACM0)")
        rate = url.get("rate", None, float)
        if rate is not None and not (rate > 0 and math.isfinite(rate)):
            raise SourceError(f"{url.url}: bad value for 'rate': {rate}")
        self.rate_hz: float | None = rate
        self.wanted_model: str | None = url.get("model", None)
        timeout = float(url.get("timeout", self.answer_timeout_s, float))
        if not (timeout > 0 and math.isfinite(timeout)):
            raise SourceError(f"{url.url}: bad value for 'timeout': {timeout}")
        self.answer_timeout_s = timeout
        self.decoder = ISensorDecoder(self.counters)
        self.device_info = self.decoder.device_info
        self._lines: list[bytes] = []
        self._partial = b""

    # -- the CLI dialogue --------------------------------------------------

    def _cli(self, *lines: str) -> None:
        for line in lines:
            self._write_bytes((line + "\r\n").encode("ascii"))

    def _drain(self, quiet_s: float = 0.1, limit_s: float = 1.0) -> None:
        """Read and drop what the board sends until it is quiet for ``quiet_s`` seconds."""
        end = time.monotonic() + limit_s
        while time.monotonic() < end:
            if not self._read_bytes(quiet_s):
                break
        self._lines, self._partial = [], b""

    def _answer(self, command: str, n_words: int) -> list[int]:
        """Send ``command`` (a ``read``) and return the ``n_words`` words it answers."""
        self._cli(command)
        end = time.monotonic() + self.answer_timeout_s
        while True:
            while self._lines:
                line = self._lines.pop(0).strip(b"\r \t")
                parts = [p for p in line.replace(b",", b" ").split() if p]
                if len(parts) == n_words:
                    try:
                        return [int(p, 16) for p in parts]
                    except ValueError:
                        pass
            left = end - time.monotonic()
            if left <= 0:
                raise SourceError(
                    f"{self.url.url}: no answer from the iSensor SPI Buffer board to "
                    f"{command!r} within {self.answer_timeout_s} s (is it the board, and "
                    "is its firmware 1.11 or newer?)"
                )
            data = self._partial + self._read_bytes(min(left, 0.1))
            *done, self._partial = data.split(b"\n")
            self._lines.extend(done)

    def _configure(self) -> None:
        """Identify the board and the IMU, then start the buffered burst stream."""
        dec = self.decoder
        assert isinstance(dec, ISensorDecoder)
        self._cli("stream 0")
        self._drain()
        self._cli("echo 0", "delim ,")
        self._drain()
        self._cli("write 0 FD")
        board_fw = self._answer("read 6E", 1)[0]
        board_sn = self._answer("read 74 7E", 6)
        self._cli("write 0 0")
        prod_id = self._answer("read 72", 1)[0]
        rang = serial = firm = None
        if prod_id in (16470, 16475, 16477, 16505, 16507):
            rang = self._answer("read 5E", 1)[0]
            serial = self._answer("read 74", 1)[0]
            firm = self._answer("read 6C", 1)[0]
        elif self._answer("read 7E", 1)[0] == 16495:  # the ADIS1649x: PROD_ID at page 0 0x7E
            prod_id = 16495
            self._cli("write 0 3")
            firm = self._answer("read 78", 1)[0]
            self._cli("write 0 4")
            serial = self._answer("read 20", 1)[0]
            self._cli("write 0 0")
        model = model_from_registers(prod_id, rang, self.wanted_model)
        dec.set_model(model)
        dec.device_info.update(
            serial=None if serial is None else f"{serial:04X}",
            firmware=None if firm is None else bcd_version(firm),
            prod_id=prod_id,
            board={
                "product": "iSensor SPI Buffer",
                "firmware": bcd_version(board_fw),
                "serial": "".join(f"{w:04X}" for w in reversed(board_sn)),
            },
        )
        if self.rate_hz is not None:
            dec_rate = max(0, int(round(model.internal_rate_hz / self.rate_hz)) - 1)
            if model.family == G_FAMILY_1647X:
                self._cli(f"write 64 {dec_rate & 0xFF:X}", f"write 65 {dec_rate >> 8:X}")
            else:
                self._cli("write 0 3", f"write C {dec_rate & 0xFF:X}", f"write D {dec_rate >> 8:X}")
                self._cli("write 0 0")
            dec.device_info["rate_hz"] = model.internal_rate_hz / (dec_rate + 1)
        self._start_stream(model)

    def _start_stream(self, model: Model) -> None:
        command = BURST_COMMAND[model.family]
        length = 2 * BURST_WORDS[model.family]
        self._cli(
            "write 0 FD",
            "write 2 3",  # BUF_CONFIG: IMU_BURST, overflow replaces the oldest entry
            "write 3 0",
            f"write 4 {length:X}",  # BUF_LEN, bytes
            "write 5 0",
            "write 0 FE",
            f"write 12 {command & 0xFF:X}",  # BUF_WRITE_0: the burst command word
            f"write 13 {command >> 8:X}",
            "cmd 1",  # clear the buffer
            "stream 1",
            "write 0 FF",  # page 255 starts the capture
        )

    # -- commands ------------------------------------------------------------

    def write_command(self, line: str) -> None:
        """``SELFTEST`` (GLOB_CMD sensor self test), ``START``, ``STOP``; ``INFO`` and
        ``RATE <hz>`` are accepted and ignored; anything else is a ValueError."""
        word = line.strip().upper()
        if not self.is_open:
            raise SourceError(f"{self.url.url}: command {line.strip()!r} on a closed source")
        dec = self.decoder
        assert isinstance(dec, ISensorDecoder)
        if word == "SELFTEST":
            model = dec.model
            self._cli("stream 0")
            if model is not None and model.family == G_FAMILY_1649X:
                self._cli("write 0 3", "write 2 2", "write 3 0")  # GLOB_CMD bit 1
            else:
                self._cli("write 0 0", "write 68 4", "write 69 0")  # GLOB_CMD bit 2
            dec.request_self_test()
            self._cli("stream 1", "write 0 FF")
        elif word == "STOP":
            self._cli("stream 0")
        elif word == "START":
            self._cli("stream 1", "write 0 FF")
        elif word == "INFO" or word.startswith("RATE "):
            return
        else:
            raise ValueError(
                f"unknown device command {line!r} for isensor://: SELFTEST, START, STOP"
            )

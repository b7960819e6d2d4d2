"""The DataFlash scan (:mod:`imudiag.logs.dataflash_scan`, issue 28: reading a log was
about 100 s of CPU per 10^6 IMU samples through pymavlink, 40 times the diagnosis) reads
what pymavlink's ``DFReader`` reads, value for value and message for message, on

- the real log (pymavlink's test.BIN, tests/data/real/ardupilot-dataflash, SOURCE.md);
- logs written here byte for byte as ArduPilot writes them, of every era
  (tests/test_dataflash_logs.py: IMU with ``I``, IMU/IMU2 of older firmware;
  tests/test_dataflash_raw.py: raw ACC/GYR logging, the batch sampler's ISBH/ISBD), each
  also with its last message cut short and with a block log's padding after it;
- a log of fields under pymavlink's multipliers (``c``, ``e``, ``L``).

Damaged logs (seeded garbage between messages, with message heads inside it), a type
redefined by a later FMT and a format pymavlink cannot unpack are refused by the scan
(ScanError), and the reader reads them through pymavlink: its samples, or its refusal, are
those of the reader through pymavlink in every case.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest
from test_dataflash_logs import HEAD, IMUCAL, _fmt, write_dataflash
from test_dataflash_raw import write_log as write_raw_log

from imudiag.logs import LogError, LogOptions, open_log, read_log
from imudiag.logs import dataflash as dataflash_module
from imudiag.logs.dataflash import _TYPES
from imudiag.logs.dataflash_scan import (
    Messages,
    ScanError,
    forget,
    pymavlink_messages,
    scan_messages,
)
from imudiag.samples import SampleBlock

REAL = Path(__file__).parent / "data" / "real" / "ardupilot-dataflash" / "test.BIN"
SEED = 28


def _same(a: Messages, b: Messages) -> None:
    assert sorted(a.offsets) == sorted(b.offsets)
    for name in a.offsets:
        np.testing.assert_array_equal(a.offsets[name], b.offsets[name], err_msg=name)
        assert sorted(a.columns[name]) == sorted(b.columns[name]), name
        for col, got in a.columns[name].items():
            want = b.columns[name][col]
            assert got.dtype == want.dtype == np.float64, (name, col)
            np.testing.assert_array_equal(got, want, err_msg=f"{name}.{col}")


@pytest.fixture(scope="module")
def session() -> SampleBlock:
    return read_log(IMUCAL).slice(0, 800)


def _logs(d: Path, session: SampleBlock) -> dict[str, Path]:
    return {
        "real": REAL,
        "imu-two-instances": write_dataflash(d / "imu.bin", session),
        "imu-old-names": write_dataflash(d / "old.bin", session, old_names=True),
        "raw-acc-gyr": write_raw_log(d / "raw.bin", session, "raw"),
        "batch-sampler": write_raw_log(d / "isb.bin", session, "batch"),
    }


def _garbage(src: Path, dst: Path, seed: int) -> Path:
    """``src`` with seeded garbage after some messages (random bytes, a message head of a
    random type after some) and its last message cut short."""
    data = src.read_bytes()
    rng = np.random.default_rng(seed)
    at = [m for m in range(len(data) - 1) if data[m : m + 2] == HEAD]
    out, last = [], 0
    for cut in sorted(rng.choice(at[10:], size=12, replace=False).tolist()):
        out.append(data[last:cut])
        junk = bytearray(rng.integers(0, 256, size=int(rng.integers(1, 40)), dtype=np.uint8))
        if rng.random() < 0.5:
            junk += HEAD + bytes([int(rng.integers(0, 256))])  # a head, maybe of a known type
        out.append(bytes(junk))
        last = cut
    out.append(data[last:-7])  # the last message cut short
    dst.write_bytes(b"".join(out))
    return dst


def _struct(fmt: str) -> str:
    """The struct layout of DataFlash format ``fmt`` (``c`` int16, ``e`` and ``L`` int32)."""
    return "<" + fmt.translate(str.maketrans("ceL", "hii"))


def _pack(fmt: str, *values: float) -> bytes:
    return struct.pack(_struct(fmt), *values)


def _fmt_of(type_id: int, name: str, fmt: str, cols: str) -> bytes:
    """An FMT message for a type whose format has multiplied characters."""
    head = _fmt(type_id, name, "", cols)  # FMT's own layout; its length byte set below
    length = 3 + struct.calcsize(_struct(fmt))
    body = struct.pack("<BB4s16s64s", type_id, length, name.encode(), fmt.encode(), cols.encode())
    return head[:3] + body


IMU_A = ("QBffffffc", "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,T")  #: T in centi-degrees (c)
GPS = ("QBIHBLLefff", "TimeUS,I,GMS,GWk,Status,Lat,Lng,Alt,Spd,GCrs,VZ")  #: L, e: x1e7, x100


def _multiplied(d: Path, redefine: bool = False) -> Path:
    """50 IMU messages with a ``c`` temperature and 5 GPS messages with ``L`` lat/lon and
    an ``e`` altitude (seeded); ``redefine``: then a later FMT giving IMU's type another
    layout (no temperature) and 30 more IMU messages."""
    imu_b = ("QBffffff", "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ")
    out = [_fmt(128, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns")]
    out.append(_fmt_of(140, "IMU", *IMU_A))
    out.append(_fmt_of(141, "GPS", *GPS))
    rng = np.random.default_rng(SEED)
    for k in range(50):
        g, a = rng.normal(0, 0.1, 3), rng.normal(0, 9.8, 3)
        temp = int(rng.integers(-3000, 3000))
        out.append(HEAD + bytes([140]) + _pack(IMU_A[0], 1000 * k, 0, *g, *a, temp))
        if k % 10 == 0:
            lat, lng = int(rng.integers(-900_000_000, 900_000_000)), 1_234_567_891
            rec = _pack(GPS[0], 1000 * k, 0, 1000 * k, 2300, 3, lat, lng, 12345, 1.5, 90.0, 0.1)
            out.append(HEAD + bytes([141]) + rec)
    if redefine:
        out.append(_fmt_of(140, "IMU", *imu_b))
        for k in range(50, 80):
            g, a = rng.normal(0, 0.1, 3), rng.normal(0, 9.8, 3)
            out.append(HEAD + bytes([140]) + _pack(imu_b[0], 1000 * k, 0, *g, *a))
    path = d / ("redefined.bin" if redefine else "multiplied.bin")
    path.write_bytes(b"".join(out))
    return path


def _redefined(d: Path) -> Path:
    return _multiplied(d, redefine=True)


def test_the_scan_reads_what_pymavlink_reads_on_every_era(tmp_path, session) -> None:
    for name, log in _logs(tmp_path, session).items():
        data = log.read_bytes()
        cut, padded = tmp_path / f"{name}-cut.bin", tmp_path / f"{name}-padded.bin"
        cut.write_bytes(data[:-7])  # the last message cut short
        padded.write_bytes(data + b"\xff" * 249 + bytes(7))  # a block log's last page
        for variant in (log, cut, padded):
            got = scan_messages(variant, _TYPES)
            assert got.offsets, variant
            _same(got, pymavlink_messages(variant, _TYPES))


def test_damage_and_redefinitions_are_left_to_pymavlink(tmp_path, session) -> None:
    logs = _logs(tmp_path, session)
    damaged = [_garbage(log, tmp_path / f"{name}-junk.bin", SEED + k)
               for k, (name, log) in enumerate(logs.items())]  # fmt: skip
    for log in [*damaged, _redefined(tmp_path)]:
        with pytest.raises(ScanError):
            scan_messages(log, _TYPES)


def test_multiplied_fields_are_divided_as_pymavlink_divides_them(tmp_path) -> None:
    log = _multiplied(tmp_path)
    got = scan_messages(log, _TYPES)
    _same(got, pymavlink_messages(log, _TYPES))
    assert got.count("IMU") == 50 and got.count("GPS") == 5
    assert got.columns["GPS"]["Lng"][0] == 1_234_567_891 / (1 / 1e-7)
    assert got.columns["GPS"]["Alt"][0] == 12345 / 100.0


def _read(log: Path, options: LogOptions) -> tuple[object, ...]:
    """The reader's samples and metadata, or its refusal."""
    try:
        with open_log(log, options=options) as r:
            block = SampleBlock.concat(list(r))
            return (r.meta, block.t, block.gyro, block.accel, block.temp)
    except LogError as exc:
        return ("refused", str(exc))


def test_the_reader_gives_the_samples_of_the_reader_through_pymavlink(
    tmp_path, session, monkeypatch
) -> None:
    logs = _logs(tmp_path, session)
    for k in range(3):  # left to pymavlink by the scan
        logs[f"junk-{k}"] = _garbage(logs["imu-two-instances"], tmp_path / f"j{k}.bin", SEED + k)
    for name, log in logs.items():
        for instance in (0, 1) if name in ("real", "imu-two-instances") else (0,):
            options = LogOptions(instance=instance)
            fast = _read(log, options)
            with monkeypatch.context() as m:
                m.setattr(dataflash_module, "scan_messages", _refuse)
                ref = _read(log, options)
            assert len(fast) == len(ref) and fast[0] == ref[0], name
            for got, want in zip(fast[1:], ref[1:], strict=True):
                np.testing.assert_array_equal(got, want, err_msg=name)


def _refuse(path: object, names: object) -> Messages:
    raise ScanError("the reference path, for the test")


def test_a_format_the_scan_does_not_know_is_read_through_pymavlink(tmp_path, session) -> None:
    """An FMT whose format and length disagree (pymavlink fails to unpack such a message
    and looks for the next from inside it): the scan refuses the log (ScanError) and the
    reader reads it through pymavlink."""
    log = write_dataflash(tmp_path / "ok.bin", session.slice(0, 50), instances=(0,))
    data = bytearray(log.read_bytes())
    bad = _fmt(150, "XYZ", "Qf", "TimeUS,V")
    bad = bad[:4] + bytes([bad[4] + 4]) + bad[5:]  # a length 4 bytes longer than "Qf"
    odd = tmp_path / "odd.bin"
    odd.write_bytes(bytes(data[:89]) + bad + bytes(data[89:]))
    for wanted in (["XYZ", *_TYPES], _TYPES):
        with pytest.raises(ScanError, match="XYZ"):
            scan_messages(odd, wanted)
    np.testing.assert_array_equal(read_log(odd).gyro, read_log(log).gyro)


def test_a_log_read_again_is_not_scanned_again_until_it_changes(tmp_path, session) -> None:
    """Each IMU instance and each pass of a diagnosis reads the log again: the last scan is
    kept (read only) while the file's size and modification time are unchanged."""
    log = write_dataflash(tmp_path / "imu.bin", session)
    first = scan_messages(log, _TYPES)
    assert scan_messages(log, _TYPES) is first
    with pytest.raises(ValueError, match="read-only"):
        first.columns["IMU"]["GyrX"][0] = 0.0
    kept = _read(log, LogOptions(instance=1))  # from the scan kept
    forget()
    cold = _read(log, LogOptions(instance=1))
    assert kept[0] == cold[0]
    for got, want in zip(kept[1:], cold[1:], strict=True):
        np.testing.assert_array_equal(got, want)
    write_dataflash(log, session.slice(0, 100))  # the same file written again, shorter
    again = scan_messages(log, _TYPES)
    assert again is not first and again.count("IMU") == 200

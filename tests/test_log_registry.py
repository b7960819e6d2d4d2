"""The log-format registry: chosen by file name, and by magic bytes where names collide."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from imudiag.logs import (
    LogError,
    formats,
    log_format,
    lookup,
    open_log,
    register_format,
    registry,
    write_log,
)
from imudiag.logs.base import LogReader
from imudiag.samples import SampleBlock


class _MagicReader(LogReader):
    format = "magic-test"


@pytest.fixture
def magic_format():
    fmt = registry.LogFormat(
        "magic-test", (".bin",), _MagicReader, magic=lambda b: b[:4] == b"MAGI"
    )
    register_format(fmt)
    yield fmt
    registry._FORMATS.remove(fmt)


def _block(n: int = 5) -> SampleBlock:
    t = np.arange(n) * 0.01
    raw = np.arange(n * 3, dtype=float).reshape(n, 3)
    return SampleBlock(t=t, gyro=raw, accel=raw + 1, temp=None, seq=None, flags=None, meta={})


def test_builtin_formats_by_name() -> None:
    names = {f.name for f in formats()}
    assert {".csv", ".csv.gz", ".npz", ".bin"} <= names
    assert log_format("a/B.CSV.GZ") == ".csv.gz"
    assert log_format("x.csv") == ".csv"
    with pytest.raises(LogError, match="unknown log format"):
        log_format("x.unknownext")


def test_magic_bytes_pick_among_formats_sharing_an_ending(tmp_path: Path, magic_format) -> None:
    wire = tmp_path / "capture.bin"
    write_log(wire, _block())
    assert lookup(wire).name == ".bin"  # no magic match: the plain wire capture
    with open_log(wire) as reader:
        assert sum(len(b) for b in reader) == 5
    other = tmp_path / "other.bin"
    other.write_bytes(b"MAGIC and more")
    assert lookup(other) is magic_format
    assert isinstance(open_log(other), _MagicReader)
    # a new file (no bytes yet) is written as the plain format
    assert lookup(tmp_path / "new.bin").name == ".bin"


def test_reading_only_format_refuses_writing(tmp_path: Path) -> None:
    fmt = registry.LogFormat("readonly-test", (".rotest",), _MagicReader)
    register_format(fmt)
    try:
        with pytest.raises(LogError, match="unknown log format for writing"):
            write_log(tmp_path / "x.rotest", _block())
    finally:
        registry._FORMATS.remove(fmt)

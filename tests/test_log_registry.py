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


def test_which_formats_may_carry_gnss_of_their_own(tmp_path: Path, monkeypatch) -> None:
    """A format may hold GNSS fixes of its own unless its reader is a LogReader class that
    keeps the base's ``gnss`` (none): ``diagnose`` then does not open such a log again to
    ask (a CSV, NPZ or wire capture); a reader made by a function is always asked; and a
    CSV log's report is the same without that second open (no ``moving_base`` section)."""
    carries = {f.name: f.may_carry_gnss for f in formats()}
    assert not any(carries[n] for n in (".csv", ".csv.gz", ".npz", ".bin"))
    assert all(carries[n] for n in ("dataflash", ".ulg", "rosbag2", "rosbag1"))

    class _WithGnss(LogReader):
        def gnss(self):  # type: ignore[no-untyped-def]
            return None

    assert registry.LogFormat("x", (".x",), _WithGnss).may_carry_gnss
    assert registry.LogFormat("y", (".y",), lambda path, block_size: _WithGnss(path)).may_carry_gnss
    assert not registry.LogFormat("z", (".z",), _MagicReader).may_carry_gnss

    from imudiag.api import diagnose
    from imudiag.certificate import load_default
    from imudiag.logs.csv_format import CsvReader
    from imudiag.sim import multi_position, simulate

    cert = load_default()
    traj = multi_position(n_attitudes=8, dwell_s=20.0, turn_s=2.0, rate_hz=100, seed=3)
    log = tmp_path / "session.csv"
    write_log(log, simulate(cert, traj, seed=4).samples)
    opened = []
    real_init = CsvReader.__init__

    def counting_init(self, *args, **kwargs):  # type: ignore[no-untyped-def]
        opened.append(args[0] if args else kwargs.get("path"))
        real_init(self, *args, **kwargs)

    monkeypatch.setattr(CsvReader, "__init__", counting_init)
    report = diagnose(str(log), None)
    assert "moving_base" not in report
    assert len(opened) == 1, opened  # read once, not opened again to ask for its GNSS


def test_reading_only_format_refuses_writing(tmp_path: Path) -> None:
    fmt = registry.LogFormat("readonly-test", (".rotest",), _MagicReader)
    register_format(fmt)
    try:
        with pytest.raises(LogError, match="unknown log format for writing"):
            write_log(tmp_path / "x.rotest", _block())
    finally:
        registry._FORMATS.remove(fmt)


PLUGIN = """
import numpy as np
from imudiag.logs.base import LogReader, make_block
from imudiag.logs.registry import LogFormat


class ConstReader(LogReader):
    format = "const"

    def _blocks(self):
        n = 5
        cols = {k: np.zeros(n) for k in ("gx", "gy", "gz", "ax", "ay", "az")}
        cols["t"] = np.arange(n) * 0.5
        yield make_block(cols, self.meta)


FORMAT = LogFormat("const", (".const",), ConstReader, description="plug-in test format")
"""


def test_plugin_formats_come_from_entry_points(tmp_path: Path) -> None:
    """A distribution declaring imudiag.log_formats adds a format (python-can's model)."""
    import subprocess
    import sys

    (tmp_path / "imudiag_const_plugin.py").write_text(PLUGIN)
    dist = tmp_path / "imudiag_const_plugin-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text(
        "Metadata-Version: 2.1\nName: imudiag-const-plugin\nVersion: 0.1\n"
    )
    (dist / "entry_points.txt").write_text(
        "[imudiag.log_formats]\nconst = imudiag_const_plugin:FORMAT\n"
    )
    (tmp_path / "x.const").write_bytes(b"")
    code = (
        "import sys; sys.path.insert(0, sys.argv[1]);"
        "from imudiag.logs import read_log, log_format;"
        "b = read_log(sys.argv[1] + '/x.const'); print(log_format('a.const'), len(b), b.t[-1])"
    )
    r = subprocess.run(
        [sys.executable, "-c", code, str(tmp_path)], capture_output=True, text=True, timeout=120
    )
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == ["const", "5", "2.0"]

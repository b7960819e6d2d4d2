"""Text tables users already have: separators, headers or none, --columns, time units, --rate."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from imudiag.errors import BadInput
from imudiag.logs import LogError, LogOptions, open_log, read_log
from imudiag.logs.options import parse_columns, parse_units

RNG = np.random.default_rng(11)
N = 50
T = 100.0 + np.arange(N) * 0.01
G = RNG.normal(0, 0.01, (N, 3))
A = RNG.normal(0, 0.01, (N, 3)) + [0, 0, 9.81]


def _rows(sep: str, t_scale: float = 1.0, with_t: bool = True) -> list[str]:
    rows = []
    for i in range(N):
        vals = ([repr(float(T[i] / t_scale))] if with_t else []) + [
            repr(float(v)) for v in (*G[i], *A[i])
        ]
        rows.append(sep.join(vals))
    return rows


def _check(block, t=T) -> None:
    np.testing.assert_allclose(block.t, t, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(block.gyro, G)
    np.testing.assert_array_equal(block.accel, A)


@pytest.mark.parametrize("sep", [",", ";", "\t", " ", "   "])
def test_separators_with_a_header(tmp_path: Path, sep: str) -> None:
    head = sep.join(["time", "gyro_x", "gyro_y", "gyro_z", "acc_x", "acc_y", "acc_z"])
    path = tmp_path / "imu.txt"
    path.write_text("% recorded on a bench\n" + head + "\n" + "\n".join(_rows(sep)) + "\n")
    _check(read_log(path))


def test_semicolon_table_with_decimal_commas(tmp_path: Path) -> None:
    rows = [r.replace(".", ",") for r in _rows(";")]
    path = tmp_path / "imu.dat"
    path.write_text("\n".join(rows) + "\n")
    opts = LogOptions(columns=parse_columns("t,gx,gy,gz,ax,ay,az"))
    _check(read_log_opts(path, opts))


def read_log_opts(path: Path, opts: LogOptions):
    with open_log(path, options=opts) as reader:
        blocks = list(reader)
    from imudiag.samples import SampleBlock

    return SampleBlock.concat(blocks)


def test_headerless_without_time_needs_columns_and_rate(tmp_path: Path) -> None:
    path = tmp_path / "imu.txt"
    path.write_text("\n".join(_rows(" ", with_t=False)) + "\n")
    with pytest.raises(LogError, match="--columns") as exc:
        open_log(path)
    assert exc.value.line == 1
    with pytest.raises(LogError, match="--rate"):
        open_log(path, options=LogOptions(columns=parse_columns("gx,gy,gz,ax,ay,az")))
    opts = LogOptions(columns=parse_columns("gx,gy,gz,ax,ay,az"), rate=100.0)
    block = read_log_opts(path, opts)
    _check(block, t=np.arange(N) * 0.01)


def test_microsecond_time_and_skipped_columns(tmp_path: Path) -> None:
    rows = [f"{i},{r},junk" for i, r in enumerate(_rows(",", t_scale=1e-6))]
    path = tmp_path / "imu.csv"
    path.write_text("\n".join(rows) + "\n")
    with pytest.raises(LogError, match="--columns"):
        open_log(path)  # no header: the spec CSV reader and the table reader both need names
    opts = LogOptions(columns=parse_columns("_,t,gx,gy,gz,ax,ay,az,_"), time_unit="us")
    _check(read_log_opts(path, opts))


def test_bad_rows_name_file_and_line(tmp_path: Path) -> None:
    rows = _rows("\t")
    rows[7] = rows[7].replace(repr(float(G[7, 1])), "abc")
    path = tmp_path / "imu.tsv"
    path.write_text("t\tgx\tgy\tgz\tax\tay\taz\n" + "\n".join(rows) + "\n")
    with pytest.raises(LogError) as exc:
        read_log(path)
    assert exc.value.line == 9 and "not a number: 'abc'" in exc.value.reason
    rows = _rows("\t")
    rows[3] = rows[2]
    path.write_text("t\tgx\tgy\tgz\tax\tay\taz\n" + "\n".join(rows) + "\n")
    with pytest.raises(LogError, match="t not increasing") as exc:
        read_log(path)
    assert exc.value.line == 5


def test_option_values_are_checked() -> None:
    with pytest.raises(BadInput, match="unknown column 'wx'"):
        parse_columns("t,wx,gy,gz,ax,ay,az")
    with pytest.raises(BadInput, match="missing gx"):
        parse_columns("t,gy,gz,ax,ay,az")
    with pytest.raises(BadInput, match="furlong"):
        parse_units("gyro=furlong/s")
    assert parse_units("gyro=deg/s,accel=g") == {"gyro": "deg/s", "accel": "g"}

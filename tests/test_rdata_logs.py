"""R .rda / .RData / .rds logs written by R's own save() and saveRDS() (tests/data/rdata/).

One simulated session as the spec CSV and as an R data.frame: diagnose gives the same report.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
from conftest import run_imudiag_in_process, run_imudiag_without

from imudiag.logs import LogError, LogOptions, lookup, open_log, read_log
from imudiag.samples import SampleBlock

DATA = Path(__file__).parent / "data" / "rdata"
CSV = DATA / "session.csv.gz"


def _read(path: Path, options: LogOptions | None = None) -> SampleBlock:
    with open_log(path, options=options) as reader:
        block = SampleBlock.concat(list(reader))
        block.meta = reader.meta
    return block


def _report(*args: str) -> dict:
    """``imudiag diagnose ARGS --json -`` by the command's entry point in this process (the
    unreadable files below run it as a real subprocess)."""
    r = run_imudiag_in_process("diagnose", *args, "--json", "-")
    assert r.returncode == 0, r.stderr
    report = json.loads(r.stdout)
    report.pop("log", None)
    return report


def test_the_r_endings_are_one_format() -> None:
    for name in ("x.rda", "x.RData", "x.rds", "X.RDA"):
        fmt = lookup(name)
        assert fmt.name == "rdata" and fmt.extra == "r"


def test_data_frame_reads_the_same_samples_as_the_csv() -> None:
    ref = read_log(CSV)
    got = _read(DATA / "session.rda", LogOptions(variable="imu"))
    assert len(got) == len(ref) == 3075
    np.testing.assert_array_equal(got.t, ref.t)
    np.testing.assert_array_equal(got.gyro, ref.gyro)
    np.testing.assert_array_equal(got.accel, ref.accel)
    np.testing.assert_array_equal(got.temp, ref.temp)
    assert got.meta["source"] == "R data.frame 'imu'"


def test_several_objects_are_listed_and_chosen_with_variable() -> None:
    with pytest.raises(LogError, match="choose one with --variable NAME") as exc:
        open_log(DATA / "session.rda")
    assert "imu (data.frame 3075x8)" in exc.value.reason
    assert "gain (matrix 3x3)" in exc.value.reason
    with pytest.raises(
        LogError, match=r"no object 'nope' \(--variable\); the file has \['gain', 'imu'\]"
    ):
        open_log(DATA / "session.rda", options=LogOptions(variable="nope"))
    with pytest.raises(LogError, match="matrix 'gain' is 3x3: name its columns with --columns"):
        open_log(DATA / "session.rda", options=LogOptions(variable="gain"))


def test_unnamed_matrix_rds_by_position() -> None:
    ref = read_log(CSV).slice(0, 500)
    got = _read(DATA / "session_matrix.rds")
    np.testing.assert_array_equal(got.t, ref.t)
    np.testing.assert_array_equal(got.gyro, ref.gyro)
    np.testing.assert_array_equal(got.accel, ref.accel)
    assert got.temp is None
    with pytest.raises(LogError, match="--variable does not apply to an .rds file"):
        open_log(DATA / "session_matrix.rds", options=LogOptions(variable="imu"))
    # --columns renames by position: ax/gx swapped reads the other triad's values
    cols = ["t", "ax", "ay", "az", "gx", "gy", "gz"]
    swapped = _read(DATA / "session_matrix.rds", LogOptions(columns=cols))
    np.testing.assert_array_equal(swapped.gyro, ref.accel)


def test_named_matrix_columns_by_name_in_any_order() -> None:
    ref = read_log(CSV).slice(0, 500)
    got = _read(DATA / "session_named.RData")  # the character vector is not a candidate
    np.testing.assert_array_equal(got.t, ref.t)
    np.testing.assert_array_equal(got.gyro, ref.gyro)
    np.testing.assert_array_equal(got.accel, ref.accel)
    with pytest.raises(LogError, match="object 'note' is a vector, not a data.frame"):
        open_log(DATA / "session_named.RData", options=LogOptions(variable="note"))


def test_diagnose_on_rda_equals_diagnose_on_csv() -> None:
    ref = _report(str(CSV))
    got = _report(str(DATA / "session.rda"), "--variable", "imu")
    assert ref["verdict"]["accel"] == "fault"
    assert [f["sensor"] for f in ref["verdict"]["faults"]] == ["az", None]
    assert got == ref  # verdict, faults and every window's estimates, to the last bit


def test_missing_rdata_is_exit_2_with_the_pip_command() -> None:
    r = run_imudiag_without("rdata", "diagnose", str(DATA / "session.rda"), "--variable", "imu")
    assert r.returncode == 2, r.stderr
    assert "'rdata'" in r.stderr and "pip install 'imudiag[r]'" in r.stderr
    assert "Traceback" not in r.stderr


@pytest.mark.parametrize("damage", ["garbage", "truncated", "missing"])
def test_unreadable_r_file_is_one_line_exit_2(tmp_path: Path, damage: str) -> None:
    path = tmp_path / "bad.rda"
    if damage == "garbage":
        path.write_bytes(b"not an R file at all\n")
    elif damage == "truncated":
        path.write_bytes((DATA / "session.rda").read_bytes()[:200])
    if damage == "truncated":  # the real subprocess; the other damages in this process
        r = subprocess.run(
            [sys.executable, "-m", "imudiag", "diagnose", str(path)],
            capture_output=True,
            text=True,
            timeout=120,
        )
    else:
        # pytest records warnings raised in this process instead of printing them: caught
        # here, none may be raised (a new process would print each on stderr)
        with warnings.catch_warnings(record=True) as raised:
            warnings.simplefilter("always")
            r = run_imudiag_in_process("diagnose", str(path))
        assert raised == [], [str(w.message) for w in raised]
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and str(path) in lines[0], r.stderr
    assert "Traceback" not in r.stderr and "Warning" not in r.stderr


def test_convert_rda_to_csv(tmp_path: Path) -> None:
    src = tmp_path / "session.RData"
    shutil.copy(DATA / "session_named.RData", src)
    out = tmp_path / "out.csv"
    r = run_imudiag_in_process("convert", str(src), str(out))
    assert r.returncode == 0, r.stderr
    np.testing.assert_array_equal(read_log(out).accel, read_log(CSV).slice(0, 500).accel)


def test_text_and_factor_columns_are_ignored_unless_read() -> None:
    ref = read_log(CSV).slice(0, 50)
    got = _read(DATA / "session_tagged.rds")  # label (text) and pose (factor) not named
    np.testing.assert_array_equal(got.gyro, ref.gyro)
    np.testing.assert_array_equal(got.accel, ref.accel)
    cols = ["t", "gx", "gy", "gz", "ax", "ay", "_", "az", "_"]  # label read as az
    with pytest.raises(LogError, match="the column read as az is not numeric"):
        open_log(DATA / "session_tagged.rds", options=LogOptions(columns=cols))

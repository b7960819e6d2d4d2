"""MATLAB .mat logs written by the real libraries (scipy.io.savemat v5, h5py v7.3 layout).

One simulated session as the spec CSV and as .mat: diagnose gives the same report.
"""

from __future__ import annotations

import json
from pathlib import Path

import h5py  # the [test] extra installs both
import numpy as np
import pytest
import scipy.io as scipy_io
from conftest import run_imudiag_in_process, run_imudiag_without

from imudiag.logs import LogError, LogOptions, open_log, read_log


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    from imudiag.certificate import load_default
    from imudiag.logs import open_writer
    from imudiag.sim import Fault, multi_position, simulate

    cert = load_default()
    traj = multi_position(n_attitudes=14, dwell_s=3.0, turn_s=1.5, rate_hz=200, seed=21)
    lim = cert.accel.limits.scale_factor_error[2]
    sim = simulate(cert, traj, seed=22, faults=[Fault("scale_factor", "az", 0.0, 4 * lim)])
    d = tmp_path_factory.mktemp("mat")
    s = sim.samples
    with open_writer(d / "session.csv", {}) as w:
        w.write(s)
    m = np.column_stack([s.t, s.gyro, s.accel])
    # v5, as MATLAB's save: the session matrix and a distractor
    scipy_io.savemat(d / "session_v5.mat", {"imu": m, "gain": np.eye(3)})
    # v7.3: HDF5 behind MATLAB's 512-byte text header; datasets hold the transpose
    v73 = d / "session_v73.mat"
    with h5py.File(v73, "w", userblock_size=512) as f:
        f.create_dataset("imu", data=m.T)
        f.create_dataset("gain", data=np.eye(3))
    with open(v73, "r+b") as fh:
        fh.write(b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: imudiag test".ljust(116))
    return d, s


def _report(*args: str) -> dict:
    """``imudiag diagnose ARGS --json - --no-windows`` by the command's entry point in this
    process (a missing extra below runs it as a real subprocess)."""
    r = run_imudiag_in_process("diagnose", *args, "--json", "-", "--no-windows")
    assert r.returncode == 0, r.stderr
    report = json.loads(r.stdout)
    report.pop("log", None)
    return report


@pytest.mark.parametrize("name", ["session_v5.mat", "session_v73.mat"])
def test_mat_reads_the_same_samples(session, name: str) -> None:
    d, s = session
    path = d / name
    with pytest.raises(LogError, match="--variable") as exc:
        open_log(path)  # two 2-D matrices: the user chooses
    assert "imu" in exc.value.reason and "gain" in exc.value.reason
    with open_log(path, options=LogOptions(variable="imu")) as reader:
        blocks = list(reader)
        assert "imu" in reader.meta["source"]
    from imudiag.samples import SampleBlock

    got = SampleBlock.concat(blocks)
    np.testing.assert_array_equal(got.t, s.t)
    np.testing.assert_array_equal(got.gyro, s.gyro)
    np.testing.assert_array_equal(got.accel, s.accel)
    with pytest.raises(LogError, match="no variable 'nope'"):
        open_log(path, options=LogOptions(variable="nope"))


@pytest.mark.parametrize("name", ["session_v5.mat", "session_v73.mat"])
def test_diagnose_on_mat_equals_diagnose_on_csv(session, name: str) -> None:
    d, _ = session
    ref = _report(str(d / "session.csv"))
    got = _report(str(d / name), "--variable", "imu")
    assert ref["verdict"]["accel"] == "fault"
    assert got == ref


@pytest.mark.parametrize(
    ("name", "mod"), [("session_v5.mat", "scipy"), ("session_v73.mat", "h5py")]
)
def test_missing_extra_is_exit_2_with_the_pip_command(session, name: str, mod: str) -> None:
    d, _ = session
    r = run_imudiag_without(mod, "diagnose", str(d / name), "--variable", "imu")
    assert r.returncode == 2, r.stderr
    assert f"'{mod}'" in r.stderr and "pip install 'imudiag[mat]'" in r.stderr
    assert "Traceback" not in r.stderr


def test_mat_without_time_uses_rate(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    m = rng.normal(size=(6, 40))  # a 6 x N matrix, as MATLAB users often store it
    scipy_io.savemat(tmp_path / "raw.mat", {"data": m})
    block = read_log_opts(tmp_path / "raw.mat", LogOptions(rate=50.0))
    np.testing.assert_allclose(block.t, np.arange(40) / 50.0)
    np.testing.assert_array_equal(block.gyro, m[:3].T)
    with pytest.raises(LogError, match="--columns"):
        open_log(tmp_path / "raw.mat")


def read_log_opts(path: Path, opts: LogOptions):
    from imudiag.samples import SampleBlock

    with open_log(path, options=opts) as reader:
        return SampleBlock.concat(list(reader))


def test_read_log_of_a_plain_mat(tmp_path: Path) -> None:
    t = np.arange(10) * 0.1
    m = np.column_stack([t, np.ones((10, 6))])
    scipy_io.savemat(tmp_path / "one.mat", {"imu": m})
    assert len(read_log(tmp_path / "one.mat")) == 10

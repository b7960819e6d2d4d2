"""`imudiag diagnose` as spec/reports.md says: report keys, verdicts, bad input, methods.

Real subprocesses: the report written to a file (test_report_shape_and_verdict), to stdout
(test_json_to_stdout), the first refusal of test_bad_certificate_and_log and the linear method;
the other cases run the command's entry point in this process
(``conftest.run_imudiag_in_process``: the same exit status and output)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from conftest import run_imudiag_in_process

from imudiag.certificate import load_default
from imudiag.diagnosis.inputs import write_magnitudes
from imudiag.logs import open_writer
from imudiag.sim import Fault, multi_position, simulate, still, turntable

UNITS = "gyro=count accel=count"


def _write(path: Path, sim, units: str | None = UNITS) -> Path:
    meta = {"sample_rate": sim.truth.rate_hz}
    if units:
        meta["units"] = units
    with open_writer(path, meta) as w:
        w.write(sim.samples)
    return path


@pytest.fixture(scope="module")
def faulty_log(tmp_path_factory):
    """A MEMS multi-position session with a 4-limit scale-factor fault on az, and its truth."""
    cert = load_default()
    traj = multi_position(n_attitudes=14, dwell_s=3.0, turn_s=1.5, rate_hz=200, seed=21)
    lim = cert.accel.limits.scale_factor_error[2]
    sim = simulate(cert, traj, seed=22, faults=[Fault("scale_factor", "az", 0.0, 4 * lim)])
    d = tmp_path_factory.mktemp("diag")
    log = _write(d / "faulty.npz", sim)
    mags = d / "magnitudes.csv"
    write_magnitudes(
        mags,
        traj.t,
        np.linalg.norm(traj.specific_force, axis=1),
        np.linalg.norm(traj.omega, axis=1),
    )
    return log, mags, sim


def test_report_shape_and_verdict(faulty_log, imudiag_cli, tmp_path):
    log, _, sim = faulty_log
    out = tmp_path / "report.json"
    r = imudiag_cli(
        "diagnose", str(log), "--certificate", "config/default-certificate.yaml", "--json", str(out)
    )
    assert r.returncode == 0, r.stderr
    rep = json.loads(out.read_text())
    assert rep["format"] == "imudiag-diagnosis/1"
    assert rep["samples"] == len(sim.samples)
    for triad in ("accel", "gyro"):
        assert set(rep["f0"][triad]) == {"checked", "failed"}
        assert 0 <= rep["f0"][triad]["failed"] <= rep["f0"][triad]["checked"] <= rep["samples"]
    v = rep["verdict"]
    assert (v["accel"], v["gyro"]) == ("fault", "ok")
    (f,) = [f for f in v["faults"] if f["cause"] != "f0"]
    # the persistent F0 failure the daemon would raise too, explained by the named fault
    for f0_fault in (f for f in v["faults"] if f["cause"] == "f0"):
        assert f0_fault["triad"] == "accel"
        assert f0_fault["explained_by"] == [{"sensor": "az", "cause": "scale_factor"}]
        assert {"sensor", "estimate", "limit", "t_first", "raised"} <= set(f0_fault)
    assert {"triad", "sensor", "cause", "estimate", "certificate", "limit", "t_first"} <= set(f)
    assert (f["triad"], f["sensor"], f["cause"]) == ("accel", "az", "scale_factor")
    cert = load_default()
    assert f["certificate"] == pytest.approx(cert.accel.scale_factor_error[2])
    assert f["limit"] == pytest.approx(cert.accel.limits.scale_factor_error[2])
    assert f["estimate"] == pytest.approx(f["certificate"] + 4 * f["limit"], abs=0.1 * f["limit"])
    assert v["undetermined"] == []
    w = rep["windows"][-1]
    for triad in ("accel", "gyro"):
        for key in ("bias", "scale_factor", "misalignment"):
            assert len(w[triad][key]["estimate"]) == 3 and len(w[triad][key]["std"]) == 3
    assert "FAULT accel az scale_factor" in r.stdout
    # every number of the fault says its unit, in the report and in the text
    assert f["unit"] == "count/(m/s^2)"
    (line,) = [ln for ln in r.stdout.splitlines() if "FAULT accel az scale_factor" in ln]
    for word in ("estimate", "certificate", "limit"):
        assert re.search(rf"{word} [-+0-9.e]+ count/\(m/s\^2\),", line), line


def test_json_to_stdout(faulty_log, imudiag_cli):
    log, _, _ = faulty_log
    r = imudiag_cli("diagnose", str(log), "--json", "-", "--no-windows")
    assert r.returncode == 0, r.stderr
    rep = json.loads(r.stdout)
    assert rep["windows"] == [] and rep["verdict"]["accel"] == "fault"


def test_units_mismatch_names_both(tmp_path, imudiag_in_process):
    cert = load_default()
    sim = simulate(cert, still(3.0, 200), seed=1)
    log = _write(tmp_path / "units.csv", sim, units="gyro=deg/s accel=count")
    r = imudiag_in_process("diagnose", str(log), "--certificate", "config/default-certificate.yaml")
    assert r.returncode == 2
    assert "deg/s" in r.stderr and "'count'" in r.stderr and "gyro.output_unit" in r.stderr
    assert "default-certificate.yaml" in r.stderr and "units.csv" in r.stderr


def test_one_attitude_is_undetermined_never_ok(tmp_path, imudiag_in_process):
    cert = load_default()
    sim = simulate(cert, still(40.0, 200, attitude_rpy_deg=(10, -5, 30)), seed=2)
    log = _write(tmp_path / "still.npz", sim)
    r = imudiag_in_process("diagnose", str(log), "--json", "-")
    assert r.returncode == 0, r.stderr
    v = json.loads(r.stdout)["verdict"]
    assert (v["accel"], v["gyro"]) == ("undetermined", "undetermined")
    assert v["faults"] == []
    und = {(u["triad"], u["sensor"], u["cause"]): u["reason"] for u in v["undetermined"]}
    # gyro biases are seen at rest; scale factor and misalignment need rotations
    assert ("gyro", "gx", "bias") not in und
    assert und[("gyro", "gy", "scale_factor")] == "no rotation between static poses"
    assert "1 distinct attitude" in und[("accel", "ax", "scale_factor")]
    # the std and the limit it is compared with, each with its unit
    assert re.match(
        r"std [0-9.e+-]+ count/\(m/s\^2\) above 0\.5 x limit [0-9.e+-]+ count/\(m/s\^2\);",
        und[("accel", "ax", "scale_factor")],
    )
    assert re.match(r"std [0-9.e+-]+ count above", und[("accel", "ay", "bias")])
    assert re.match(r"std [0-9.e+-]+ rad above", und[("accel", "ax/az", "misalignment")])


def test_no_still_period_is_undetermined(tmp_path, imudiag_in_process):
    cert = load_default()
    sim = simulate(cert, turntable(30.0, axis="x", duration_s=20.0, rate_hz=200), seed=3)
    log = _write(tmp_path / "turning.npz", sim)
    r = imudiag_in_process("diagnose", str(log), "--json", "-")
    rep = json.loads(r.stdout)
    assert rep["verdict"]["accel"] == "undetermined" and rep["verdict"]["gyro"] == "undetermined"
    assert all("no quasi-static interval" in u["reason"] for u in rep["verdict"]["undetermined"])


def test_bad_certificate_and_log(tmp_path, imudiag_cli, faulty_log):
    bad = tmp_path / "bad.yaml"
    bad.write_text(
        Path("config/default-certificate.yaml")
        .read_text()
        .replace("bias: [21.0, 21.0, 21.0]", "bias: [21.0, 21.0]")
    )
    r = imudiag_cli("diagnose", str(faulty_log[0]), "--certificate", str(bad))
    assert r.returncode == 2 and "accel.limits.bias" in r.stderr
    broken = tmp_path / "broken.csv"
    broken.write_text("t,gx,gy,gz,ax,ay,az\n0,1,2,3,4,5,6\n0.005,1,2,x,4,5,6\n")
    r = run_imudiag_in_process("diagnose", str(broken))
    assert r.returncode == 2 and "broken.csv:3" in r.stderr
    r = run_imudiag_in_process("diagnose", str(faulty_log[0]), "--magnitude", str(faulty_log[1]))
    assert r.returncode == 2 and "--magnitude" in r.stderr


@pytest.mark.parametrize("method", ["linear", "moving-base"])
def test_other_methods_run(faulty_log, imudiag_cli, method):
    log, mags, _ = faulty_log
    args = ["diagnose", str(log), "--method", method, "--json", "-"]
    if method == "moving-base":
        args += ["--magnitude", str(mags)]
    # one method as a real subprocess, the other through cli.main in this process (the
    # same exit status and output: conftest.run_imudiag_in_process)
    r = (imudiag_cli if method == "linear" else run_imudiag_in_process)(*args)
    assert r.returncode == 0, r.stderr
    rep = json.loads(r.stdout)
    assert rep["method"] == method and rep["windows"]
    assert all(w["method"] in (method, "linear") for w in rep["windows"])
    # both variants see the large accelerometer scale fault (with or without company)
    assert ("accel", "az", "scale_factor") in {
        (f["triad"], f["sensor"], f["cause"]) for f in rep["verdict"]["faults"]
    }


def test_moving_base_without_magnitude_warns(faulty_log, imudiag_in_process):
    r = imudiag_in_process("diagnose", str(faulty_log[0]), "--method", "moving-base")
    assert r.returncode == 0
    assert "cannot see faults" in r.stderr


def test_parameter_units_read_unambiguously():
    """A scale-factor error's unit is output per input unit, each side in parentheses when
    it is a quotient itself (``m/s^2/(m/s^2)`` would read as something else)."""
    from imudiag.certificate import load
    from imudiag.diagnosis.params import cause_unit, parameter_units

    data = Path(__file__).parent / "data"
    units = {
        "default": parameter_units(load_default().accel),
        "si in, si out": parameter_units(load(data / "diagnosis" / "like-imucal.yaml").accel),
        "g in, g out": parameter_units(
            load(data / "real" / "gnss-imu-drive" / "nominal-certificate.yaml").accel
        ),
    }
    assert units["default"] == ("count",) * 3 + ("count/(m/s^2)",) * 3 + ("rad",) * 3
    assert units["si in, si out"][3:6] == ("(m/s^2)/(m/s^2)",) * 3
    assert units["g in, g out"][:6] == ("g",) * 3 + ("g/g",) * 3
    assert cause_unit(load_default().gyro, "scale_factor") == "count/(deg/s)"
    with pytest.raises(ValueError, match="f0"):
        cause_unit(load_default().gyro, "f0")

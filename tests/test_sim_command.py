"""``imudiag simulate`` and ``imudiag allan`` as real subprocesses, and the benchmark script.

A parametrized check runs one of its cases as a real subprocess (the CLI is the contract)
and the others through the command's entry point in this process
(:func:`conftest.run_imudiag_in_process`, the same exit status and output)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import run_imudiag, run_imudiag_in_process

from imudiag.certificate import load
from imudiag.logs import open_log, read_log
from imudiag.sim import Effects, Fault, simulate
from imudiag.sim.scenarios import parse_effects, scenario_motion

PROJECT_DIR = Path(__file__).parent.parent


@pytest.mark.parametrize("ext", [".csv", ".csv.gz", ".npz", ".bin"])
def test_simulate_writes_every_format(tmp_path, default_certificate, ext):
    out = tmp_path / f"session{ext}"
    run = run_imudiag if ext == ".bin" else run_imudiag_in_process  # module docstring
    r = run(
        "simulate",
        "multiposition",
        "--seed",
        "4",
        "--out",
        str(out),
        "--param",
        "n=6",
        "--param",
        "dwell=1",
        "--fault",
        "bias:ax:3:150",
        "--effect",
        "temperature:20:5:30",
        "--effect",
        "temperature_bias:gx:1.5",
    )
    assert r.returncode == 0, r.stderr
    assert "samples" in r.stdout
    with open_log(out) as reader:
        blocks = list(reader)
        meta = reader.meta
    got = read_log(out)
    assert len(got) == sum(len(b) for b in blocks)
    motion = scenario_motion("multiposition", 4, {"n": "6", "dwell": "1"})
    eff = parse_effects(["temperature:20:5:30", "temperature_bias:gx:1.5"])
    exp = simulate(
        default_certificate,
        motion.sample(200),
        seed=4,
        effects=eff,
        faults=[Fault("bias", "ax", 3.0, 150.0)],
    ).samples
    assert len(got) == len(exp) == int(round(motion.duration_s * 200))
    np.testing.assert_array_equal(got.gyro, exp.gyro)
    np.testing.assert_array_equal(got.accel, exp.accel)
    np.testing.assert_allclose(got.t, exp.t, atol=1e-12)
    np.testing.assert_allclose(got.temp, exp.temp, atol=1e-9)
    assert float(meta["sample_rate"]) == 200.0
    assert meta["faults"] == "bias:ax:3:150"
    # .bin: seq is u16 on the wire, read back unwrapped from the first sample frame's own
    # value (the info frame before it is stamped 65535, just below 0): the same numbers
    np.testing.assert_array_equal(got.seq, exp.seq)


def test_simulate_true_certificate_and_duration(tmp_path, imudiag_cli, default_certificate):
    out, cert = tmp_path / "s.npz", tmp_path / "true.yaml"
    r = imudiag_cli(
        "simulate",
        "static",
        "--duration",
        "12.5",
        "--seed",
        "1",
        "--rate",
        "100",
        "--out",
        str(out),
        "--fault",
        "scale_factor:gz:5:0.5",
        "--effect",
        "g_sensitivity:gx:1:0:0",
        "--true-certificate",
        str(cert),
    )
    assert r.returncode == 0, r.stderr
    assert len(read_log(out)) == 1250
    true = load(cert)
    assert true.gyro.scale_factor_error[2] == pytest.approx(
        default_certificate.gyro.scale_factor_error[2] + 0.5
    )
    np.testing.assert_array_equal(true.gyro.g_sensitivity[0], [1.0, 0.0, 0.0])


@pytest.mark.parametrize(
    "args,msg",
    [
        (["static", "--out", "x.csv"], "--duration: required"),
        (["static", "--duration", "5", "--out", "x.csv", "--effect", "foo:1"], "unknown effect"),
        (
            ["static", "--duration", "5", "--out", "x.csv", "--fault", "bias:qx:1:2"],
            "unknown sensor 'qx'",
        ),
        (["nowhere", "--duration", "5", "--out", "x.csv"], "unknown scenario"),
        (["static", "--duration", "5", "--out", "x.txt"], "unknown log format"),
        (["static", "--duration", "-1", "--out", "x.csv"], "--duration: must be > 0"),
        (["vehicle", "--out", "x.csv", "--param", "speed=fast"], "speed must be a number"),
        (
            ["still", "--duration", "1", "--out", "x.csv", "--certificate", "missing.yaml"],
            "missing.yaml",
        ),
    ],
)
def test_simulate_bad_input_exit_2(tmp_path, args, msg):
    run = run_imudiag if msg == "unknown effect" else run_imudiag_in_process  # module docstring
    args = [a if a not in ("x.csv", "x.txt") else str(tmp_path / a) for a in args]
    r = run("simulate", *args)
    assert r.returncode == 2, (r.stdout, r.stderr)
    assert msg in r.stderr
    assert not (tmp_path / "x.csv").exists()


def test_allan_command_identifies_noise(tmp_path, imudiag_cli, default_certificate):
    log = tmp_path / "still.npz"
    r = run_imudiag_in_process(
        "simulate",
        "still",
        "--duration",
        "1800",
        "--rate",
        "50",
        "--seed",
        "2",
        "--out",
        str(log),
        "--effect",
        "bias_drift:gy:2",
    )
    assert r.returncode == 0, r.stderr
    out = tmp_path / "allan.json"
    r = imudiag_cli("allan", str(log), "--json", str(out))
    assert r.returncode == 0, r.stderr
    assert "gx" in r.stdout and "K [u/rts]" in r.stdout
    rep = json.loads(out.read_text())
    assert rep["format"] == "imudiag-allan/1" and rep["samples"] == 90000
    assert rep["rate_hz"] == 50 and rep["gaps"] == 0
    for name, density in (("gx", 6.55), ("az", 0.82)):
        s = rep["sensors"][name]
        assert abs(s["density_one_sided"] / density - 1) < 0.05
        assert abs(s["psd_white_density"] / density - 1) < 0.05
    assert abs(rep["sensors"]["gy"]["random_walk"] / 2.0 - 1) < 0.2
    assert len(rep["sensors"]["gx"]["allan"]["tau"]) == len(rep["sensors"]["gx"]["allan"]["adev"])
    # --json - writes only JSON on stdout
    r = run_imudiag_in_process("allan", str(log), "--json", "-", "--sensors", "ax", "--stop", "600")
    assert r.returncode == 0
    rep2 = json.loads(r.stdout)
    assert list(rep2["sensors"]) == ["ax"] and rep2["samples"] == 30001


def test_allan_bad_input(tmp_path, imudiag_in_process):
    imudiag_cli = imudiag_in_process  # module docstring: allan runs as a subprocess above
    r = imudiag_cli("allan", str(tmp_path / "none.csv"))
    assert r.returncode == 2 and "none.csv" in r.stderr
    bad = tmp_path / "bad.csv"
    bad.write_text("t,gx,gy,gz,ax,ay,az\n0,1,2,3,4,5,6\n0.01,1,2,x,4,5,6\n")
    r = imudiag_cli("allan", str(bad))
    assert r.returncode == 2 and "bad.csv:3" in r.stderr
    log = tmp_path / "s.csv"
    assert imudiag_cli("simulate", "still", "--duration", "1", "--out", str(log)).returncode == 0
    r = imudiag_cli("allan", str(log), "--sensors", "gq")
    assert r.returncode == 2 and "unknown sensor 'gq'" in r.stderr


def test_effect_text_forms():
    e = parse_effects(
        [
            "none",
            "bias_instability:gx:2:100",
            "periodic_disturbance:ay:3:50:0.5",
            "bias_step:gz:10:5",
            "saturation:100:60000",
            "adc_error:0.001",
            "drop:0.01",
            "jitter:0.0001",
            "noise:2",
            "scale_nonlinearity:ax:0.01",
            "temperature_scale:gy:1e-4",
        ]
    )
    assert not e.quantize and e.white_noise and e.noise_scale == 2.0
    assert e.bias_instability == {"gx": (2.0, 100.0)}
    assert e.periodic_disturbance[0].phase_rad == 0.5 and e.bias_step[0].size == 5.0
    assert e.saturation == (100.0, 60000.0) and e.drop_rate == 0.01
    assert parse_effects(["all"]).bias_drift == Effects.all_on().bias_drift
    assert parse_effects(["noise:0"]).white_noise is False
    for bad in [
        "bias_drift:gx",
        "saturation:5:1",
        "drop:2",
        "temperature:20:5:0",
        "g_sensitivity:ax:1:2:3",
        "bias_instability:gx:1:0",
    ]:
        with pytest.raises(ValueError):
            parse_effects([bad])


def test_benchmark_script_runs():
    r = subprocess.run(
        [
            sys.executable,
            "benchmarks/simulate.py",
            "--duration",
            "20",
            "--rate",
            "1000",
            "--chunk",
            "5",
        ],
        cwd=PROJECT_DIR,
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert r.returncode == 0, r.stderr
    assert "20000 samples" in r.stdout and "faster than real time" in r.stdout


@pytest.mark.parametrize("ext", ["csv", "csv.gz", "npz", "bin"])
def test_simulate_refuses_a_session_larger_than_the_free_space(tmp_path, ext):
    """1e9 s at the bundled 200 Hz is 2e11 samples: terabytes in every format, more than the
    real filesystem of tmp_path holds; refused before anything is written."""
    out = tmp_path / f"huge.{ext}"
    free = shutil.disk_usage(tmp_path).free
    from imudiag.logs import lookup

    assert lookup(out).bytes_per_sample * 2e11 > free  # the premise, on this machine
    run = run_imudiag if ext == "csv" else run_imudiag_in_process  # module docstring
    r = run("simulate", "static", "--duration", "1e9", "--out", str(out))
    assert r.returncode == 2, (r.stdout, r.stderr)
    line = r.stderr.strip()
    assert len(line.splitlines()) == 1 and "Traceback" not in line
    assert "--duration: 1e+09 s at 200 Hz is 200000000000 samples" in line
    assert "free on the filesystem of" in line and str(tmp_path) in line
    assert list(tmp_path.iterdir()) == []  # not even a temporary part file


def test_simulate_free_space_estimate_is_near_what_is_written(tmp_path):
    """The per-format estimate is within a factor 1.5 of the real size of a written log
    (the command in this process: test_simulate_writes_every_format runs it as a real
    subprocess)."""
    from imudiag.logs import lookup

    for ext in ("csv", "csv.gz", "npz", "bin"):
        out = tmp_path / f"s.{ext}"
        r = run_imudiag_in_process("simulate", "static", "--duration", "10", "--out", str(out))
        assert r.returncode == 0, r.stderr
        per_sample = out.stat().st_size / 2000
        estimate = lookup(out).bytes_per_sample
        assert estimate / 1.5 < per_sample < estimate * 1.5, (ext, per_sample, estimate)


@pytest.mark.parametrize(
    ("fault", "refused"),
    [
        ("bias:ax:60:150", True),  # at the end of a 60 s session
        ("scale_factor:gz:61:0.1", True),  # after it
        ("stuck:gy:1e6", True),
        ("bias:ax:59.9975:150", True),  # after the last sample (t = 59.995 s at 200 Hz)
        ("bias:ax:59.995:150", False),  # on the last sample: one faulty sample
        ("bias:ax:30:150", False),
    ],
)
def test_simulate_refuses_a_fault_at_or_after_the_end(tmp_path, fault, refused):
    out = tmp_path / "f.npz"
    run = run_imudiag if fault == "bias:ax:60:150" else run_imudiag_in_process  # module doc
    r = run("simulate", "static", "--duration", "60", "--out", str(out), "--fault", fault)
    if not refused:
        assert r.returncode == 0, r.stderr
        return
    assert r.returncode == 2, (r.stdout, r.stderr)
    assert r.stderr.count("\n") == 1 and "Traceback" not in r.stderr
    assert f"--fault {':'.join(fault.split(':')[:2])}:" in r.stderr
    assert "at or after the end of the session (60 s, last sample at t = 59.995 s)" in r.stderr
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_simulate_absurd_duration_message_stays_short(tmp_path, imudiag_cli):
    r = imudiag_cli("simulate", "static", "--duration", "1e300", "--out", str(tmp_path / "x.csv"))
    assert r.returncode == 2, r.stderr
    assert "is 2e+302 samples, about 1.4e+286 EB as .csv" in r.stderr
    assert len(r.stderr) < 300 and list(tmp_path.iterdir()) == []

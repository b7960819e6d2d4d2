"""Issue 30 item 4: the library as a contract.

- every configuration is validated by the one validator (imudiag.validate) and a bad value
  raises the project's BadInput naming the key: imudiag.diagnose's configuration, the
  StreamingDiagnoser's (and its rate), the daemon's DaemonConfig built in code;
- one noise default for streaming and offline (diagnosis.config.CERTIFICATE_NOISE): a
  StreamingDiagnoser left at its defaults gives the windows and verdict of imudiag.diagnose;
- the sample flags are honoured by the GNSS aiding: a flagged burst in a moving-base
  drive does not move its estimates (the flagged samples count as absent);
- GNSS aiding is callable from the library on samples and a GNSS stream
  (imudiag.moving_base), giving the section ``imudiag diagnose --gnss`` gives;
- the report is typed (imudiag.DiagnosisReport): every key of every report, the frozen
  ones included, is a documented key, and the JSON is the plain dict it always was.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

import imudiag
from imudiag import validate
from imudiag.aiding.moving import MovingConfig, moving_base_diagnosis
from imudiag.aiding.tpv import parse_tpv, track_from_reports
from imudiag.certificate import load_default
from imudiag.diagnosis import DiagnosisConfig, StreamingDiagnoser
from imudiag.diagnosis.config import CERTIFICATE_NOISE
from imudiag.diagnosis.session import DEFAULT_BLOCK_SIZE
from imudiag.errors import EXIT_BAD_INPUT, BadInput, exit_code
from imudiag.samples import FLAG_ACCEL_SATURATED, FLAG_GYRO_SATURATED, SampleBlock
from imudiag.service.config import DaemonConfig
from imudiag.sim import Fault, multi_position, simulate
from imudiag.sim.drive import simulate_drive, write_gpspipe_log

CERT = load_default()


# ---------------------------------------------------------------------------
# the one validator


@pytest.mark.parametrize(
    ("call", "reason"),
    [
        (lambda: validate.number("3", "a.b"), "a.b: expected a number, got '3'"),
        (lambda: validate.number(True, "a.b"), "a.b: expected a number, got True"),
        (lambda: validate.number(math.nan, "a.b"), "a.b: not a finite number: nan"),
        (lambda: validate.number(10**400, "a.b"), "a.b: not a finite number: integer beyond"),
        (lambda: validate.number(-1, "a.b", 0.0, lo_open=True), "a.b: -1.0 is out of range (0,"),
        (lambda: validate.number(5, "a.b", 0, 1, unit="s"), "a.b: 5.0 is out of range [0, 1] s"),
        (
            lambda: validate.number(1.0, "a.b", 0, 1, hi_open=True),
            "a.b: 1.0 is out of range [0, 1)",
        ),
        (lambda: validate.integer(2.0, "n"), "n: expected an integer, got 2.0"),
        (lambda: validate.integer(0, "n", 1), "n: 0 is out of range [1, inf]"),
        (lambda: validate.integer(7, "n", 1, 5), "n: 7 is out of range [1, 5]"),
        (lambda: validate.boolean(1, "x"), "x: expected true or false, got 1"),
        (lambda: validate.text(" ", "x"), "x: expected a non-empty string, got ' '"),
        (lambda: validate.text("c", "x", ("a", "b")), "x: expected one of a, b, got 'c'"),
    ],
)
def test_the_validator_names_the_key_and_the_reason(call, reason):
    with pytest.raises(BadInput) as info:
        call()
    assert str(info.value).startswith(reason)
    assert exit_code(info.value) == EXIT_BAD_INPUT


def test_the_validator_passes_good_values_and_the_readers_own_error():
    assert validate.number(np.float32(0.5), "k", 0, 1) == 0.5
    assert validate.integer(np.int64(3), "k", 1) == 3
    assert validate.text(" exact ", "k", ("exact",)) == "exact"

    class Mine(BadInput):
        pass

    with pytest.raises(Mine, match="^file.yaml:3: k: expected"):
        validate.integer("x", lambda reason: Mine(f"file.yaml:3: k: {reason}"))


# ---------------------------------------------------------------------------
# item 4a: validated configuration


@pytest.fixture(scope="module")
def session() -> SampleBlock:
    """A 12-attitude session whose noise is 6 times the certificate's (100 Hz)."""
    traj = multi_position(n_attitudes=12, rate_hz=100.0, seed=3)
    noisy = [Fault("noise", s, 0.0, 6.0) for s in ("gx", "gy", "gz", "ax", "ay", "az")]
    return simulate(CERT, traj, seed=4, faults=noisy).samples


@pytest.mark.parametrize(
    ("config", "key"),
    [
        ({"determined_std_ratio": -0.5}, "diagnosis.determined_std_ratio"),
        ({"determined_std_ratio": 0.0}, "diagnosis.determined_std_ratio"),
        ({"prior_factor": math.inf}, "diagnosis.prior_factor"),
        ({"k_sigma": "4"}, "diagnosis.k_sigma"),
        ({"window_intervals": 2.5}, "diagnosis.window_intervals"),
        ({"attitude_separation_deg": 270.0}, "diagnosis.attitude_separation_deg"),
        ({"min_dof": -1.0}, "diagnosis.min_dof"),
        ({"method": "fast"}, "diagnosis.method"),
        ({"no_such_key": 1}, "diagnosis.no_such_key"),
    ],
)
def test_diagnose_refuses_a_bad_configuration_naming_the_key(session, config, key):
    """A negative determined_std_ratio used to run and make all 18 parameters undetermined."""
    with pytest.raises(BadInput, match=f"^config: {key}: "):
        imudiag.diagnose(session, CERT, config=config, rate_hz=100.0, gnss="none")
    with pytest.raises(BadInput, match=f"^{key}: "):
        StreamingDiagnoser(CERT, config)
    if "no_such_key" not in config:
        with pytest.raises(BadInput, match=f"^{key}: "):
            DiagnosisConfig(**config)


@pytest.mark.parametrize("rate", [0.0, -5.0, math.nan, 1e9, "100"])
def test_the_streaming_diagnoser_refuses_a_bad_rate(rate):
    """A rate of 0 used to fall back to the certificate's silently; -5 was taken."""
    with pytest.raises(BadInput, match="^rate_hz: "):
        StreamingDiagnoser(CERT, rate_hz=rate)


@pytest.mark.parametrize(
    ("field", "value", "key"),
    [
        ("status_rate_hz", 0.0, "status.rate_hz"),
        ("nmea_queue", 0, "status.nmea_queue"),
        ("stuck_samples", 1.5, "monitor.stuck_samples"),
        ("diagnosis_window_intervals", 3, "diagnosis.window_intervals"),
        ("status_stdout", "yes", "status.stdout"),
        ("log_level", "loud", "log_level"),
        ("source", "nosuch://x", "source"),
    ],
)
def test_a_daemon_config_built_in_code_is_checked_as_the_file(field, value, key):
    with pytest.raises(BadInput, match=f"^{key}: "):
        DaemonConfig(**{field: value})
    with pytest.raises(BadInput, match=f"^{key}: "):
        DaemonConfig().replace(**{field: value})


# ---------------------------------------------------------------------------
# item 4b: one noise default


def test_streaming_and_offline_share_the_noise_default(session):
    """A StreamingDiagnoser at its defaults measures the noise from the data as
    imudiag.diagnose does: the same windows and verdict on the same stream. (It used to
    trust the certificate's noise: on this session, 6 times noisier than the certificate
    says, it found no still interval at all.)"""
    assert CERTIFICATE_NOISE is False
    report = imudiag.diagnose(session, CERT, rate_hz=100.0, gnss="none")
    diag = StreamingDiagnoser(CERT, rate_hz=100.0)
    assert diag.certificate_noise is CERTIFICATE_NOISE
    for i in range(0, len(session), DEFAULT_BLOCK_SIZE):
        diag.update(session.slice(i, i + DEFAULT_BLOCK_SIZE))
    diag.finish()
    streamed = diag.report()
    assert report["intervals"] == streamed["intervals"] == 12
    assert report["windows_run"] == streamed["windows_run"] > 0
    assert streamed["windows"] == report["windows"]
    assert streamed["verdict"] == report["verdict"]


# ---------------------------------------------------------------------------
# item 4c: the sample flags in the GNSS aiding


def _strip(report: dict) -> dict:
    out = dict(report)
    out["gnss"] = {k: v for k, v in report["gnss"].items() if k != "flagged_samples"}
    return out


@pytest.fixture(scope="module")
def drive():
    """300 s of the urban drive (100 Hz IMU, t in UTC Unix time) and its gpsd TPV reports."""
    return simulate_drive("urban", 300.0, CERT, seed=11)


def test_a_flagged_burst_does_not_move_the_moving_base_estimates(drive):
    res, reports, _ = drive
    track = track_from_reports([parse_tpv(r) for r in reports])
    clean = res.samples
    n = len(clean)
    burst = np.zeros(n, dtype=bool)
    burst[n // 2 : n // 2 + 60] = True  # 0.6 s in motion, saturated outputs
    accel, gyro = clean.accel.copy(), clean.gyro.copy()
    accel[burst] = 65535.0
    gyro[burst, 2] = 0.0
    flags = np.where(burst, FLAG_ACCEL_SATURATED | FLAG_GYRO_SATURATED, 0).astype(np.uint16)
    flagged = SampleBlock(t=clean.t, gyro=gyro, accel=accel, flags=flags)
    absent = SampleBlock(t=clean.t[~burst], gyro=clean.gyro[~burst], accel=clean.accel[~burst])
    cfg = MovingConfig()
    with_flags = moving_base_diagnosis(flagged, CERT, track, cfg)
    without = moving_base_diagnosis(absent, CERT, track, cfg)
    base = moving_base_diagnosis(clean, CERT, track, cfg)
    # the flagged samples are left out of every step: as if they were not there
    assert with_flags["gnss"]["flagged_samples"] == 60
    assert "flagged_samples" not in base["gnss"]
    assert _strip(with_flags) == without
    # and the estimates stay where the clean drive put them
    assert with_flags["verdict"] == base["verdict"] == "ok"
    assert with_flags["faults"] == []
    assert with_flags["f0"]["failed"] == base["f0"]["failed"]
    assert len(with_flags["windows"]) == len(base["windows"])
    for w_flag, w_base in zip(with_flags["windows"], base["windows"], strict=True):
        for part in ("bias", "scale_factor", "misalignment"):
            got = np.array(w_flag["accel"][part]["estimate"])
            want = np.array(w_base["accel"][part]["estimate"])
            std = np.array(w_base["accel"][part]["std"])
            assert np.all(np.abs(got - want) <= 0.1 * std), (part, got, want, std)


# ---------------------------------------------------------------------------
# item 4d: GNSS aiding from the library


def _without_source(section: dict) -> dict:
    out = {k: v for k, v in section.items() if k != "log"}
    out["gnss"] = {k: v for k, v in section["gnss"].items() if k != "source"}
    return out


def test_gnss_aiding_from_the_library_on_samples_and_a_gnss_stream(drive, tmp_path):
    """The samples in memory and gpsd's stream (its objects, or its lines) give the section
    of ``imudiag diagnose --gnss LOG``; no log is read."""
    res, reports, _ = drive
    log = tmp_path / "gnss.json"
    write_gpspipe_log(log, reports)
    from_log = imudiag.moving_base(res.samples, log, CERT)
    from_objects = imudiag.moving_base(res.samples, iter(reports), CERT)
    from_lines = imudiag.moving_base(res.samples, log.read_text().splitlines(), CERT)
    assert from_log["gnss"]["source"] == from_log["log"] == str(log)
    assert from_objects["gnss"]["source"] == from_lines["log"] == "gpsd stream"
    # the log's lines are the log (the log writer rounds: time to 1 ms, velocity to 0.1 mm/s)
    assert _without_source(from_lines) == _without_source(from_log)
    as_text = imudiag.moving_base(res.samples, [json.dumps(r) for r in reports], CERT)
    assert as_text == from_objects and from_objects["verdict"] == "ok"
    assert from_log["verdict"] == "ok" and from_log["gnss"]["used"] > 200
    # imudiag diagnose --gnss gives the section of the rate it measured on the samples
    report = imudiag.diagnose(res.samples, CERT, gnss=str(log), windows=False)
    rate = report["sample_rate"]
    assert report["moving_base"] == imudiag.moving_base(res.samples, log, CERT, rate_hz=rate)


def test_gnss_aiding_from_the_library_refuses_what_it_cannot_use(drive):
    res, reports, _ = drive
    with pytest.raises(BadInput, match="^gnss:2: not a gpsd JSON object"):
        imudiag.moving_base(res.samples, [reports[0], {"time": "x"}], CERT)
    with pytest.raises(BadInput, match="^gnss: no TPV report with a time"):
        imudiag.moving_base(res.samples, [{"class": "SKY"}], CERT)
    with pytest.raises(BadInput, match="^gnss: 'auto' names a log's own GNSS"):
        imudiag.moving_base(res.samples, "auto", CERT)
    with pytest.raises(BadInput, match="^gnss: expected gpsd objects"):
        imudiag.moving_base(res.samples, 5, CERT)
    with pytest.raises(BadInput, match="^samples: expected a SampleBlock"):
        imudiag.moving_base(res.samples.t, reports, CERT)
    with pytest.raises(BadInput, match="^rate_hz: "):
        imudiag.moving_base(res.samples, reports, CERT, rate_hz=-100.0)


# ---------------------------------------------------------------------------
# item 4e: a typed report with the documented keys

FROZEN = Path(__file__).parent / "data" / "frozen-reports"


def test_the_report_type_has_the_documented_keys(session, drive, tmp_path):
    from imudiag.diagnosis.report import DiagnosisReport, Verdict, check_keys

    assert imudiag.DiagnosisReport is DiagnosisReport
    assert imudiag.diagnose.__annotations__["return"] == "DiagnosisReport"
    # the documented keys of docs/spec/reports.md are the required ones
    assert {"class", "format", "samples", "f0", "verdict", "windows"} <= (
        DiagnosisReport.__required_keys__
    )
    assert set(Verdict.__required_keys__) == {"accel", "gyro", "faults", "undetermined"}
    # reports of every kind hold only documented keys: in memory, with GNSS, the frozen
    # ones (a raw .bin capture's wire counters, an npz log, a real Xsens log)
    report = imudiag.diagnose(session, CERT, rate_hz=100.0, gnss="none")
    check_keys(dict(report))
    assert type(report) is dict and json.loads(json.dumps(report)) == report
    res, reports, _ = drive
    log = tmp_path / "gnss.json"
    write_gpspipe_log(log, reports)
    aided = imudiag.diagnose(res.samples, CERT, gnss=str(log), windows=False)
    assert "moving_base" in aided
    check_keys(dict(aided))
    frozen = sorted(FROZEN.glob("*/*.json"))
    assert len(frozen) >= 6
    for path in frozen:
        check_keys(json.loads(path.read_text()))
    with pytest.raises(ValueError, match=r"undocumented keys \['extra'\]"):
        check_keys({**report, "extra": 1})
    with pytest.raises(ValueError, match=r"missing keys \['verdict'\]"):
        check_keys({k: v for k, v in report.items() if k != "verdict"})

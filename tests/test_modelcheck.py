"""Model check: its statistics against references, streaming, the command line, the
extended certificate in use by the monitor, and the real recordings."""

from __future__ import annotations

import json
import math
from pathlib import Path

import allantools
import numpy as np
import pytest
from conftest import REAL_DATA_DIR, run_imudiag, run_imudiag_in_process
from modelcheck_cases import session
from scipy import signal, stats

from imudiag.certificate import load, load_default
from imudiag.logs import write_log
from imudiag.modelcheck import model_check
from imudiag.modelcheck.kalman import filter_products, run_filter
from imudiag.modelcheck.report import check_report
from imudiag.modelcheck.streams import SegmentStats, allan_m_grid
from imudiag.monitor import Monitor
from imudiag.samples import SampleBlock
from imudiag.sim import Effects, TemperatureProfile, simulate, turntable
from imudiag.stats import chi2_significance, log_chi2_sf, z_from_log_p

MC_DATA = Path(__file__).parent / "data" / "modelcheck"


# ---------------------------------------------------------------------------
# statistics against references


def test_tail_probabilities_match_scipy() -> None:
    for x, k in [(25.0, 1), (50.0, 3), (400.0, 3), (10.0, 2), (40.0, 7), (0.3, 3)]:
        assert log_chi2_sf(x, k) == pytest.approx(stats.chi2.logsf(x, k), rel=1e-6, abs=1e-9)
    for z in (0.5, 3.0, 5.0, 12.0, 30.0):
        assert z_from_log_p(stats.norm.logsf(z)) == pytest.approx(z, rel=1e-6)
    # Bonferroni over 100 trials lowers the significance
    assert chi2_significance(60.0, 1, 100.0) < chi2_significance(60.0, 1)


def test_segment_allan_and_psd_match_references() -> None:
    rng = np.random.default_rng(3)
    n, rate = 8192, 100.0
    y = np.cumsum(rng.normal(0, 0.05, (n, 6)), axis=0) + rng.normal(0, 1.0, (n, 6))
    m = allan_m_grid(n, 8)
    st = SegmentStats(
        m=m,
        rate_hz=rate,
        nperseg=512,
        n_chunks=1,
        predictors={"raw": lambda t, temp, c: np.zeros((t.shape[0], 6))},
    )
    st.add(np.arange(n) / rate, y, None, np.zeros(n, dtype=int), 0)
    tau, adev, _ind = st.allan("raw", (0,))
    ref_tau, ref_adev, *_ = allantools.oadev(y[:, 2], rate=rate, data_type="freq", taus=m / rate)
    common = np.isin(np.round(tau * rate), np.round(ref_tau * rate))
    assert common.sum() == ref_tau.shape[0] >= tau.shape[0] - 1
    assert np.allclose(adev[common, 2], ref_adev, rtol=1e-9)
    f, p, k = st.psd("raw", 0)
    fr, pr = signal.welch(
        y[:, 4], fs=rate, window="hann", nperseg=512, noverlap=256, detrend="constant"
    )
    assert np.allclose(f, fr) and k == (n - 512) // 256 + 1
    assert np.allclose(p[:, 4], pr, rtol=1e-9)


def test_kalman_without_walk_is_weighted_least_squares() -> None:
    rng = np.random.default_rng(1)
    n = 200
    t = np.arange(n, dtype=float)
    x = np.stack([np.sin(t / 17.0), t / n], axis=1)
    r = rng.uniform(0.5, 2.0, n)
    y = 3.0 + x @ np.array([0.7, -1.2]) + rng.normal(0, np.sqrt(r))
    inn = run_filter(t, np.ones((n, 1)), r, np.column_stack([y, x]), np.zeros((1, 1)))
    rows = np.flatnonzero(inn.valid[0])
    w = inn.nu[0, rows] / np.sqrt(inn.S[0, rows])[:, None]
    beta = np.linalg.lstsq(w[:, 1:], w[:, 0], rcond=None)[0]
    a = np.column_stack([np.ones(n), x]) / np.sqrt(r)[:, None]
    ref = np.linalg.lstsq(a, y / np.sqrt(r), rcond=None)[0]
    assert beta == pytest.approx(ref[1:], rel=1e-6)


# ---------------------------------------------------------------------------
# streaming and the report


def _temperature_session(effects_kw: dict, seed: int = 4, duration_s: float = 300.0):
    cert = load_default()
    temp = TemperatureProfile(22.0, 12.0, 150.0, swing_c=2.5, swing_period_s=110.0)
    return cert, session(
        cert, seed, Effects.board(temperature=temp, **effects_kw), duration_s=duration_s
    )


def test_result_does_not_depend_on_block_boundaries() -> None:
    cert, sim = _temperature_session({"temperature_bias": {"gy": 2.0}})
    whole = model_check(sim.samples, cert, seed=1).report
    block = sim.samples

    def small_blocks():
        for i in range(0, len(block), 997):
            yield block.slice(i, min(i + 997, len(block)))

    pieces = model_check(small_blocks, cert, seed=1).report
    assert [e["name"] for e in whole["effects"]] == ["temperature_bias"]
    assert pieces["effects"] == whole["effects"]
    assert pieces["baseline"] == whole["baseline"]
    assert pieces["extended"] == whole["extended"]


def test_report_follows_the_spec(tmp_path: Path) -> None:
    cert, sim = _temperature_session({"bias_step": [("ax", 150.0, 6.0)]})
    result = model_check(sim.samples, cert)
    rep = result.report
    check_report(rep)
    json.dumps(rep, allow_nan=False)
    assert rep["format"] == "imudiag-model-check/1"
    (step,) = rep["effects"]
    assert step["name"] == "bias_step" and step["sensor"] == "ax" and step["triad"] == "accel"
    assert step["unit"] == "count" and "t" in step
    for key in ("residual_rms", "f0_false_alarm_rate", "allan_misfit"):
        assert set(rep["baseline"][key]) == {"gyro", "accel"}
        assert set(rep["gain"][key]) == {"gyro", "accel"}
    assert rep["gain"]["residual_rms"]["accel"] < 0.5
    comp = rep["comparison"]
    # white noise: measured, simulated and certified agree on clean noise (within 5 %)
    for s, d in comp["noise_density"].items():
        assert d["measured"] == pytest.approx(d["certificate"], rel=0.05), s
        assert d["simulated"] == pytest.approx(d["certificate"], rel=0.05), s
    assert len(comp["allan"]["tau"]) == len(comp["allan"]["gx"]["measured"])
    assert comp["f0"]["accel"]["measured"]["samples"] > 20000
    names = {u["name"] for u in rep["untestable"]}
    assert "periodic_disturbance" not in names


def test_no_quasi_static_data_is_reported_as_untestable() -> None:
    cert = load_default()
    moving = turntable(90.0, "z", 20.0, rate_hz=100.0)
    spin = simulate(cert, moving, seed=2, effects=Effects.board()).samples
    rep = model_check(spin, cert).report
    assert rep["effects"] == []
    assert rep["untestable"] and all("quasi-static" in u["reason"] for u in rep["untestable"])


# ---------------------------------------------------------------------------
# command line and the extended certificate in use


def test_command_line_writes_report_certificate_and_plots(tmp_path: Path) -> None:
    cert, sim = _temperature_session({"temperature_bias": {"ay": 5.0}})
    log = tmp_path / "session.csv.gz"
    write_log(log, sim.samples)
    out = tmp_path / "mc.json"
    ext = tmp_path / "extended.yaml"
    plots = tmp_path / "plots"
    proc = run_imudiag(
        "model-check",
        str(log),
        "--certificate",
        "config/default-certificate.yaml",
        "--json",
        str(out),
        "--extended-certificate",
        str(ext),
        "--plots",
        str(plots),
        "--seed",
        "3",
    )
    assert proc.returncode == 0, proc.stderr
    rep = json.loads(out.read_text())
    check_report(rep)
    assert [(e["name"], e["sensor"]) for e in rep["effects"]] == [("temperature_bias", "ay")]
    assert rep["effects"][0]["value"] == pytest.approx(5.0, rel=0.1)
    assert "temperature_bias ay" in proc.stdout
    extended = load(ext)
    assert extended.accel.temperature is not None
    assert extended.accel.temperature.bias_coefficient[1] == pytest.approx(5.0, rel=0.1)
    assert extended.accel.temperature.reference == 25.0
    assert np.allclose(extended.accel.bias, cert.accel.bias)
    pngs = sorted(p.name for p in plots.glob("*.png"))
    assert "allan_ay.png" in pngs and "residuals_accel.png" in pngs

    # the monitor uses the extended block: F0 failures of the warm board go away
    def f0_failed(c) -> int:
        mon = Monitor(c)
        for i in range(0, len(sim.samples), 4096):
            mon.update(sim.samples.slice(i, min(i + 4096, len(sim.samples))))
        return mon.f0_failed["accel"]

    before, after = f0_failed(cert), f0_failed(extended)
    assert before > 1000 and after < before / 20, (before, after)


def test_command_line_bad_input(tmp_path: Path) -> None:
    bad_cert = tmp_path / "bad.yaml"
    bad_cert.write_text(
        Path("config/default-certificate.yaml").read_text().replace("f0: 0.01", "f0: -1", 1)
    )
    log = tmp_path / "s.csv"
    write_log(
        log, SampleBlock(t=np.arange(10) / 100.0, gyro=np.zeros((10, 3)), accel=np.zeros((10, 3)))
    )
    # the bad certificate is the real subprocess run; the other refusals run in process
    proc = run_imudiag("model-check", str(log), "--certificate", str(bad_cert))
    assert proc.returncode == 2 and "gyro.limits.f0" in proc.stderr
    broken = tmp_path / "broken.csv"
    broken.write_text("t,gx,gy,gz,ax,ay,az\n0,1,2,3,4,5,6\n0.01,1,2,x,4,5,6\n")
    proc = run_imudiag_in_process(
        "model-check", str(broken), "--certificate", "config/default-certificate.yaml"
    )
    assert proc.returncode == 2 and "broken.csv:3" in proc.stderr and "gz" in proc.stderr
    proc = run_imudiag_in_process(
        "model-check",
        str(tmp_path / "missing.csv"),
        "--certificate",
        "config/default-certificate.yaml",
    )
    assert proc.returncode == 2 and "missing.csv" in proc.stderr
    proc = run_imudiag_in_process(
        "model-check", str(log), "--certificate", "config/default-certificate.yaml", "--chunk", "0"
    )
    assert proc.returncode == 2 and "--chunk" in proc.stderr


# ---------------------------------------------------------------------------
# real recordings (the findings of docs/model-check.md)


@pytest.fixture(scope="module")
def xsens_report() -> dict:
    cert = load(MC_DATA / "xsens-mti.yaml")
    return model_check(REAL_DATA_DIR / "xsens-mti-multiposition" / "session.csv.gz", cert).report


def test_xsens_gyro_g_sensitivity_is_named_and_explains_held_out_data(xsens_report) -> None:
    rep = xsens_report
    g = {e["sensor"]: e for e in rep["effects"] if e["name"] == "g_sensitivity"}
    assert set(g) == {"gx", "gy", "gz"}
    assert all(e["significance"] > 20 for e in g.values())
    assert rep["gain"]["residual_rms"]["gyro"] < 0.6
    # no temperature column: temperature effects are untestable, and said so
    reasons = {(u["name"], u["sensor"]): u["reason"] for u in rep["untestable"]}
    assert "no temperature column" in reasons[("temperature_bias", "gx")]
    # still runs of about 16 s: no noise model, and said so
    assert "60 s or more" in rep["noise_model"]["untestable"]


def test_firm_flight_has_too_little_still_data() -> None:
    cert = load(MC_DATA / "firm.yaml")
    rep = model_check(REAL_DATA_DIR / "firm-rocket-launch" / "flight.csv.gz", cert).report
    assert rep["effects"] == []
    assert rep["untestable"]


def test_real_data_certificates_load() -> None:
    for name in ("xsens-mti", "mpu6050", "imucal-ferraris", "firm"):
        c = load(MC_DATA / f"{name}.yaml")
        assert math.isfinite(c.gravity)


def test_filter_products_equal_sums_of_whitened_innovations() -> None:
    rng = np.random.default_rng(5)
    n = 150
    t = np.cumsum(rng.uniform(0.5, 3.0, n))
    h = rng.normal(size=(n, 2))
    r = rng.uniform(0.5, 2.0, n)
    head = rng.normal(size=(n, 3))
    cand = rng.normal(size=(n, 2))
    q = np.array([[0.01, 0.3], [0.0, 0.0]])
    rows = rng.random(n) < 0.7
    steps_axis, steps_at = np.array([1, 0]), np.array([40, 90])
    p = filter_products(
        t,
        h,
        r,
        head,
        q,
        rows[None],
        cand=cand,
        step_axis=steps_axis,
        step_at=steps_at,
        block_k=2,
        buffer_rows=16,
    )
    idx = np.arange(n)
    steps = np.stack(
        [h[:, a] * (idx >= b) for a, b in zip(steps_axis, steps_at, strict=True)], axis=1
    )
    z = np.concatenate([head, cand, steps], axis=1)
    inn = run_filter(t, h, r, z, q)
    for b in range(2):
        w = inn.nu[b, rows] / np.sqrt(inn.S[b, rows])[:, None]
        full = w.T @ w
        assert np.allclose(p.head[b, 0], full[:3, :3])
        assert np.allclose(p.cross[b, 0], full[3:, :3])
        assert np.allclose(p.diag[b, 0], np.diag(full)[3:])
        assert np.allclose(p.block[b, 0], full[3:5, 3:5])
        assert p.log_s[b, 0] == pytest.approx(np.sum(np.log(inn.S[b, rows])))


def _kalman_cases(seed: int) -> dict:
    """Random filter inputs under ``seed`` (1 state in half the cases, 2 or 3 in the
    others): gaps, unused rows, a batch of random walks (some zero), head and candidate
    columns, bias steps, groups."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 400))
    b = int(rng.choice([1, 1, 3, 9]))
    d = 1 if seed % 2 == 0 else int(rng.integers(2, 4))
    t = np.cumsum(rng.uniform(0.0, 2.0, n) * (rng.random(n) < 0.9))
    h = rng.normal(size=(n, d)) * (rng.random((n, d)) < 0.95)
    r = rng.uniform(0.2, 3.0, n)
    q = rng.uniform(0.0, 0.5, (b, d)) * (rng.random((b, d)) < 0.8)
    use = rng.random(n) < 0.85
    g = int(rng.integers(1, 4))
    groups = rng.random((g, n)) < 0.6
    hw = int(rng.integers(1, 4))
    c1 = int(rng.integers(0, 3))
    steps = int(rng.integers(0, 5))
    return {
        "args": (t, h, r, rng.normal(size=(n, hw)), q, groups),
        "kw": {
            "use": use if rng.random() < 0.7 else None,
            "cand": rng.normal(size=(n, c1)) if c1 else None,
            "step_axis": rng.integers(0, d, steps) if steps else None,
            "step_at": rng.integers(0, n, steps) if steps else None,
            "block_k": min(int(rng.integers(0, 3)), c1 + steps),
            "buffer_rows": int(rng.choice([1, 7, 64])),
        },
        "z": rng.normal(size=(n, int(rng.choice([1, 1, 4])))),
    }


@pytest.mark.parametrize("seed", range(40))
def test_two_pass_filter_is_the_row_by_row_filter_bit_for_bit(monkeypatch, seed: int) -> None:
    """The two-pass paths of filter_products and run_filter (variance recursion, then
    the state; Python floats for one state: the model check's speed) give the row-by-row
    loop's floating-point results exactly, on random inputs with 1-3 states, gaps, unused
    rows, batches, candidates, steps and groups, in passes of 7, 37 or 2048 rows."""
    import imudiag.modelcheck.kalman as kalman

    case = _kalman_cases(seed)
    t, h, r, head, q, groups = case["args"]
    # passes of a few rows too: the state, the log S sums and the buffers carried across
    monkeypatch.setattr(kalman, "PASS_ROWS", (7, 37, 2048)[seed % 3])
    fast = filter_products(*case["args"], **case["kw"])
    inn_fast = run_filter(t, h, r, case["z"], q, use=case["kw"]["use"])
    monkeypatch.setattr(kalman, "_GENERAL_ONLY", True)
    slow = filter_products(*case["args"], **case["kw"])
    inn_slow = run_filter(t, h, r, case["z"], q, use=case["kw"]["use"])
    for name in ("head", "cross", "diag", "block", "log_s", "rows"):
        a, b = getattr(fast, name), getattr(slow, name)
        assert a.shape == b.shape and np.array_equal(a, b), name
    assert np.array_equal(inn_fast.nu, inn_slow.nu)
    assert np.array_equal(inn_fast.S, inn_slow.S)
    assert np.array_equal(inn_fast.valid, inn_slow.valid)

"""Issue 13 item 3: the daemon's status states the unit's white noise, measured live as
every command measures it (median second differences), beside the certificate's."""

from __future__ import annotations

import numpy as np
import pytest

from imudiag.certificate import load_default
from imudiag.logs import open_writer
from imudiag.noise_estimate import METHOD, NoiseMeter
from imudiag.service.daemon import NOISE_WINDOW_S, Daemon, DaemonSettings
from imudiag.sim import multi_position, simulate
from imudiag.sim.scenarios import parse_effects
from tests.helpers import CollectSink


def _last_status(tmp_path, noise_scale: float) -> dict:
    cert = load_default()
    effects = parse_effects([f"noise:{noise_scale}"]) if noise_scale != 1.0 else None
    s = simulate(
        cert,
        multi_position(n_attitudes=10, rate_hz=cert.sample_rate, seed=41),
        seed=42,
        effects=effects,
    ).samples
    log = tmp_path / f"noise-x{noise_scale}.npz"
    with open_writer(
        log, {"sample_rate": cert.sample_rate, "units": "gyro=count accel=count"}
    ) as w:
        w.write(s)
    sink = CollectSink()
    daemon = Daemon(DaemonSettings(source_url=f"replay://{log}?speed=0"), [sink])
    assert daemon.run() == 0
    return [x for x in sink.lines if "noise" in x][-1]


@pytest.mark.parametrize(("scale", "disagrees"), [(1.0, False), (2.5, True)])
def test_status_states_the_measured_white_noise_beside_the_certificate(tmp_path, scale, disagrees):
    status = _last_status(tmp_path, scale)
    noise = status["noise"]
    assert noise["method"] == METHOD and noise["window_s"] == NOISE_WINDOW_S
    for triad in ("gyro", "accel"):
        entry = noise[triad]
        assert entry["unit"] == "count/sqrt(Hz)"
        # motion in most of the session does not inflate it: the ratio is the noise scale
        assert np.allclose(entry["ratio"], scale, rtol=0.12), entry
        assert entry["disagrees"] is disagrees


def test_the_meter_keeps_a_sliding_window_of_chunks():
    rng = np.random.default_rng(5)
    meter = NoiseMeter(100.0, max_chunks=10)
    meter.update(rng.normal(size=(3000, 3)) * 4.0, rng.normal(size=(3000, 3)))
    meter.update(rng.normal(size=(1000, 3)), rng.normal(size=(1000, 3)))  # 10 quieter chunks
    fig = meter.result()
    assert fig["gyro"].chunks == 10
    assert np.allclose(fig["gyro"].sigma, 1.0, rtol=0.15)


def test_the_meter_quantile_is_nanquantiles_bit_for_bit():
    """The meter takes np.quantile where no chunk figure is NaN (np.nanquantile's column loop
    costs 6x): the same figures, bit for bit, with and without NaN figures (a channel whose
    chunks are all constant gives none)."""
    from imudiag.noise_estimate import quantile_bias

    rng = np.random.default_rng(11)
    for trial in range(200):
        meter = NoiseMeter(100.0, quantile=float(rng.choice([0.05, 0.25, 0.5])))
        n = 100 * int(rng.integers(1, 40))
        gyro = np.round(rng.normal(size=(n, 3)) * rng.uniform(0.5, 50.0, 3), 1)
        accel = rng.normal(size=(n, 3)) * rng.uniform(0.01, 5.0, 3)
        meter.update(gyro, accel)
        if trial % 4 == 0 and len(meter._chunks) > 1:
            meter._chunks[0][int(rng.integers(0, 6))] = np.nan
        figures = np.vstack(meter._chunks)
        want = np.nanquantile(figures, meter.quantile, axis=0)
        want = want / quantile_bias(meter.chunk, meter.quantile)
        got = meter.sample_sigma()
        assert np.where(np.isfinite(want) & (want > 0), want, np.nan).tobytes() == got.tobytes()

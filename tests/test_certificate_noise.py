"""Certificate noise fields (IEEE Std 952 / 1554 terms): loaded, validated, written back,
and the closed-form Allan deviation they predict, per sensor."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from imudiag.certificate import (
    FLICKER_FACTOR,
    NOISE_FIELDS,
    CertificateError,
    Noise,
    default_certificate_path,
    load,
    loads,
)
from imudiag.noise_stats import overlapping_allan

FULL_NOISE = {
    "density": [0.5, 0.6, 0.7],
    "bias_random_walk": [0.01, 0.02, 0.03],
    "quantization": [0.001, 0.002, 0.003],
    "bias_instability": [0.05, 0.06, 0.07],
    "rate_ramp": [1e-4, 2e-4, 3e-4],
    "gauss_markov_sigma": [0.2, 0.3, 0.4],
    "gauss_markov_time": [30.0, 60.0, 90.0],
}


@pytest.fixture
def doc() -> dict[str, Any]:
    return yaml.safe_load(default_certificate_path().read_text())


def _error(doc: dict[str, Any]) -> CertificateError:
    with pytest.raises(CertificateError) as info:
        loads(yaml.safe_dump(doc, sort_keys=False), source="cert.yaml")
    return info.value


def test_every_field_has_a_unit_and_a_meaning() -> None:
    assert set(FULL_NOISE) == set(NOISE_FIELDS)
    for key, (unit, meaning) in NOISE_FIELDS.items():
        assert unit and meaning, key


def test_all_noise_fields_round_trip_through_a_file(tmp_path: Path, doc: dict[str, Any]) -> None:
    doc["gyro"]["noise"] = dict(FULL_NOISE)
    src = tmp_path / "in.yaml"
    src.write_text(yaml.safe_dump(doc, sort_keys=False))
    cert = load(src)
    for key, vals in FULL_NOISE.items():
        assert getattr(cert.gyro.noise, key).tolist() == vals
    out = tmp_path / "out.yaml"
    cert.save(out)
    again = load(out)
    for key, vals in FULL_NOISE.items():
        assert getattr(again.gyro.noise, key).tolist() == vals
    assert yaml.safe_load(out.read_text())["gyro"]["noise"] == FULL_NOISE


@pytest.mark.parametrize(
    ("field", "value", "key", "reason"),
    [
        ("bias_instability", [0.1, -0.1, 0.1], "gyro.noise.bias_instability[1]", ">= 0"),
        ("rate_ramp", [0.1, 0.1], "gyro.noise.rate_ramp", "3"),
        ("quantization", [0.1, "x", 0.1], "gyro.noise.quantization[1]", "number"),
        ("flicker", [0.1, 0.1, 0.1], "gyro.noise.flicker", "unknown key"),
    ],
)
def test_bad_noise_field_names_its_key(
    doc: dict[str, Any], field: str, value: Any, key: str, reason: str
) -> None:
    doc["gyro"].setdefault("noise", {})[field] = value
    err = _error(doc)
    assert err.key == key and reason in err.reason


def test_gauss_markov_needs_both_and_a_positive_time(doc: dict[str, Any]) -> None:
    noise = doc["accel"].setdefault("noise", {})
    noise["gauss_markov_sigma"] = [0.1, 0.1, 0.1]
    err = _error(doc)
    assert err.key == "accel.noise.gauss_markov_time" and "both" in err.reason
    noise["gauss_markov_time"] = [10.0, 0.0, 10.0]
    err = _error(doc)
    assert err.key == "accel.noise.gauss_markov_time[1]" and "> 0" in err.reason


def _only(key: str, value: float, **more: float) -> Noise:
    kw = {key: np.full(3, value)}
    kw.update({k: np.full(3, v) for k, v in more.items()})
    return Noise(**kw)


def test_closed_form_terms_have_their_ieee_signatures() -> None:
    tau = np.array([0.1, 1.0, 3.0, 10.0, 1000.0])
    # white: N = density / sqrt(2) read at tau = 1 s on the -1/2 line
    a = _only("density", 0.8).allan_deviation(tau)
    assert a.shape == (3, 5)
    assert a[0, 1] == pytest.approx(0.8 / math.sqrt(2.0))
    assert a[0, 0] / a[0, 1] == pytest.approx(math.sqrt(10.0))
    # rate random walk: K read at tau = 3 s on the +1/2 line
    a = _only("bias_random_walk", 0.02).allan_deviation(tau)
    assert a[0, 2] == pytest.approx(0.02)
    # bias instability: flat at 0.664 B
    a = _only("bias_instability", 0.05).allan_deviation(tau)
    assert np.allclose(a, FLICKER_FACTOR * 0.05)
    assert FLICKER_FACTOR == pytest.approx(0.6643, abs=1e-4)
    # quantisation: sqrt(3) Q / tau; rate ramp: R tau / sqrt(2)
    assert _only("quantization", 0.01).allan_deviation(1.0)[0, 0] == pytest.approx(
        math.sqrt(3.0) * 0.01
    )
    assert _only("rate_ramp", 0.01).allan_deviation(10.0)[0, 0] == pytest.approx(
        0.1 / math.sqrt(2.0)
    )
    # Gauss-Markov: a random walk sigma sqrt(2/T) well below T, white sigma sqrt(2T) well above
    gm = _only("gauss_markov_sigma", 0.3, gauss_markov_time=50.0)
    short, long_ = gm.allan_deviation(np.array([0.01, 1e5]))[0]
    assert short == pytest.approx(0.3 * math.sqrt(2.0 / 50.0) * math.sqrt(0.01 / 3.0), rel=1e-3)
    assert long_ == pytest.approx(0.3 * math.sqrt(2.0 * 50.0) / math.sqrt(1e5), rel=1e-3)
    # independent terms add in variance, per axis
    n = Noise(**{k: np.asarray(v) for k, v in FULL_NOISE.items()})
    total = n.allan_deviation(tau) ** 2
    parts = sum(
        _single(k, n).allan_deviation(tau) ** 2 for k in FULL_NOISE if k != "gauss_markov_time"
    )
    assert np.allclose(total, parts)
    assert not np.allclose(total[0], total[1])  # per sensor


def _single(key: str, n: Noise) -> Noise:
    kw = {key: getattr(n, key)}
    if key == "gauss_markov_sigma":
        kw["gauss_markov_time"] = n.gauss_markov_time
    return Noise(**kw)


def test_closed_form_matches_the_allan_deviation_of_a_realisation() -> None:
    """White noise plus an exact discrete Gauss-Markov bias: the measured overlapping Allan
    deviation follows the certificate's closed form within its statistical error."""
    rate, n = 50.0, 200_000  # 4000 s
    sigma_w, gm_sigma, gm_t = 0.5, 0.2, 20.0
    rng = np.random.default_rng(7)
    phi = math.exp(-1.0 / (rate * gm_t))
    drive = rng.normal(0.0, gm_sigma * math.sqrt(1.0 - phi**2), n)
    b = np.empty(n)
    b[0] = rng.normal(0.0, gm_sigma)
    for i in range(1, n):  # AR(1), exact for the sampled process
        b[i] = phi * b[i - 1] + drive[i]
    y = b + rng.normal(0.0, sigma_w, n)
    measured = overlapping_allan(y, rate, points_per_decade=5)
    keep = measured.independent >= 20
    density = sigma_w / math.sqrt(rate / 2.0)
    noise = Noise(
        density=np.full(3, density),
        gauss_markov_sigma=np.full(3, gm_sigma),
        gauss_markov_time=np.full(3, gm_t),
    )
    predicted = noise.allan_deviation(measured.tau[keep])[0]
    ratio = measured.adev[keep] / predicted
    assert np.all(np.abs(np.log(ratio)) < 4.0 / np.sqrt(measured.independent[keep]) + 0.03), ratio

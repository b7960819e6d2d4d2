"""The scalar function F0 on certificate-corrected outputs."""

import numpy as np
import pytest

from imudiag.certificate import Temperature, load_default
from imudiag.scalar import corrected_si, f0, f0_raw, norm

CERT = load_default()


def _unit_vectors(n: int, seed: int) -> np.ndarray:
    v = np.random.default_rng(seed).normal(size=(n, 3))
    return v / norm(v)[:, None]


@pytest.mark.parametrize("triad", ["gyro", "accel"])
def test_f0_is_zero_for_outputs_of_the_model_at_the_known_magnitude(triad):
    model = CERT.triad(triad)
    mag = CERT.magnitude_si(triad) if triad == "accel" else 1.0  # 1 rad/s: a known rate
    raw = model.forward_si(_unit_vectors(1000, 1) * mag)
    np.testing.assert_allclose(f0_raw(model, raw, mag), 0.0, atol=1e-12)


def test_f0_of_a_scaled_vector_is_half_of_the_squared_norm_minus_one():
    u = _unit_vectors(10, 2) * 1.01
    np.testing.assert_allclose(f0(u), 0.5 * (1.01**2 - 1.0))


def test_fast_path_equals_the_general_correction():
    raw = CERT.accel.forward_si(_unit_vectors(500, 3) * 9.7)
    general = f0(corrected_si(CERT.accel, raw) / CERT.gravity)
    np.testing.assert_allclose(f0_raw(CERT.accel, raw, CERT.gravity), general, atol=1e-14)
    mags = np.full(500, CERT.gravity)  # a per-sample magnitude takes the general path
    np.testing.assert_allclose(f0_raw(CERT.accel, raw, mags), general, atol=1e-14)


def test_temperature_block_is_applied_when_a_temperature_is_given():
    cert = CERT.copy()
    cert.accel.temperature = Temperature(
        reference=20.0, bias_coefficient=np.array([3.0, -2.0, 5.0]), scale_coefficient=np.zeros(3)
    )
    temp = np.linspace(10.0, 40.0, 300)
    raw = cert.accel.forward_si(_unit_vectors(300, 4) * CERT.gravity, temp_c=temp)
    np.testing.assert_allclose(f0_raw(cert.accel, raw, CERT.gravity, temp_c=temp), 0.0, atol=1e-12)
    assert np.max(np.abs(f0_raw(cert.accel, raw, CERT.gravity))) > 1e-4  # without it: wrong

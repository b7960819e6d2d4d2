"""The certificate's inverse, the noise meter's chunk figures and ``rows_op`` work in place
on arrays of their own or with a longer inner loop (issue 14: on blocks of 10^5 samples
fresh temporaries and numpy's loops of 3 cost more than the arithmetic). They must give
the numbers of the plain expressions they replace bit for bit, for every model block and
broadcast shape, and never write into their inputs."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from imudiag import noise_estimate
from imudiag.certificate import Certificate, TriadModel, load_default
from imudiag.noise_estimate import second_difference_sigmas
from imudiag.rowwise import rows_op
from tests.test_certificate import extended


def _plain_inverse(t: TriadModel, u: Any, temp_c: Any = None, accel_input: Any = None) -> Any:
    """TriadModel.inverse as it was written before (one new array per operation)."""
    u = np.asarray(u, dtype=float)
    bias, scale = t.bias, t.scale_factor
    if t.temperature is not None and temp_c is not None:
        dt = np.asarray(temp_c, dtype=float)[..., None] - t.temperature.reference
        bias = t.bias + t.temperature.bias_coefficient * dt
        scale = t.scale_factor * (1.0 + t.temperature.scale_coefficient * dt)
    r = u - bias
    if t.g_sensitivity is not None and accel_input is not None:
        r = r - np.asarray(accel_input, dtype=float) @ t.g_sensitivity.T
    if t.nonlinearity is None:
        nx = r / scale
    else:
        with np.errstate(invalid="ignore"):
            root = np.sqrt(scale**2 + 4.0 * t.nonlinearity * r)
        nx = 2.0 * r / (scale + root)
    return nx @ np.linalg.inv(t.n_matrix()).T


def _bits(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=float).view(np.int64)


def _certificates() -> dict[str, Certificate]:
    plain = load_default()
    ext = extended(plain, seed=5)
    linear_temp = plain.copy()
    linear_temp.accel.temperature = ext.accel.temperature  # temperature, no nonlinearity
    return {"default": plain, "extended": ext, "temperature only": linear_temp}


@pytest.mark.parametrize("cert_name", ["default", "extended", "temperature only"])
@pytest.mark.parametrize("triad", ["gyro", "accel"])
def test_inverse_is_the_plain_expression_bit_for_bit(cert_name: str, triad: str) -> None:
    t = _certificates()[cert_name].triad(triad)
    rng = np.random.default_rng(17)
    n = 5000
    u = rng.normal(32768.0, 3000.0, (n, 3))
    u[7] = [np.nan, np.inf, -np.inf]  # outputs not finite stay where they are
    temp = rng.uniform(-40.0, 85.0, n)
    accel = rng.normal(0.0, 9.8, (n, 3))
    shapes: list[tuple[np.ndarray, dict[str, Any]]] = [
        (u, {}),
        (u, {"temp_c": temp}),
        (u, {"temp_c": 31.5}),
        (u, {"temp_c": temp, "accel_input": accel}),
        (u, {"accel_input": accel[0]}),  # one accelerometer row for every sample
        (u[0], {"temp_c": temp}),  # one output row at many temperatures: (N, 3)
        (u[0], {}),
        (u[:127], {"temp_c": temp[:127], "accel_input": accel[:127]}),  # a daemon's reads
        (u[:128], {"temp_c": temp[:128], "accel_input": accel[:128]}),  # and from here on
        (u[:5], {}),
        (u[:, 1:2].repeat(3, axis=1)[::2], {}),  # a strided input
        (u.astype(np.float32), {}),
        (np.round(np.where(np.isfinite(u), u, 0.0)).astype(np.int64), {}),  # counts
    ]
    for x, kw in shapes:
        before = [np.array(v, copy=True) for v in (x, *kw.values())]
        with np.errstate(invalid="ignore"):
            got = t.inverse(x, **kw)
            want = _plain_inverse(t, x, **kw)
            got_si = t.inverse_si(x, **kw)
        assert got.shape == want.shape
        np.testing.assert_array_equal(_bits(got), _bits(want))
        np.testing.assert_array_equal(_bits(got_si), _bits(want * t.unit_to_si))
        for old, now in zip(before, (x, *kw.values()), strict=True):
            np.testing.assert_array_equal(np.asarray(now), old)  # the inputs are untouched


def _plain_second_difference_sigmas(chunks: np.ndarray) -> np.ndarray:
    """second_difference_sigmas as it was written before."""
    d = chunks[:, 2:] - 2.0 * chunks[:, 1:-1] + chunks[:, :-2]
    d = d - np.median(d, axis=1, keepdims=True)
    ad = np.abs(d)
    mad = np.median(ad, axis=1)
    d2 = d * d
    rms = np.sqrt(np.mean(d2, axis=1))
    s0 = np.where(mad > 0, noise_estimate._MAD_TO_SIGMA * mad, rms)
    kept = (ad <= 5.0 * s0[:, None, :]) | (s0 <= 0)[:, None, :]
    mean_kept = np.sum(np.where(kept, d2, 0.0), axis=1) / np.sum(kept, axis=1)
    return np.sqrt(mean_kept / 6.0)


@pytest.mark.parametrize("length", [200, 201, 8])
def test_chunk_noise_figures_are_the_plain_expression_bit_for_bit(length: int) -> None:
    rng = np.random.default_rng(length)
    chunks = rng.normal(0.0, 1.0, (40, length, 6)) * rng.uniform(0.1, 30.0, 6)
    chunks[:, :, 2] = np.round(chunks[:, :, 2])  # quantised: many equal values, MAD 0
    chunks[:, :, 5] = np.round(chunks[:, :, 5] * 0.05)
    chunks[3] = 7.0  # a constant chunk: MAD and RMS 0
    chunks[5, length // 2 :, 1] += 1e3  # a step
    chunks[9, :, 4] += np.linspace(0.0, 50.0, length)  # a ramp
    before = chunks.copy()
    got = second_difference_sigmas(chunks)
    np.testing.assert_array_equal(_bits(got), _bits(_plain_second_difference_sigmas(chunks)))
    np.testing.assert_array_equal(chunks, before)


@pytest.mark.parametrize("outlier", [False, True])
def test_chunk_noise_figures_of_still_data_are_the_plain_expression_bit_for_bit(
    outlier: bool,
) -> None:
    """Every MAD above 0 (no RMS fallback), and nothing clipped or one value clipped."""
    rng = np.random.default_rng(31)
    chunks = rng.uniform(-1.0, 1.0, (50, 200, 6)) * rng.uniform(0.1, 30.0, 6)
    if outlier:
        chunks[7, 100, 3] += 1e4
    got = second_difference_sigmas(chunks)
    np.testing.assert_array_equal(_bits(got), _bits(_plain_second_difference_sigmas(chunks)))


@pytest.mark.parametrize("op", [np.add, np.subtract, np.multiply, np.divide])
def test_rows_op_is_numpys_broadcast_bit_for_bit(op: np.ufunc) -> None:
    rng = np.random.default_rng(23)
    row = rng.normal(0.0, 100.0, 3)
    wide = rng.normal(0.0, 1e4, (1000, 6))
    wide[17, 4] = np.nan
    wide[18, 5] = np.inf
    for n in (0, 1, 5, 127, 128, 129, 1000):  # below, at and past the tiling, remainders
        x = wide[:n, :3].copy()
        cases = {
            "contiguous": (x, None),
            "strided": (wide[:n, 3:], None),  # a view on every other triple
            "in place": (x.copy(), "x"),
            "into a strided out": (x, np.empty((n, 6))[:, :3]),
        }
        for name, (a, out) in cases.items():
            want = op(a, row)
            target = a if isinstance(out, str) else out
            with np.errstate(all="ignore"):
                got = rows_op(op, a, row, out=target)
            assert got.shape == want.shape, name
            np.testing.assert_array_equal(_bits(got), _bits(want), err_msg=f"{name}, {n} rows")
            if target is not None:
                assert got is target
    # other shapes and dtypes are numpy's own broadcast
    f32 = wide[:300, :3].astype(np.float32)
    assert rows_op(op, f32, row).dtype == op(f32, row).dtype
    np.testing.assert_array_equal(rows_op(op, wide[:300], row[0]), op(wide[:300], row[0]))

"""The certificate in one internal form (issue 30 item 5): :func:`imudiag.diagnosis.params.
triad_form` converts a triad's certificate once (vectors, limits, units, gauge) and every fit
takes it in place of the model. The fits given the form equal the fits given the model (the
plain path, converting on every call) bit for bit, and the moving-base diagnosis converts the
accelerometer certificate once however many windows it fits."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from imudiag.aiding.isolation import isolate
from imudiag.certificate import load_default
from imudiag.diagnosis import params
from imudiag.diagnosis.gauge import shape_of_triad
from imudiag.diagnosis.params import (
    certificate_std_vector,
    certificate_vector,
    internal_scale,
    limit_vector,
    parameter_units,
    triad_form,
)
from imudiag.diagnosis.scalar_fit import certificate_internal, exact_fit, internal_limits


def fit_arrays(fit):
    return {
        "estimate": fit.estimate,
        "std": fit.std,
        "certificate": fit.certificate,
        "limit": fit.limit,
        "determined": fit.determined,
        "certificate_std": fit.certificate_std,
        "loo": fit.loo_deviation,
        "z": fit.point_z,
    }


@pytest.fixture(scope="module")
def cert():
    return load_default()


def test_form_holds_the_conversions(cert):
    for model in (cert.accel, cert.gyro):
        form = triad_form(model)
        assert triad_form(form) is form and form.name == model.name
        np.testing.assert_array_equal(form.certificate, certificate_vector(model))
        np.testing.assert_array_equal(form.limit, limit_vector(model))
        np.testing.assert_array_equal(form.certificate_std, certificate_std_vector(model))
        assert form.units == parameter_units(model)
        shape, q = shape_of_triad(model)
        np.testing.assert_array_equal(form.shape, shape)
        np.testing.assert_array_equal(form.q, q)
        for m0 in (1.0, 9.80665, 1234.5):
            np.testing.assert_array_equal(form.scale(m0), internal_scale(model, m0))
            np.testing.assert_array_equal(
                internal_limits(form, m0), limit_vector(model) / internal_scale(model, m0)
            )
            np.testing.assert_array_equal(
                certificate_internal(form, m0)[0],
                np.concatenate([model.bias / (model.scale_factor * m0), shape]),
            )
        with pytest.raises(ValueError):
            form.certificate[0] = 1.0  # shared by every fit: read-only


@pytest.mark.parametrize("seed", range(4))
def test_fits_with_the_form_equal_fits_with_the_model(cert, seed):
    rng = np.random.default_rng(seed)
    model = cert.accel
    k = 14
    up = rng.normal(size=(k, 3))
    up /= np.linalg.norm(up, axis=1)[:, None]
    g = 1.0 / model.unit_to_si * 9.80665
    means = model.bias + model.scale_factor * up * g + rng.normal(0.0, 0.5, (k, 3))
    var = np.full((k, 3), 0.3)
    mag = np.full(k, g)
    form = triad_form(model)
    for kw in ({}, {"start": "certificate", "max_iter": 0, "scale_by_residual": False}):
        a = fit_arrays(exact_fit(model, means, var, mag, **kw))
        b = fit_arrays(exact_fit(form, means, var, mag, **kw))
        for key in a:
            if a[key] is None:
                assert b[key] is None
            else:
                np.testing.assert_array_equal(b[key], a[key], err_msg=key)
    i_model, i_form = isolate(model, means, var, mag), isolate(form, means, var, mag)
    np.testing.assert_array_equal(i_form.alone_std, i_model.alone_std)
    np.testing.assert_array_equal(i_form.limit, i_model.limit)
    assert [f.group for f in i_form.findings] == [f.group for f in i_model.findings]


def test_moving_base_converts_the_certificate_once(cert, monkeypatch):
    from imudiag.aiding.moving import MovingConfig, moving_base_diagnosis
    from imudiag.aiding.tpv import parse_tpv, track_from_reports
    from imudiag.sim.drive import simulate_drive

    res, reports, _ = simulate_drive("urban", 420.0, cert, 3, 100.0)
    track = track_from_reports([parse_tpv(r) for r in reports])
    calls = []
    real = params.certificate_vector

    def counted(triad):
        calls.append(triad.name)
        return real(triad)

    for module in list(sys.modules.values()):  # every module that bound the name
        if getattr(module, "__name__", "").startswith("imudiag") and (
            getattr(module, "certificate_vector", None) is real
        ):
            monkeypatch.setattr(module, "certificate_vector", counted)
    out = moving_base_diagnosis(res.samples, cert, track, MovingConfig())
    assert out["windows_run"] >= 3
    assert calls.count("accel") == 1  # once for every window's isolation and fit

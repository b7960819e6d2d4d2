"""A window's std that holds a scatter measured on its own few points is judged as Student-t.

A window fit of few degrees of freedom (3 to 5: 12 to 14 attitudes for the 9 parameters)
estimates the scatter of its points beyond their stated noise (the excess variance, the
Birge ratio: bias wander, placement) from those few residuals. The fault test compared the
deviation with 4 of that std as if it were known; the ratio is Student-t with the std's
effective degrees of freedom (Welch-Satterthwaite: :attr:`TriadFit.deviation_dof`), whose
4-sigma tail is at 17 sigma for 4 degrees of freedom. On a healthy unit whose biases wander
(benchmarks/fault_onset.py ``--wander``, sigma 0.21 limits, tau 31 s) the windows ending at
52 and 57 s (3 and 4 degrees of freedom) named ax/az and ay/az misalignments at -1.4 and
-2.1 limits until 2026-11-29; no real recording or frozen report changes (their fits have
15 or more degrees of freedom, or no excess).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from benchmarks.fault_onset import wander_session
from imudiag.certificate import load_default
from imudiag.diagnosis import diagnose_samples
from imudiag.diagnosis.params import PARAM_KEYS, TriadFit
from imudiag.diagnosis.predicates import candidates, critical_sigma
from imudiag.diagnosis.scalar_fit import exact_fit
from imudiag.sim.trajectories import spread_up_directions
from imudiag.stats import log_t_two_sided, t_equivalent

G = 9.80665


def test_t_tail_and_quantile_equal_scipys():
    st = pytest.importorskip("scipy.stats")
    p = 2.0 * st.norm.sf(4.0)
    for dof in (0.5, 1.0, 2.0, 3.0, 3.37, 4.0, 7.5, 15.0, 40.0, 1e4):
        assert t_equivalent(4.0, dof) == pytest.approx(st.t.isf(p / 2.0, dof), rel=1e-8)
    for t, dof in ((0.1, 3.0), (2.0, 1.0), (5.0, 7.5), (30.0, 2.0), (4.0, 200.0)):
        assert math.exp(log_t_two_sided(t, dof)) == pytest.approx(2 * st.t.sf(t, dof), rel=1e-10)
    assert t_equivalent(4.0, math.inf) == 4.0


def _fit(std: float, estimated: float, dof: float, cert_std: float = 0.0) -> TriadFit:
    return TriadFit(
        triad="accel",
        method="exact",
        estimate=np.full(9, 10.0),
        std=np.full(9, std),
        certificate=np.zeros(9),
        limit=np.ones(9),
        determined=np.ones(9, dtype=bool),
        dof=dof,
        estimated_var=np.full(9, estimated),
        certificate_std=np.full(9, cert_std),
    )


def test_satterthwaite_degrees_of_freedom():
    # nothing estimated: the std is known, k sigma as before
    assert np.all(np.isinf(_fit(1.0, 0.0, 3.0).deviation_dof))
    np.testing.assert_array_equal(critical_sigma(_fit(1.0, 0.0, 3.0), 4.0), 4.0)
    # all of it estimated with 4 degrees of freedom: t with 4
    np.testing.assert_allclose(_fit(2.0, 4.0, 4.0).deviation_dof, 4.0)
    np.testing.assert_allclose(critical_sigma(_fit(2.0, 4.0, 4.0), 4.0), t_equivalent(4.0, 4.0))
    # a quarter estimated: 16 x the dof; a certificate's own std adds known variance
    np.testing.assert_allclose(_fit(2.0, 1.0, 4.0).deviation_dof, 64.0)
    np.testing.assert_allclose(_fit(2.0, 1.0, 4.0, cert_std=2.0).deviation_dof, 256.0)
    # a deviation of 10 std: a candidate at 4 dof (17.4 sigma needed) no longer, at 64 yes
    assert not candidates(_fit(1.0, 1.0, 4.0), 4.0).any()
    assert candidates(_fit(2.0, 1.0, 4.0), 4.0).all()


def test_few_dof_windows_of_a_scattering_healthy_unit():
    """800 accelerometer windows of a healthy unit, 12 attitudes each (3 degrees of freedom),
    their means scattering 5x their stated noise: among the fits that estimated that
    excess, a deviation beyond 4 of its std was 2.6 % of the parameters (160 of 8824 in a
    first run: t with 3 dof puts 2.8 % there); beyond the Student-t threshold, 0.2 %."""
    cert = load_default()
    triad = cert.accel
    rng = np.random.default_rng(5)
    white = triad.noise_sigma(200.0) / math.sqrt(600)  # a 3-s hold's mean, output units
    normal = student = params = 0
    for k in range(800):
        up = spread_up_directions(12, k)
        means = triad.forward_si(up * G) + rng.normal(size=(12, 3)) * white * math.sqrt(26.0)
        fit = exact_fit(triad, means, np.tile(white**2, (12, 1)), G)
        if fit.excess_var <= 0.0:
            continue  # the excess not seen by these 3 residuals (the docstring of the module)
        z = np.abs(fit.deviation) / fit.deviation_std
        assert 2.5 < fit.dof < 3.5
        params += int(fit.determined.sum())
        normal += int(np.sum((z > 4.0) & fit.determined))
        student += int(np.sum((z > critical_sigma(fit, 4.0)) & fit.determined))
    assert params > 6000
    assert normal > 0.015 * params, (normal, params)
    assert student < 0.004 * params and student * 6 < normal, (student, normal, params)


def test_a_healthy_unit_whose_biases_wander_names_nothing():
    """The wander session that named two accelerometer misalignments (module docstring):
    the windows alone (``diagnose_samples``) name no parameter; both faces:
    tests/test_one_answer.py ``session-wander``."""
    cert = load_default()
    frac, tau_s, traj, sim, excursion = wander_session(cert, 706)
    assert (round(frac, 2), round(tau_s, 1)) == (0.21, 31.3)
    assert max(excursion.values()) < 0.5  # every bias within half its limit, all along
    report = diagnose_samples(cert, sim.samples, rate_hz=traj.rate_hz)
    verdict = report.verdict()
    assert [f for f in verdict["faults"] if f["cause"] in PARAM_KEYS] == []
    # the windows that named them: few degrees of freedom, an excess estimated
    few = [w for w in report.windows if w.accel.dof < 5 and w.accel.excess_var > 0]
    assert few, "no few-dof window with an excess: the case no longer tests the threshold"
    assert all(np.all(critical_sigma(w.accel, 4.0) > 5.0) for w in few)

"""A fault that begins mid-session (an onset, the daemon's everyday case) is named.

A window's exact fit that finds a step change (:mod:`imudiag.diagnosis.changepoint`: the
intervals on one side of the rejected ones are far off the fit to the others) keeps every
interval, as before; since 2026-11-29 the stream then starts its next windows at the step,
so they hold the unit as it is now only. Before, the windows rolled through the step over
24 intervals, and a session that ended within that time often named nothing but the F0
check (an accelerometer bias of 9 limits from t = 60 s of a 135-s session) or named the
fault late.

Measured on 54 onsets drawn at random (``python -m benchmarks.fault_onset``: bias and
scale factor of any accelerometer or MEMS gyro axis, any accelerometer misalignment, 4 to 9
limits, onset at 30 to 90 s; through diagnose): named exactly 45, with a wrong
parameter 2, missed 7 before 2026-11-29; 54, 0 and 0 after (docs/diagnosis.md, "Fault
onsets mid-session").
"""

from __future__ import annotations

from itertools import pairwise

import numpy as np
import pytest

from benchmarks.fault_onset import catalogue
from imudiag.certificate import load_default
from imudiag.diagnosis import diagnose_samples
from imudiag.diagnosis.params import limit_vector
from imudiag.sim import Fault, multi_position, simulate

AXES = "xyz"


def _onsets(n: int, seed: int) -> list:
    """``n`` onsets picked at random under ``seed``: fault, size 5 to 9 limits, sign,
    onset time 40 to 70 s, simulation seed."""
    rng = np.random.default_rng(seed)
    cat = catalogue(("accel",))
    out = []
    for _ in range(n):
        kind, sensor, index = cat[int(rng.integers(len(cat)))]
        factor = round(float(rng.uniform(5.0, 9.0)) * float(rng.choice([-1.0, 1.0])), 2)
        at = round(float(rng.uniform(40.0, 70.0)), 1)
        sim_seed = int(rng.integers(10_000))
        out.append(
            pytest.param(
                kind, sensor, index, factor, at, sim_seed, id=f"{sensor}-{kind}-{factor:+}x-{at}s"
            )
        )
    return out


def _diagnose(faults: list[Fault], sim_seed: int, attitudes: int = 30):
    cert = load_default()
    traj = multi_position(n_attitudes=attitudes, dwell_s=3.0, turn_s=1.5, rate_hz=200, seed=41)
    sim = simulate(cert, traj, seed=sim_seed, faults=faults)
    return cert, diagnose_samples(cert, sim.samples, rate_hz=traj.rate_hz)


@pytest.mark.parametrize("kind, sensor, index, factor, at_s, sim_seed", _onsets(3, seed=2912))
def test_a_hidden_accelerometer_onset_is_named_alone(
    kind: str, sensor: str, index: int, factor: float, at_s: float, sim_seed: int
) -> None:
    """The fault is the verdict's only one, first in a window after the onset, its
    estimate the faulty value; a window that found the step had the stream start again
    within one pose of the onset. (The first pick, ax/ay misalignment from 40 s, named
    ax/az and ay/az as well before the withdrawal: the windows at 66 and 70 s, 9 holds
    before the onset and 5 after, fitted the mixture with other misalignments.)"""
    cert = load_default()
    limit = float(limit_vector(cert.accel)[index])
    cert, diag = _diagnose([Fault(kind, sensor, at_s, factor * limit)], sim_seed, attitudes=40)
    verdict = diag.verdict()
    assert [(f["triad"], f["sensor"], f["cause"]) for f in verdict["faults"]] == [
        ("accel", sensor, kind)
    ]
    (fault,) = verdict["faults"]
    assert fault["t_first"] > at_s
    truth = fault["certificate"] + factor * limit
    assert abs(fault["estimate"] - truth) < max(4.0 * fault["std"], 0.3 * limit)
    # what windows mixing both sides of the onset raised is withdrawn, never earlier
    assert all(f["t_first"] > at_s for f in verdict.get("withdrawn", []))
    for before, after in pairwise(diag.windows):
        if before.accel.extra.get("step_change") or before.gyro.extra.get("step_change"):
            assert at_s - 4.5 <= after.t_start <= at_s + 4.5


def test_a_bias_step_near_the_end_of_a_session_is_named_from_the_windows_after_it() -> None:
    """ax's bias steps by 9 limits at 60 s of a 135-s session: a window finds the step,
    the next windows start at it, and they name ax bias with its new value. Before they
    straddled the step to the session's end, the std about a limit: nothing named."""
    cert = load_default()
    limit = float(cert.accel.limits.bias[0])
    cert, diag = _diagnose([Fault("bias", "ax", 60.0, 9.0 * limit)], 45)
    found = [w for w in diag.windows if w.accel.extra.get("step_change")]
    assert len(found) == 1
    later = [w for w in diag.windows if w.t_end > found[0].t_end]
    assert later and all(60.0 - 4.5 <= w.t_start <= 60.0 + 4.5 for w in later)
    verdict = diag.verdict()
    assert [(f["sensor"], f["cause"]) for f in verdict["faults"]] == [("ax", "bias")]
    (fault,) = verdict["faults"]
    assert fault["estimate"] == pytest.approx(float(cert.accel.bias[0]) + 9.0 * limit, abs=3.0)


def test_a_clean_session_never_starts_again() -> None:
    """No step in a healthy session: no window finds one, the windows roll as before."""
    _, diag = _diagnose([], 42, attitudes=40)
    assert not [w for w in diag.windows if w.accel.extra.get("step_change")]
    assert (diag.verdict()["accel"], diag.verdict()["faults"]) == ("ok", [])


def test_faults_raised_on_a_mixture_are_withdrawn_and_earlier_ones_stay() -> None:
    """PredicateTracker.restart: a fault first raised at or after the step is withdrawn
    with its reason, one raised before stays, and a streak begun after the step is
    forgotten (one more candidate window does not complete it)."""
    from imudiag.diagnosis.params import TriadFit
    from imudiag.diagnosis.predicates import PredicateTracker

    cert = load_default()
    lim = limit_vector(cert.accel)

    def fit(dev: dict[int, float]) -> TriadFit:
        est = np.zeros(9)
        for i, k in dev.items():
            est[i] = k * lim[i]
        return TriadFit(
            triad="accel",
            method="exact",
            estimate=est,
            std=0.01 * lim,
            certificate=np.zeros(9),
            limit=lim,
            determined=np.ones(9, dtype=bool),
            reasons=[""] * 9,
            points=24,
            dof=10.0,
        )

    tracker = PredicateTracker()
    tracker.update(fit({0: 5.0}), 10.0)
    tracker.update(fit({0: 5.0}), 20.0)  # ax bias raised, first at 10 s
    tracker.update(fit({0: 5.0, 7: 5.0}), 30.0)
    tracker.update(fit({0: 5.0, 7: 5.0}), 40.0)  # ax/az misalignment raised, first at 30 s
    tracker.update(fit({0: 5.0, 7: 5.0, 4: 5.0}), 50.0)  # ay scale: one window of a streak
    withdrawn = tracker.restart("accel", 25.0)
    assert [(f["sensor"], f["cause"], f["t_first"]) for f in withdrawn] == [
        ("ax/az", "misalignment", 30.0)
    ]
    assert "step change at t = 25.00 s" in withdrawn[0]["reason"]
    assert tracker.withdrawn == withdrawn
    assert [(f["sensor"], f["cause"]) for f in tracker.all_raised()] == [("ax", "bias")]
    assert [(f["sensor"], f["cause"]) for f in tracker.active()] == [("ax", "bias")]
    tracker.update(fit({0: 5.0, 4: 5.0}), 60.0)  # the ay streak starts again
    assert ("ay", "scale_factor") not in {(f["sensor"], f["cause"]) for f in tracker.active()}
    tracker.update(fit({0: 5.0, 4: 5.0}), 70.0)
    assert ("ay", "scale_factor") in {(f["sensor"], f["cause"]) for f in tracker.active()}


def _gyro_scale_onsets(n: int, seed: int) -> list:
    """``n`` MEMS gyro scale-factor onsets picked at random under ``seed``: axis, size 5 to
    9 limits, sign, onset time 40 to 70 s, simulation seed (gyro bias onsets:
    tests/test_rest_step.py)."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        axis = int(rng.integers(3))
        factor = round(float(rng.uniform(5.0, 9.0)) * float(rng.choice([-1.0, 1.0])), 2)
        at = round(float(rng.uniform(40.0, 70.0)), 1)
        sim_seed = int(rng.integers(10_000))
        out.append(pytest.param(axis, factor, at, sim_seed, id=f"g{AXES[axis]}-{factor:+}x-{at}s"))
    return out


@pytest.mark.parametrize("axis, factor, at_s, sim_seed", _gyro_scale_onsets(2, seed=2914))
def test_a_hidden_gyro_scale_onset_is_named_alone(
    axis: int, factor: float, at_s: float, sim_seed: int
) -> None:
    """A gyro's scale factor changes mid-session (the rotation fit, which has no step
    test of its own): named alone, first in a window after the onset, its estimate the
    faulty value."""
    cert = load_default()
    sensor = f"g{AXES[axis]}"
    limit = float(limit_vector(cert.gyro)[3 + axis])
    _, diag = _diagnose(
        [Fault("scale_factor", sensor, at_s, factor * limit)], sim_seed, attitudes=40
    )
    verdict = diag.verdict()
    assert [(f["triad"], f["sensor"], f["cause"]) for f in verdict["faults"]] == [
        ("gyro", sensor, "scale_factor")
    ]
    (fault,) = verdict["faults"]
    assert fault["t_first"] > at_s
    truth = fault["certificate"] + factor * limit
    assert abs(fault["estimate"] - truth) < max(4.0 * fault["std"], 0.3 * limit)

"""Evidence: on simulated multi-position sessions the exact fault is isolated, clean ones pass.

One injected fault at 3 to 6 times its limit (bias, scale factor, misalignment of
any accelerometer axis; bias and scale factor of any MEMS gyro axis; bias,
scale factor and misalignment of a navigation-grade gyro that sees Earth
rate), or none. The cases are a seeded random subset of that catalogue.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from imudiag.certificate import load, load_default
from imudiag.diagnosis import diagnose_samples
from imudiag.diagnosis.params import certificate_vector, limit_vector
from imudiag.sim import Fault, multi_position, simulate

NAV = Path(__file__).parent / "data" / "diagnosis" / "nav-grade.yaml"
AXES = "xyz"


def _catalogue(grade: str) -> list[tuple[str, str, int]]:
    """(kind, sensor, parameter index) the evidence covers for a grade."""
    out = []
    for t in ("a", "g"):
        for a in range(3):
            out.append(("bias", f"{t}{AXES[a]}", a))
            out.append(("scale_factor", f"{t}{AXES[a]}", 3 + a))
        if t == "a" or grade == "nav":
            for k, pair in enumerate((f"{t}x/{t}y", f"{t}x/{t}z", f"{t}y/{t}z")):
                out.append(("misalignment", pair, 6 + k))
    return out


def _cases(grade: str, n_faulty: int, n_clean: int, seed: int) -> list:
    rng = np.random.default_rng(seed)
    cat = _catalogue(grade)
    pick = rng.permutation(len(cat))[:n_faulty]
    cases = []
    for k in pick:
        kind, sensor, index = cat[k]
        factor = float(rng.uniform(3.0, 6.0)) * float(rng.choice([-1.0, 1.0]))
        cases.append(
            pytest.param(
                grade,
                kind,
                sensor,
                index,
                round(factor, 2),
                int(rng.integers(10_000)),
                id=f"{grade}-{kind}-{sensor}-{factor:+.1f}x",
            )
        )
    for k in range(n_clean):
        cases.append(
            pytest.param(
                grade, None, None, None, 0.0, int(rng.integers(10_000)), id=f"{grade}-clean-{k}"
            )
        )
    return cases


CASES = _cases("mems", 14, 3, seed=2026) + _cases("nav", 8, 2, seed=2027)


def _session(grade: str, seed: int):
    if grade == "mems":
        cert = load_default()
        traj = multi_position(n_attitudes=16, dwell_s=3.0, turn_s=1.5, rate_hz=200, seed=seed)
    else:
        cert = load(NAV)
        traj = multi_position(n_attitudes=20, dwell_s=20.0, turn_s=2.0, rate_hz=100, seed=seed)
    return cert, traj


@pytest.mark.parametrize("grade, kind, sensor, index, factor, seed", CASES)
def test_fault_isolated_or_clean(grade, kind, sensor, index, factor, seed):
    cert, traj = _session(grade, seed)
    faults = []
    if kind is not None:
        triad = "gyro" if sensor[0] == "g" else "accel"
        limit = limit_vector(cert.triad(triad))[index]
        faults = [Fault(kind, sensor, 0.0, factor * limit)]
    sim = simulate(cert, traj, seed=seed + 1, faults=faults)
    diag = diagnose_samples(cert, sim.samples, rate_hz=traj.rate_hz)
    verdict = diag.verdict()
    raised = [(f["triad"], f["sensor"], f["cause"]) for f in verdict["faults"]]
    if kind is None:
        assert raised == []
        assert (verdict["accel"], verdict["gyro"]) == ("ok", "ok"), verdict["undetermined"]
        return
    other = "accel" if triad == "gyro" else "gyro"
    assert raised == [(triad, sensor, kind)]
    assert verdict[triad] == "fault"
    assert verdict[other] == "ok", verdict["undetermined"]
    (fault,) = verdict["faults"]
    truth = certificate_vector(cert.triad(triad))[index] + factor * limit
    assert fault["certificate"] == pytest.approx(certificate_vector(cert.triad(triad))[index])
    assert fault["limit"] == pytest.approx(limit)
    assert abs(fault["estimate"] - truth) < max(4.0 * fault["std"], 0.3 * limit)
    assert fault["t_first"] <= traj.t[-1]

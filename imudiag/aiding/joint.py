"""GNSS latency and lever arm solved together (issue 15).

The two confound: a lever arm adds rotation-dependent terms to |f| that shift the
correlation peak of :mod:`.align`, and a latency error shifts |f| in time, which in
turns and braking looks like the tangential lever term (:mod:`.lever_arm`). Started
from the separate estimates, Gauss-Newton on the epochs' |f| mismatch

    |f_gnss| - |f_imu(tau)| = d_k (tau' - tau) + u^T A(tau) l + c

with d_k = d|f_imu|/dtau (s^-1 m/s^2, the central difference of the epoch means at
tau +- ``step_s``) and the lever-arm rows of :func:`.lever_arm.lever_arm_rows`,
re-linearised at the new latency until the step is below ``tol_s``. The covariance
gives the latency's std and its correlation with each lever component.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .lever_arm import (
    LeverArmEstimate,
    lever_arm_rows,
    row_noise_correction,
    undetermined_reason,
    weighted_solve,
)
from .specific_force import GnssEpochs, ImuSeries

#: lag step of the |f| derivative, s
DERIVATIVE_STEP_S = 0.02
#: the iteration stops when the latency moves less than this, s
TOLERANCE_S = 1e-3
MAX_ITERATIONS = 8
#: the joint solution replaces the separate estimates when it converged with a latency
#: std at most this, s (a third of the 0.03 s latency tolerance of docs/moving-base.md);
#: with MEMS noise on a car the two confound too much (std 15-110 ms) and the separate
#: estimates are kept
MAX_LATENCY_STD_S = 0.01


@dataclass
class JointEstimate:
    """Latency (s) and lever arm (m, body, IMU to antenna) solved together."""

    latency_s: float  #: nan when nothing could be solved
    latency_std_s: float  #: 1 sigma, s
    lever: LeverArmEstimate
    #: correlation of the latency with each lever component (3,), from the covariance
    correlation: np.ndarray
    iterations: int
    converged: bool
    reason: str  #: why not solved ("" when solved)

    def usable(self, max_latency_std_s: float = MAX_LATENCY_STD_S) -> tuple[bool, str]:
        """(whether the joint solution replaces the separate one, why)."""
        if not self.converged or not math.isfinite(self.latency_s):
            return False, f"separate estimates kept: {self.reason or 'no joint solution'}"
        if not self.latency_std_s <= max_latency_std_s:
            return False, (
                f"separate estimates kept: the joint latency std {1e3 * self.latency_std_s:.3g} ms"
                f" is above {1e3 * max_latency_std_s:g} ms (latency and lever arm confounded)"
            )
        return True, f"joint: latency std {1e3 * self.latency_std_s:.3g} ms"

    def to_json(self) -> dict:
        """The joint estimate as reported."""

        def r(x: float, nd: int = 4) -> float | None:
            return round(float(x), nd) if math.isfinite(x) else None

        return {
            "latency_s": r(self.latency_s),
            "latency_std_s": r(self.latency_std_s),
            "lever_arm": self.lever.to_json(),
            "latency_lever_correlation": [r(x, 3) for x in self.correlation],
            "iterations": self.iterations,
            "converged": self.converged,
            "reason": self.reason,
        }


def solve_latency_lever(
    t: np.ndarray,
    accel_si: np.ndarray,
    gyro_si: np.ndarray,
    epochs: GnssEpochs,
    latency_s: float,
    sigma_sample_si: np.ndarray | float = 0.0,
    row_noise_var: float = 0.0,
    max_latency_s: float = 0.5,
    determined_std_m: float = 0.15,
    min_epochs: int = 30,
    free_axes: np.ndarray | None = None,
    series: ImuSeries | None = None,
) -> JointEstimate:
    """The joint latency and lever arm (module doc), started at ``latency_s`` (s):
    t (N,) s, accel_si and gyro_si (N, 3) corrected SI samples, the GNSS ``epochs``;
    ``sigma_sample_si`` the accelerometer white noise per sample (m/s^2) and
    ``row_noise_var`` the lever rows' noise (:func:`.lever_arm.row_noise_variance`);
    ``free_axes`` (3,) bool: the lever components solved for (the others are held at 0
    and reported undetermined; default all three). ``series``: the record made once
    (:class:`.ImuSeries` of t, accel_si, gyro_si) when the caller has it."""
    if series is None:  # three cuts of the same record per iteration
        series = ImuSeries(t, accel_si, gyro_si)
    free = np.ones(3, bool) if free_axes is None else np.asarray(free_axes, bool)
    cols = np.concatenate([[True], free, [True]])
    tau = float(latency_s)
    nan3 = np.full(3, np.nan)
    it, converged = 0, False
    x = cov = std = None
    chi2_dof = math.nan
    n = 0
    u_ok = np.zeros((0, 3))
    while it < MAX_ITERATIONS:
        it += 1
        sig = sigma_sample_si
        im = series.epochs(epochs.t0, epochs.t1, sigma_sample_si=sig, latency_s=tau)
        hi = series.epochs(
            epochs.t0,
            epochs.t1,
            sigma_sample_si=sig,
            latency_s=tau + DERIVATIVE_STEP_S,
            gyro_means=False,  # only |f| and the coverage are used
        )
        lo = series.epochs(
            epochs.t0,
            epochs.t1,
            sigma_sample_si=sig,
            latency_s=tau - DERIVATIVE_STEP_S,
            gyro_means=False,  # only |f| and the coverage are used
        )
        d = (hi.mag - lo.mag) / (2.0 * DERIVATIVE_STEP_S)
        rows = lever_arm_rows(t, gyro_si, epochs.t0, epochs.t1, im.mean_si, tau, series=series)
        y = epochs.mag - im.mag
        var = epochs.sigma_mag**2 + im.sigma_mag**2
        ok = (
            epochs.valid
            & im.covered
            & hi.covered
            & lo.covered
            & np.isfinite(d)
            & np.all(np.isfinite(rows), axis=1)
            & np.isfinite(y)
            & np.isfinite(var)
            & (var > 0)
        )
        n = int(np.sum(ok))
        if n < min_epochs:
            lever = LeverArmEstimate(
                nan3, nan3, np.zeros(3, bool), math.nan, n, math.nan,
                f"{n} usable GNSS epochs, {min_epochs} needed",
            )  # fmt: skip
            return JointEstimate(math.nan, math.nan, lever, nan3, it, False, lever.reason)
        h = np.column_stack([d[ok], rows[ok], np.ones(n)])[:, cols]
        correction = None
        with np.errstate(invalid="ignore", divide="ignore"):
            u_ok = im.mean_si[ok] / im.mag[ok][:, None]
        if row_noise_var > 0:
            correction = np.zeros((5, 5))
            correction[1:4, 1:4] = row_noise_correction(u_ok, 1.0 / var[ok], row_noise_var)
            correction = correction[np.ix_(cols, cols)]
        xs, cs, ss, chi2_dof = weighted_solve(h, y[ok], var[ok], correction)
        # back to (latency, lever x y z, offset), held components at 0 with an infinite std
        x, std = np.zeros(5), np.full(5, np.inf)
        cov = np.zeros((5, 5))
        x[cols], std[cols] = xs, ss
        cov[np.ix_(cols, cols)] = cs
        step = float(x[0]) if math.isfinite(std[0]) else 0.0
        new_tau = float(np.clip(tau + step, -max_latency_s, max_latency_s))
        moved = abs(new_tau - tau)
        tau = new_tau
        if moved < TOLERANCE_S:
            converged = True
            break
    assert x is not None and cov is not None and std is not None
    lever_std = std[1:4]
    determined = lever_std <= determined_std_m
    reason = undetermined_reason(lever_std, determined_std_m)
    lever = LeverArmEstimate(x[1:4], lever_std, determined, float(x[4]), n, chi2_dof, reason)
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov[0, 1:4] / np.sqrt(cov[0, 0] * np.diag(cov)[1:4])
    corr = np.where(np.isfinite(std[1:4]) & math.isfinite(std[0]), corr, np.nan)
    why = "" if converged else f"the latency still moved after {it} iterations"
    return JointEstimate(tau, float(std[0]), lever, corr, it, converged, why)


def separate_latency_std(report: dict, latency_s: float, std_s: float) -> float:
    """Std (s) of the separate (correlation) ``latency_s`` (s) with its own ``std_s`` (s)
    when the joint solution (``report`` of :func:`choose`) is not used: where the joint
    one has a latency and a finite std (converged or not: a hilly RTK drive's did not
    within 8 passes, and the correlation's 59 ms error was 3.3 of its own stds), at
    least hypot(distance between the two, joint std), the separate latency's error being
    that distance plus the joint one's error: a lever arm left out of the correlation
    pulls its peak (53-61 ms on the exact hilly drives, docs/moving-base.md) and no
    spread of the correlation itself shows that."""
    joint_s, joint_std = report.get("latency_s"), report.get("latency_std_s")
    if joint_s is not None and joint_std is not None:
        return max(std_s, math.hypot(float(joint_s) - latency_s, float(joint_std)))
    return std_s


def choose(
    joint: JointEstimate,
    latency_s: float,
    lever: LeverArmEstimate,
    latency_determined: bool = True,
) -> tuple[float, LeverArmEstimate, dict]:
    """(latency s, lever estimate, report): the joint ones where :meth:`JointEstimate.usable`
    and the separate latency was determined, else the separate ``latency_s`` and ``lever``;
    the report is the joint estimate's JSON with ``used`` and ``note``. Started from an
    undetermined latency (a highway drive with MEMS noise) the joint solution claimed
    1-3 ms stds while 90-130 ms off (docs/moving-base.md), so it is reported, not used."""
    ok, note = joint.usable()
    if ok and not latency_determined:
        ok, note = False, "separate estimates kept: started from an undetermined latency"
    report = dict(joint.to_json(), used=ok, note=note)
    if ok:
        return joint.latency_s, joint.lever, report
    return latency_s, lever, report


__all__ = [
    "MAX_LATENCY_STD_S",
    "JointEstimate",
    "choose",
    "separate_latency_std",
    "solve_latency_lever",
]

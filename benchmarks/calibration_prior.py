"""Evidence for issue 29: how wide the prior toward ``--like`` should be, chosen by the
calibration's own check (each attitude left out in turn, on imudiag's own intervals), never
by the evaluator's score (``tests/holdout_scoring.py``).

Run: ``.venv/bin/python -m benchmarks.calibration_prior``. Prints, per shipped
multi-position recording:

- what the data alone know with each attitude left out (imucal): the free fit's (no prior)
  standard deviation of every bias (output units) and scale-factor error, each attitude's
  tilt off its nearest axis (deg), and, linearised at the whole session's fit with the
  misalignments held known (the most the faces could say), the left-out axis's bias and
  scale std and their correlation;
- the leave-one-attitude-out RMS of |a|/g - 1 (mg) of the calibration with the prior
  scale per class as ``imudiag calibrate`` sets it (type-II maximum likelihood,
  :func:`imudiag.diagnosis.calibrate.prior_inflation`), with the certificate's stated
  width unscaled (``stated``) and with practically no prior (``free``); the prior scale is
  estimated inside each fold, from the attitudes the fold keeps.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from imudiag.certificate import Certificate, load
from imudiag.diagnosis import calibrate as cal
from imudiag.diagnosis.config import DiagnosisConfig
from imudiag.diagnosis.intervals import QuasiStaticInterval
from imudiag.diagnosis.params import triad_form
from imudiag.diagnosis.scalar_fit import (
    RESIDUAL_FLOOR,
    certificate_internal,
    exact_fit,
    residuals_and_jacobian,
)
from imudiag.diagnosis.session import collect_intervals
from imudiag.diagnosis.window import attitude_groups
from imudiag.logs import read_log

DATA = Path(__file__).resolve().parent.parent / "tests" / "data"
#: the shipped multi-position recordings and their --like certificates
RECORDINGS = (
    ("xsens-mti-multiposition/session.csv.gz", "like-xsens.yaml"),
    ("imucal-ferraris/session.csv.gz", "like-imucal.yaml"),
    ("mpu6050/calibration.csv.gz", "like-mpu6050.yaml"),
)
RULES = ("evidence", "stated", "free")


@contextmanager
def prior_rule(rule: str) -> Iterator[None]:
    """Within the block, the calibration's prior scale per class follows ``rule``."""
    original = cal.prior_inflation
    if rule == "stated":
        cal.prior_inflation = lambda *a: np.ones(3)  # type: ignore[assignment]
    elif rule == "free":
        cal.prior_inflation = lambda *a: np.full(3, 1.0e4)  # type: ignore[assignment]
    try:
        yield
    finally:
        cal.prior_inflation = original  # type: ignore[assignment]


def leave_attitudes_out(
    intervals: list[QuasiStaticInterval], like: Certificate, rate: float, cfg: DiagnosisConfig
) -> tuple[float, list[float]]:
    """RMS (mg) of |a|/g - 1 over every interval predicted with its attitude left out, and
    each fold's RMS (mg)."""
    g_in = like.gravity / like.accel.unit_to_si
    groups = attitude_groups(np.array([iv.up for iv in intervals]), cfg.attitude_separation_deg)
    errs, per = [], []
    for k in range(int(groups.max()) + 1):
        out = groups == k
        train = [iv for iv, o in zip(intervals, out, strict=True) if not o]
        if len(train) < 3:
            continue
        res = cal.calibrate(train, copy.deepcopy(like), "exact", rate, config=cfg)
        m = np.array([iv.accel_mean for iv, o in zip(intervals, out, strict=True) if o])
        e = np.linalg.norm(res.certificate.accel.inverse(m), axis=1) / g_in - 1.0
        errs.append(e)
        per.append(1e3 * float(np.sqrt(np.mean(e**2))))
    a = np.concatenate(errs)
    return 1e3 * float(np.sqrt(np.mean(a**2))), per


def information(intervals: list[QuasiStaticInterval], like: Certificate, cfg: DiagnosisConfig):
    """Per attitude left out: its direction, interval count, tilt off the nearest axis (deg),
    the free fit's std (no prior, at its own estimate) of the biases (output units) and
    scale-factor errors on the rest, and, linearised at the whole session's free fit with the
    misalignments held known, the left-out axis's bias std (output units), scale std and the
    correlation of the two."""
    acc = like.accel
    g_in = like.gravity / acc.unit_to_si
    means = np.array([iv.accel_mean for iv in intervals])
    mvar = np.array([iv.mean_var("accel") for iv in intervals])
    ups = np.array([iv.up for iv in intervals])
    groups = attitude_groups(ups, cfg.attitude_separation_deg)
    whole = exact_fit(acc, means, mvar, g_in, prior_factor=np.inf, max_iter=100)
    form = triad_form(acc)
    scale = form.scale(g_in)
    theta_c, _ = certificate_internal(form, g_in)
    theta = theta_c + (whole.estimate - whole.certificate) / scale
    for k in range(int(groups.max()) + 1):
        u = ups[groups == k].mean(axis=0)
        u /= np.linalg.norm(u)
        axis = int(np.argmax(np.abs(u)))
        tilt = math.degrees(math.acos(min(1.0, float(np.max(np.abs(u))))))
        keep = groups != k
        f = exact_fit(acc, means[keep], mvar[keep], g_in, prior_factor=np.inf, max_iter=100)
        v = means[keep] / (form.scale_factor * g_in)
        _, jac, w = residuals_and_jacobian(theta, v, np.ones(int(keep.sum())))
        var_v = mvar[keep] / (form.scale_factor * g_in) ** 2
        wgt = 1.0 / (np.einsum("kj,kj->k", w * w, var_v) + RESIDUAL_FLOOR**2 + whole.excess_var)
        info = jac.T @ (jac * wgt[:, None])
        cov = np.linalg.inv(info[:6, :6])  # biases and scales, misalignments known
        sb = math.sqrt(cov[axis, axis]) * scale[axis]
        ss = math.sqrt(cov[3 + axis, 3 + axis]) * scale[3 + axis]
        corr = cov[axis, 3 + axis] / math.sqrt(cov[axis, axis] * cov[3 + axis, 3 + axis])
        yield k, u, tilt, int((groups == k).sum()), f.std[:3], f.std[3:6], (sb, ss, corr)


def main() -> None:
    cfg = DiagnosisConfig()
    for rec, like_name in RECORDINGS:
        block = read_log(DATA / "real" / rec)
        like = load(DATA / "diagnosis" / like_name)
        intervals, rate, _ = collect_intervals(block, like, cfg)
        name = rec.split("/")[0]
        print(f"## {name}: {len(intervals)} intervals ({like.accel.output_unit})")
        if name == "imucal-ferraris":
            for k, u, tilt, n, sb, ss, (lb, ls, corr) in information(intervals, like, cfg):
                print(
                    f"  attitude {k} {np.round(u, 3)} ({n} intervals, tilt {tilt:.1f} deg) "
                    f"left out: free-fit std bias {np.round(sb, 3)}, scale {np.round(ss, 4)}; "
                    f"at the whole fit, misalignments known: its axis's bias std {lb:.3f}, "
                    f"scale std {ls:.4f}, correlation {corr:+.4f}"
                )
        for rule in RULES:
            with prior_rule(rule):
                total, per = leave_attitudes_out(intervals, like, rate, cfg)
            print(
                f"  {rule:8s} left out by attitude: {total:.3f} mg "
                f"(folds {' '.join(f'{x:.2f}' for x in per)})"
            )


if __name__ == "__main__":
    main()

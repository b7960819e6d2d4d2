"""``python -m benchmarks.latency_lever``: GNSS latency and lever arm, separate vs joint.

Simulated drives (fixed seeds) whose GNSS velocity is the antenna's, ``LEVER`` m from
the IMU (body axes), tagged ``LATENCY_S`` late. For each drive: the separate estimates
(latency by the |f| correlation of :mod:`imudiag.aiding.align`, then the lever arm at
that latency, :func:`imudiag.aiding.moving.estimate_lever_arm`) and the joint solution
started from them (:mod:`imudiag.aiding.joint`); printed: the latency error (ms), the
lever error per axis (m, with the std, ``-`` where the axis is not determined), the
joint latency std and its correlation with the lever components. Kinds:

- ``exact``: the trajectory's exact specific force and rate at 100 Hz, GNSS velocity to
  1 mm/s, no multipath (the tolerances of docs/moving-base.md are for this kind);
- ``rtk`` / ``standard``: the bundled certificate's MEMS noise at 100 Hz, GNSS velocity
  noise 0.01/0.015 or 0.03/0.05 m/s, 0.5 % multipath epochs.

Also the correlation latency's jackknife std (:mod:`imudiag.aiding.align`) and its
coverage: the share of drives with |error| <= 2 std and <= 3 std (per kind and over
all), at each sample rate of ``--rates``.

One JSON line per drive; a summary per kind at the end.
"""

from __future__ import annotations

import argparse
import json
import math
from typing import Any

import numpy as np

from imudiag.aiding.align import LATENCY_TOLERANCE_S, estimate_latency, used_latency
from imudiag.aiding.joint import choose, separate_latency_std, solve_latency_lever
from imudiag.aiding.lever_arm import lever_arm_rows, solve_lever_arm
from imudiag.aiding.moving import (
    accel_noise,
    estimate_lever_arm,
    gyro_noise_si,
    lever_row_noise,
)
from imudiag.aiding.specific_force import gnss_epochs, imu_epochs
from imudiag.aiding.tpv import parse_tpv, track_from_reports
from imudiag.certificate import load_default
from imudiag.sim.drive import EPOCH_UNIX, GnssSimConfig, drive_motion, gnss_reports, simulate_drive

LEVER = (1.0, -0.8, -1.2)  #: m, IMU to antenna, body axes
LATENCY_S = 0.12
RATE_HZ = 100.0
KINDS = {
    "exact": GnssSimConfig(sigma_h_m_s=0.001, sigma_v_m_s=0.001, outlier_rate=0.0),
    "rtk": GnssSimConfig(sigma_h_m_s=0.01, sigma_v_m_s=0.015),
    "standard": GnssSimConfig(),
}


def run_drive(
    scenario: str, seed: int, kind: str, duration_s: float, rate_hz: float = RATE_HZ
) -> dict[str, Any]:
    """Separate and joint estimates on one drive (module doc)."""
    base = KINDS[kind]
    gcfg = GnssSimConfig(
        sigma_h_m_s=base.sigma_h_m_s,
        sigma_v_m_s=base.sigma_v_m_s,
        outlier_rate=base.outlier_rate,
        latency_s=LATENCY_S,
        lever_arm_m=LEVER,
    )
    cert = load_default()
    if kind == "exact":
        motion = drive_motion(scenario, duration_s, seed)
        tr = motion.sample(rate_hz)
        t, f_si, w_si = tr.t + EPOCH_UNIX, tr.specific_force, tr.omega
        gyro_raw, sig_si, rv = None, 0.0, 0.0
        reports = gnss_reports(motion, gcfg, seed)
    else:
        res, reports, _ = simulate_drive(
            scenario, duration_s, cert, seed=seed, gnss=gcfg, rate_hz=rate_hz
        )
        t = res.samples.t
        f_si = cert.accel.inverse_si(res.samples.accel)
        w_si = cert.gyro.inverse_si(res.samples.gyro)
        gyro_raw = res.samples.gyro
        acc = cert.accel
        sig_si = accel_noise(res.samples.accel, acc.noise_sigma(rate_hz))
        sig_si = sig_si / acc.scale_factor * acc.unit_to_si
    track = track_from_reports([p for p in (parse_tpv(r) for r in reports) if p is not None])
    ep = gnss_epochs(track, span=max(1, int(round(1.0 / track.period_s()))))
    ep = ep.select((ep.t1 >= t[0]) & (ep.t0 <= t[-1]))
    if gyro_raw is not None:
        gyro_sig_si = gyro_noise_si(gyro_raw, cert.gyro, rate_hz)
        rv = lever_row_noise(gyro_sig_si, ep, rate_hz)
    lat = estimate_latency(t, f_si, ep, gyro_si=w_si, max_latency_s=0.5)
    tau, tau_std = used_latency(lat, 0.5)  # the best estimate, determined or not
    plain = imu_epochs(t, f_si, ep.t0, ep.t1, gyro_si=w_si, sigma_sample_si=sig_si, latency_s=tau)
    if gyro_raw is None:
        use = ep.valid & plain.covered & np.isfinite(plain.mag)
        rows = lever_arm_rows(t, w_si, ep.t0, ep.t1, plain.mean_si, tau)
        sep = solve_lever_arm(
            rows[use], (ep.mag - plain.mag)[use], (ep.sigma_mag**2 + plain.sigma_mag**2)[use]
        )
    else:
        sep = estimate_lever_arm(t, w_si, gyro_sig_si, ep, plain, tau, rate_hz)
    joint = solve_latency_lever(
        t, f_si, w_si, ep, tau, sigma_sample_si=sig_si, row_noise_var=rv, max_latency_s=0.5
    )
    chosen_tau, chosen, report = choose(joint, tau, sep, lat.determined)
    # the std the diagnosis uses with it (imudiag.aiding.moving)
    if report["used"]:
        chosen_std = joint.latency_std_s
    elif lat.determined:
        chosen_std = separate_latency_std(report, tau, tau_std)
    else:
        chosen_std = tau_std

    def lever_err(est: Any) -> list[float | None]:
        return [
            round(float(est.lever_arm_m[i] - LEVER[i]), 3) if est.determined[i] else None
            for i in range(3)
        ]

    return {
        "scenario": scenario,
        "seed": seed,
        "kind": kind,
        "rate_hz": rate_hz,
        # the correlation's own estimate, determined or not, and its jackknife std
        "correlation": {
            "latency_error_ms": round(1e3 * (lat.latency_s - LATENCY_S), 1)
            if math.isfinite(lat.latency_s)
            else None,
            "latency_std_ms": round(1e3 * lat.std_s, 1) if math.isfinite(lat.std_s) else None,
            "correlation": round(lat.correlation, 3),
            "determined": lat.determined,
        },
        "separate": {
            "latency_error_ms": round(1e3 * (tau - LATENCY_S), 1),
            "latency_determined": lat.determined,
            "lever_error_m": lever_err(sep),
            "lever_std_m": [round(float(s), 3) for s in sep.std_m],
        },
        "joint": {
            "latency_error_ms": round(1e3 * (joint.latency_s - LATENCY_S), 1)
            if math.isfinite(joint.latency_s)
            else None,
            "latency_std_ms": round(1e3 * joint.latency_std_s, 1),
            "lever_error_m": lever_err(joint.lever),
            "lever_std_m": [round(float(s), 3) for s in joint.lever.std_m],
            "correlation": [round(float(c), 2) for c in joint.correlation],
            "iterations": joint.iterations,
            "converged": joint.converged,
        },
        # what the diagnosis uses: the joint solution where usable, else the separate one
        "chosen": {
            "joint": report["used"],
            "latency_error_ms": round(1e3 * (chosen_tau - LATENCY_S), 1),
            "latency_std_ms": round(1e3 * chosen_std, 1),
            "determined": bool(chosen_std <= LATENCY_TOLERANCE_S),
            "lever_error_m": lever_err(chosen),
        },
    }


def _summary(rows: list[dict[str, Any]]) -> str:
    out = []
    for side in ("separate", "joint", "chosen"):
        lat = np.array([abs(r[side]["latency_error_ms"] or np.nan) for r in rows])
        lev = np.array(
            [[np.nan if e is None else abs(e) for e in r[side]["lever_error_m"]] for r in rows]
        )
        det = np.sum(np.isfinite(lev), axis=0)
        med = ", ".join(f"{np.nanmedian(lev[:, i]) if det[i] else math.nan:.2f}" for i in range(3))
        top = ", ".join(f"{np.nanmax(lev[:, i]) if det[i] else math.nan:.2f}" for i in range(3))
        extra = ""
        if side == "chosen":
            extra = f" (joint used on {sum(r['chosen']['joint'] for r in rows)})"
        out.append(
            f"{side}{extra}: |latency error| median {np.nanmedian(lat):.1f} ms, "
            f"max {np.nanmax(lat):.1f} ms; |lever error| (determined axes) median {med} m, "
            f"max {top} m (determined on {', '.join(str(int(x)) for x in det)} drives)"
        )
    return "\n  ".join(out)


def coverage(rows: list[dict[str, Any]], side: str = "correlation") -> str:
    """Share of drives whose latency error (``side``: "correlation" the correlation's
    estimate, "chosen" the one the diagnosis uses) is within 2 and 3 of its stds, and
    how many of them are determined (with their largest |error|, ms)."""

    def num(x: float | None) -> float:
        return np.nan if x is None else float(x)

    err = np.array([num(r[side]["latency_error_ms"]) for r in rows], float)
    std = np.array([num(r[side]["latency_std_ms"]) for r in rows], float)
    ok = np.isfinite(err) & np.isfinite(std)
    n = int(np.sum(ok))
    if not n:
        return "no drive with an estimate and a std"
    z = np.abs(err[ok]) / np.maximum(std[ok], 1e-9)
    det = np.array([r[side]["determined"] for r in rows], bool)
    worst = f"{np.nanmax(np.abs(err[det])):.1f} ms" if np.any(det) else "-"
    return (
        f"|error| <= 2 std on {np.mean(z <= 2):.1%}, <= 3 std on {np.mean(z <= 3):.1%} of {n}"
        f" drives; std median {np.median(std[ok]):.1f} ms (range {np.min(std[ok]):.1f}-"
        f"{np.max(std[ok]):.1f}); determined {int(np.sum(det))} of {len(rows)}, their largest"
        f" |error| {worst}"
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenarios", default="urban,highway,hilly")
    ap.add_argument("--seeds", default="21,22,23,24")
    ap.add_argument("--kinds", default="exact,rtk,standard")
    ap.add_argument("--duration", type=float, default=600.0, help="drive length, s")
    ap.add_argument("--rates", default="100", help="IMU sample rates, Hz (comma-separated)")
    args = ap.parse_args(argv)
    every = []
    for kind in args.kinds.split(","):
        rows = []
        for rate in (float(r) for r in args.rates.split(",")):
            for sc in args.scenarios.split(","):
                for seed in (int(s) for s in args.seeds.split(",")):
                    r = run_drive(sc, seed, kind, args.duration, rate)
                    rows.append(r)
                    print(json.dumps(r), flush=True)
        every += rows
        print(f"# {kind} ({len(rows)} drives):\n  {_summary(rows)}", flush=True)
        for side in ("correlation", "chosen"):
            print(f"# {kind} {side} latency std coverage: {coverage(rows, side)}", flush=True)
    for side in ("correlation", "chosen"):
        print(f"# all kinds, {side} latency std coverage: {coverage(every, side)}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Moving-base diagnosis with GNSS aiding: F0 in motion and the accelerometer fit.

Inputs: the IMU samples (raw, certificate units), the certificate and a GNSS
track. Steps:

1. GNSS specific force over epochs of ``interval_s`` (:func:`.gnss_epochs`,
   gated on the GNSS side only); the IMU's certificate-corrected mean over the
   same epochs, rotated to mid-epoch with the gyros and moved to the antenna
   by the lever arm (:func:`.imu_epochs`), shifted by the GNSS latency
   (estimated by :func:`.estimate_latency` unless configured). The estimate's
   std (s) is propagated: each epoch's |f| gains a std of latency std x |d|f|/dt|
   (:func:`.latency_sigma`), so a poorly known latency widens the checks; an
   estimate whose std exceeds ``latency_tolerance_s`` is reported undetermined
   and used anyway with its std (:func:`.used_latency`).
2. F0 in motion per epoch, ``F0 = 1/2 (|f_imu|^2 / |f_gnss|^2 - 1)``, failed
   when ``|F0| > limits.f0 + k_sigma * sigma_F0`` with ``sigma_F0`` propagated
   from both sides (IMU white noise of the epoch mean, GNSS velocity noise,
   the latency's uncertainty): the certificate's limit plus the noise of this
   epoch, not a fixed number.
3. Sliding windows of ``window_s`` (step ``step_s``): the exact scalar fit of
   the accelerometer triad (:func:`~imudiag.diagnosis.scalar_fit.exact_fit`)
   on the epoch means with the GNSS magnitude of each epoch; the variance of a
   mean adds the GNSS magnitude's variance (converted to output units) to the
   IMU's, to first order. Parameters the drive did not excite keep the
   certificate's prior and are reported undetermined with the reason and the
   specific force each axis saw. Faults: the statistical predicates with
   persistence over windows (:class:`~imudiag.diagnosis.predicates.PredicateTracker`).

4. The gyros in turns (``gyro_turns``, :mod:`.course_rate`): for a land vehicle
   under the no-slip assumption, |omega| from the GNSS course rate, a gyro F0 in
   turns and the bias and scale factor of the axes the turns excite. The full
   9-parameter gyro fit is not done in motion (``gyro``); the static path covers
   the gyros at stops.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from ..certificate import Certificate, TriadModel
from ..diagnosis.params import CAUSES, cause_unit, sensor_of, triad_form
from ..diagnosis.scalar_fit import exact_fit
from ..quasistatic import BAD_FLAGS
from ..samples import SampleBlock
from .align import (
    LATENCY_TOLERANCE_S,
    LatencyEstimate,
    estimate_latency,
    latency_sigma,
    used_latency,
)
from .course_rate import turn_check
from .isolation import IsolationTracker
from .joint import choose, separate_latency_std, solve_latency_lever
from .lever_arm import LeverArmEstimate, lever_arm_rows, row_noise_variance, solve_lever_arm
from .onset import isolate_window
from .specific_force import GateConfig, GnssEpochs, ImuEpochs, ImuSeries, gnss_epochs
from .tpv import GnssTrack


@dataclass
class MovingConfig:
    """Options of the moving-base diagnosis (units in the names)."""

    interval_s: float = 1.0  #: GNSS epoch length used (whole GNSS periods)
    latency_s: float | None = None  #: None: estimate it
    max_latency_s: float = 0.5  #: search range of the estimate, s
    #: the estimated latency is determined when its std is at most this, s
    latency_tolerance_s: float = LATENCY_TOLERANCE_S
    #: IMU -> antenna, body, m; None: estimated from the turns (:mod:`.lever_arm`) and
    #: used on the axes it determines
    lever_arm_m: tuple[float, float, float] | None = None
    window_s: float = 180.0  #: fit window, s
    step_s: float = 60.0  #: fit window step, s
    min_epochs: int = 60  #: valid epochs a window needs
    #: valid epochs after a fault onset inside a window (:mod:`.onset`) for the window to
    #: be judged on them; with fewer it is withheld
    min_epochs_after_onset: int = 30
    k_sigma_f0: float = 3.0  #: F0 threshold: limit + k sigma
    k_sigma: float = 4.0  #: fault predicates: beyond the limit and k std
    persist: int = 2  #: consecutive windows a fault must persist
    prior_factor: float = 10.0  #: prior std at the certificate, limits
    determined_std_ratio: float = 0.5  #: determined when std <= ratio x limit
    min_dof: float = 3.0


def accel_noise(raw: np.ndarray, certificate_sigma: np.ndarray | None) -> np.ndarray:
    """Per-sample white noise (3,), output units: the larger of the certificate's and the
    one measured from the data (median absolute second difference / 0.6745 / sqrt(6)),
    since a vehicle's vibration often far exceeds a data sheet's noise."""
    raw = np.asarray(raw, dtype=float)
    measured = (
        np.median(np.abs(np.diff(raw, 2, axis=0)), axis=0) / 0.6745 / np.sqrt(6.0)
        if raw.shape[0] > 10
        else np.zeros(3)
    )
    cert = certificate_sigma if certificate_sigma is not None else np.zeros(3)
    return np.maximum(measured, cert)


def gyro_noise_si(gyro_raw: np.ndarray, gyro: TriadModel, rate_hz: float) -> np.ndarray:
    """Per-sample gyro white noise (3,), rad/s: :func:`accel_noise` of the raw gyro outputs
    (the larger of the certificate's and the measured one) in SI."""
    return accel_noise(gyro_raw, gyro.noise_sigma(rate_hz)) / gyro.scale_factor * gyro.unit_to_si


def epoch_observations(
    ep: GnssEpochs,
    im: ImuEpochs,
    acc: TriadModel,
    sig_raw: np.ndarray,
    sigma_latency_mag: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(means (K, 3) output units, their variances (K, 3), magnitudes (K,) input units)
    of the epochs for the scalar fit: the rotation/lever terms go from SI to output
    units to first order (U = B + S N x); a mean's variance adds the GNSS magnitude's
    variance (converted) to the IMU's white noise over the epoch, and the latency's
    ``sigma_latency_mag`` (K,) m/s^2 (:func:`.latency_sigma`) likewise."""
    s = acc.scale_factor
    unit = acc.unit_to_si
    means = im.mean_raw + im.comp_si / unit * s
    var_imu = sig_raw**2 / np.maximum(im.count, 1)[:, None]
    mag_var = ep.sigma_mag**2
    if sigma_latency_mag is not None:
        mag_var = mag_var + np.asarray(sigma_latency_mag, dtype=float) ** 2
    var_gnss = (mag_var / unit**2)[:, None] * s**2
    return means, var_imu + var_gnss, ep.mag / unit


def _excitation(mean_si: np.ndarray, names: tuple[str, ...]) -> dict[str, dict[str, float]]:
    """Range of the specific force along each body axis over the epochs, m/s^2."""
    out = {}
    for c, n in enumerate(names):
        x = mean_si[:, c]
        out[n] = {"min_m_s2": round(float(np.min(x)), 3), "max_m_s2": round(float(np.max(x)), 3)}
    return out


def moving_base_diagnosis(
    block: SampleBlock,
    cert: Certificate,
    track: GnssTrack,
    cfg: MovingConfig | None = None,
    gate: GateConfig | None = None,
    rate_hz: float | None = None,
) -> dict:
    """The ``moving_base`` section of the diagnosis report (module doc). Samples flagged
    unusable (:data:`~imudiag.quasistatic.BAD_FLAGS`: saturation, ADC error, self-test)
    are left out of every step, as the monitor and the window diagnosis leave them out;
    how many is ``gnss.flagged_samples`` (only when there are any)."""
    cfg = cfg or MovingConfig()
    all_samples = len(block)
    block = block.without_flags(BAD_FLAGS)
    acc, gyr = cert.accel, cert.gyro
    t = block.t
    rate = rate_hz or (1.0 / float(np.median(np.diff(t))) if len(t) > 1 else 100.0)
    f_si = acc.inverse_si(block.accel)
    w_si = gyr.inverse_si(block.gyro)
    period = track.period_s()
    span = max(1, int(round(cfg.interval_s / period))) if math.isfinite(period) else 1
    ep = gnss_epochs(track, gate, span=span)
    in_imu = (ep.t1 >= t[0]) & (ep.t0 <= t[-1])
    ep = ep.select(in_imu)
    report: dict = {
        "gnss": {
            "device": track.device,
            "fixes": len(track),
            "period_s": round(period, 4) if math.isfinite(period) else None,
            "epoch_s": round(ep.period_s, 4) if math.isfinite(ep.period_s) else None,
            "epochs": len(ep),
            "valid": int(np.sum(ep.valid)),
            "rejected": ep.counts,
            "lever_arm_m": list(cfg.lever_arm_m or (0.0, 0.0, 0.0)),
        },
        "gyro": {
            "determined": False,
            "reason": "the 9 gyro parameters are not fitted in motion; the turns check the "
            "gyro magnitude against the GNSS course rate (gyro_turns, no-slip assumption) and "
            "the static path checks the gyros at stops",
        },
    }
    if len(block) < all_samples:
        report["gnss"]["flagged_samples"] = all_samples - len(block)
    if not np.any(ep.valid):
        report["verdict"] = "unknown"
        report["reason"] = "no valid GNSS epoch over the IMU record"
        return report
    series = ImuSeries(t, f_si, w_si)  # cut at many latencies below: made once
    if cfg.latency_s is None:
        lat = estimate_latency(
            t, f_si, ep, gyro_si=w_si, max_latency_s=cfg.max_latency_s,
            max_std_s=cfg.latency_tolerance_s, series=series,
        )  # fmt: skip
        latency, latency_std = used_latency(lat, cfg.max_latency_s)
        report["gnss"]["latency"] = dict(
            lat.to_json(), used_s=round(latency, 4), used_std_s=round(latency_std, 4)
        )
    else:
        latency, latency_std = float(cfg.latency_s), 0.0
        lat = LatencyEstimate(latency, math.nan, True, "configured", 0, std_s=0.0)
        report["gnss"]["latency"] = dict(lat.to_json(), used_s=latency, used_std_s=0.0)
    sig_raw = accel_noise(block.accel, acc.noise_sigma(rate))
    sig_si = sig_raw / acc.scale_factor * acc.unit_to_si
    plain = series.epochs(
        ep.t0, ep.t1, accel_raw=block.accel, sigma_sample_si=sig_si, latency_s=latency
    )
    gyro_sig_si = gyro_noise_si(block.gyro, gyr, rate)  # once: lever rows, joint, turns
    est = estimate_lever_arm(t, w_si, gyro_sig_si, ep, plain, latency, rate, series)
    if cfg.latency_s is None and cfg.lever_arm_m is None and math.isfinite(lat.std_s):
        latency, est, joint = solve_jointly(
            t, f_si, w_si, gyro_sig_si, ep, sig_si, rate, latency, est, cfg.max_latency_s,
            lat.determined, series=series,
        )  # fmt: skip
        if joint["used"]:
            latency_std = float(joint["latency_std_s"])
        elif lat.determined:
            latency_std = separate_latency_std(joint, latency, latency_std)
            if latency_std > cfg.latency_tolerance_s:
                report["gnss"]["latency"].update(
                    determined=False,
                    reason=f"the latency solved with the lever arm, {joint['latency_s']:.3f} s, "
                    f"is {1e3 * latency_std:.0f} ms from it (above the "
                    f"{1e3 * cfg.latency_tolerance_s:g} ms tolerance): a lever arm left out "
                    "pulls the correlation's peak",
                )
        report["gnss"]["latency"]["used_s"] = round(latency, 4)
        report["gnss"]["latency"]["used_std_s"] = round(latency_std, 4)
        report["gnss"]["latency_lever"] = joint
    lever = est.used() if cfg.lever_arm_m is None else np.asarray(cfg.lever_arm_m, float)
    report["gnss"]["lever_arm_m"] = [round(float(x), 3) for x in lever]
    report["gnss"]["lever_arm"] = dict(
        est.to_json(),
        configured=cfg.lever_arm_m is not None,
        used_m=[round(float(x), 3) for x in lever],
    )
    im = series.epochs(
        ep.t0,
        ep.t1,
        accel_raw=block.accel,
        sigma_sample_si=sig_si,
        latency_s=latency,
        lever_arm_m=lever,
    )
    use = ep.valid & im.covered & np.isfinite(im.mag)
    report["gnss"]["used"] = int(np.sum(use))
    sig_lat = latency_sigma(0.5 * (ep.t0 + ep.t1), im.mag, latency_std)
    report["f0"] = _f0_in_motion(ep, im, use, acc.limits.f0, cfg.k_sigma_f0, sig_lat)
    report["accel_noise_per_sample"] = [float(x) for x in sig_raw]
    report["gyro_turns"] = turn_check(
        track, ep, im, gyr, gyro_sig_si,
        k_sigma_f0=cfg.k_sigma_f0, k_sigma=cfg.k_sigma, prior_factor=cfg.prior_factor,
        determined_std_ratio=cfg.determined_std_ratio, gate=gate,
    )  # fmt: skip
    report.update(_windows(ep, im, use, cert, cfg, sig_raw, sig_lat))
    return report


def estimate_lever_arm(
    t: np.ndarray,
    w_si: np.ndarray,
    gyro_sigma_si: np.ndarray,
    ep: GnssEpochs,
    plain: ImuEpochs,
    latency_s: float,
    rate_hz: float,
    series: ImuSeries | None = None,
) -> LeverArmEstimate:
    """The lever arm from the epochs' |f| mismatch (:mod:`.lever_arm`): ``plain`` the IMU
    epochs without a lever arm; ``gyro_sigma_si`` (3,) the gyro noise, rad/s per sample
    (:func:`gyro_noise_si`: the larger of the certificate's and the measured one);
    ``series`` the record made once, when the caller has it."""
    use = ep.valid & plain.covered & np.isfinite(plain.mag)
    rows = lever_arm_rows(t, w_si, ep.t0, ep.t1, plain.mean_si, latency_s, series=series)
    rv = lever_row_noise(gyro_sigma_si, ep, rate_hz)
    with np.errstate(invalid="ignore", divide="ignore"):
        u = plain.mean_si / plain.mag[:, None]
    return solve_lever_arm(
        rows[use],
        (ep.mag - plain.mag)[use],
        (ep.sigma_mag**2 + plain.sigma_mag**2)[use],
        u[use],
        rv,
    )


def lever_row_noise(gyro_sigma_si: np.ndarray, ep: GnssEpochs, rate_hz: float) -> float:
    """Variance (rad/s^2)^2 per axis of the lever-arm rows' angular acceleration
    (:func:`.lever_arm.row_noise_variance`) from the gyro noise ``gyro_sigma_si`` (3,),
    rad/s per sample (:func:`gyro_noise_si`)."""
    sig = gyro_sigma_si
    epoch_s = float(np.median(ep.t1 - ep.t0)) if len(ep) else 1.0
    return row_noise_variance(float(np.max(sig)), rate_hz * epoch_s, epoch_s)


def solve_jointly(
    t: np.ndarray,
    f_si: np.ndarray,
    w_si: np.ndarray,
    gyro_sigma_si: np.ndarray,
    ep: GnssEpochs,
    sig_si: np.ndarray,
    rate_hz: float,
    latency_s: float,
    lever: LeverArmEstimate,
    max_latency_s: float,
    latency_determined: bool = True,
    series: ImuSeries | None = None,
) -> tuple[float, LeverArmEstimate, dict]:
    """Latency and lever arm solved together from the separate ``latency_s`` (s) and
    ``lever`` (:mod:`.joint`): (latency, lever estimate, report), the joint ones where
    they are well determined, else the separate ones; ``gyro_sigma_si`` (3,) the gyro
    noise, rad/s per sample, ``sig_si`` (3,) the accelerometers', m/s^2 per sample."""
    joint = solve_latency_lever(
        t, f_si, w_si, ep, latency_s, sigma_sample_si=sig_si,
        row_noise_var=lever_row_noise(gyro_sigma_si, ep, rate_hz), max_latency_s=max_latency_s,
        series=series,
    )  # fmt: skip
    return choose(joint, latency_s, lever, latency_determined)


def _f0_in_motion(
    ep: GnssEpochs, im: ImuEpochs, use: np.ndarray, limit: float, k: float, sig_lat: np.ndarray
) -> dict:
    g, i = ep.mag[use], im.mag[use]
    f0 = 0.5 * (i * i / (g * g) - 1.0)
    mag_var = im.sigma_mag[use] ** 2 + ep.sigma_mag[use] ** 2 + sig_lat[use] ** 2
    sigma = np.sqrt(mag_var) * i / (g * g)
    thr = limit + k * sigma
    failed = np.abs(f0) > thr
    moving = ep.speed[use] > 0.5
    return {
        "checked": int(f0.size),
        "failed": int(np.sum(failed)),
        "checked_moving": int(np.sum(moving)),
        "failed_moving": int(np.sum(failed & moving)),
        "threshold_median": round(float(np.median(thr)), 6) if f0.size else None,
        "sigma_median": round(float(np.median(sigma)), 6) if f0.size else None,
        "f0_median": round(float(np.median(f0)), 6) if f0.size else None,
    }


def _windows(
    ep: GnssEpochs,
    im: ImuEpochs,
    use: np.ndarray,
    cert: Certificate,
    cfg: MovingConfig,
    sig_raw: np.ndarray,
    sig_lat: np.ndarray,
) -> dict:
    """The sliding windows' fits and isolation; ``sig_raw`` (3,) the accelerometers' white
    noise per sample (raw units), ``sig_lat`` (K,) the epochs' |f| std from the latency's
    (m/s^2)."""
    acc = cert.accel
    form = triad_form(acc)  # the certificate's internal form, once for every window's fits
    means, var, mag_in = epoch_observations(ep, im, acc, sig_raw, sig_lat)
    tracker = IsolationTracker(persist=cfg.persist)
    t_mid = 0.5 * (ep.t0 + ep.t1)
    windows = []
    determined_any = np.zeros(9, dtype=bool)
    last_fit = None
    last_reason = [""] * 9
    alone = np.zeros(9, dtype=bool)
    last_iso = None
    if np.any(use):
        start = float(t_mid[use][0])
        end = float(t_mid[use][-1])
        w0 = start
        while True:
            w1 = w0 + cfg.window_s
            sel = use & (t_mid >= w0) & (t_mid < w1)
            if np.sum(sel) >= cfg.min_epochs:
                # a fault onset inside the window: only the epochs after it (.onset)
                win = np.flatnonzero(sel)
                wi = isolate_window(
                    form, means[win], var[win], mag_in[win], t_mid[win], cfg.min_epochs_after_onset,
                    k_sigma=cfg.k_sigma, prior_factor=cfg.prior_factor,
                )  # fmt: skip
                sel = np.zeros_like(sel)
                sel[win[wi.first :] if wi.iso is not None else win] = True
                fit = exact_fit(
                    form,
                    means[sel],
                    var[sel],
                    mag_in[sel],
                    prior_factor=cfg.prior_factor,
                    determined_std_ratio=cfg.determined_std_ratio,
                    method="moving-gnss",
                )
                fit.require_redundancy(
                    fit.dof, cfg.min_dof, range(9), "the window's epochs fit exactly"
                )
                iso = wi.iso
                # a withheld window is not judged: it neither raises nor breaks a streak
                cands = tracker.update(iso, min(w1, end)) if iso is not None else []
                determined_any |= fit.determined
                last_fit = fit
                last_reason = fit.reasons
                if iso is not None:
                    alone |= iso.alone_std <= cfg.determined_std_ratio * iso.limit
                    last_iso = iso
                windows.append(
                    {
                        "t_start": round(w0, 3),
                        "t_end": round(min(w1, end), 3),
                        "epochs": int(np.sum(sel)),
                        "onset": wi.to_json(),
                        "excitation": _excitation(im.mean_si[sel], ("ax", "ay", "az")),
                        "accel": fit.to_json(),
                        "candidates": cands,
                        "findings": [
                            {
                                "group": [f"{sensor_of('accel', j)} {CAUSES[j]}" for j in f.group],
                                "deviation": [float(f.deviation[j]) for j in f.group],
                                "std": [float(f.std[j]) for j in f.group],
                                "chi2_drop": round(float(f.chi2_drop[f.best]), 2),
                                "fault": f.fault,
                            }
                            for f in (iso.findings if iso is not None else [])
                        ],
                    }
                )
            if w1 >= end:
                break
            w0 += cfg.step_s
    faults = tracker.raised
    for fault in faults:
        if fault["named"]:
            fault["unit"] = cause_unit(acc, fault["cause"])
    units = form.units
    findings = _aggregate_findings(
        windows, cfg.persist, {f"{sensor_of('accel', j)} {CAUSES[j]}": units[j] for j in range(9)}
    )
    undetermined = []
    excite = _excitation(im.mean_si[use], ("ax", "ay", "az")) if np.any(use) else {}
    for i in range(9):
        if determined_any[i]:
            continue
        if last_fit is None or last_iso is None:
            why = "no window with enough GNSS epochs"
        else:
            why = f"with all 9 free, {last_reason[i]}"
            conf = last_iso.confused_with(i)
            if not alone[i]:
                why = f"the drive did not excite it ({why})"
            elif conf:
                why = (
                    f"alone it is observable (std {last_iso.alone_std[i]:.3g} {units[i]}), "
                    f"but its trace in |f| is that of {', '.join(conf)} on this drive ({why})"
                )
        undetermined.append(
            {
                "triad": "accel",
                "sensor": sensor_of("accel", i),
                "cause": CAUSES[i],
                "reason": why,
                "observable_alone": bool(alone[i]),
            }
        )
    determined = [
        {"triad": "accel", "sensor": sensor_of("accel", i), "cause": CAUSES[i]}
        for i in range(9)
        if determined_any[i]
    ]
    verdict = "fault" if faults else ("ok" if windows else "unknown")
    return {
        "config": {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(cfg).items()},
        "windows_run": len(windows),
        "windows": windows,
        "excitation": excite,
        "determined": determined,
        "undetermined": undetermined,
        "faults": faults,
        "findings": findings,
        "verdict": verdict,
    }


def _aggregate_findings(windows: list[dict], persist: int, units: dict[str, str]) -> list[dict]:
    """Findings seen in at least ``persist`` windows, grouped by their parameter group,
    with the median deviation of each member and whether they were faults; ``units`` the
    unit of each parameter name (``"az bias"``), for the text."""
    groups: dict[tuple[str, ...], list[dict]] = {}
    for w in windows:
        for f in w["findings"]:
            groups.setdefault(tuple(f["group"]), []).append(f)
    out = []
    for key, items in groups.items():
        if len(items) < persist:
            continue
        dev = np.median(np.array([f["deviation"] for f in items]), axis=0)
        std = np.median(np.array([f["std"] for f in items]), axis=0)
        faults = sum(1 for f in items if f["fault"])
        alts = " or ".join(
            f"{name} {d:+.4g} {units[name]} (std {s:.2g} {units[name]})"
            for name, d, s in zip(key, dev, std, strict=True)
        )
        text = f"{alts}, in {len(items)} of {len(windows)} windows"
        if not faults:
            text += "; not a fault: one of these explains it within its limit"
        out.append(
            {
                "group": list(key),
                "deviation": [float(x) for x in dev],
                "std": [float(x) for x in std],
                "windows": len(items),
                "fault_windows": faults,
                "fault": faults >= persist,
                "text": text,
            }
        )
    return out


__all__ = [
    "MovingConfig",
    "accel_noise",
    "epoch_observations",
    "estimate_lever_arm",
    "gyro_noise_si",
    "lever_row_noise",
    "solve_jointly",
    "moving_base_diagnosis",
]

"""The gyro magnitude in turns from the GNSS course rate (land vehicles, no slip).

GNSS velocity gives the course chi = atan2(v_E, v_N) (rad), defined above a
speed floor. Over an epoch [t0, t1] the course rate is the unwrapped course
change over dt (rad/s), and its noise from the cross-track velocity noise,
sigma_chi' = sqrt(s0^2 / v0^2 + s1^2 / v1^2) / dt ~ sigma_v sqrt(2) / (v dt).

**No-slip assumption** (stated in every report): a land vehicle on the road
surface moves along its own forward axis, so its heading rate is the course
rate. The vehicle's rate over the Earth is then (0, 0, chi') in NED to first
order when the pitch and roll rates are small (a level-ish road: on a slope
or a bank |omega_nb| is still |chi'| to first order); the gyros also sense the
Earth rate and the transport rate, both added in NED (7.3e-5 rad/s and
v / R ~ 5e-6 rad/s at 30 m/s, small against a turn):

    |omega_ref| = |(0, 0, chi') + Omega_ie + omega_en|   (rad/s)

is the |omega| the certificate-corrected gyros must read, averaged over the
same epoch shifted by the GNSS latency (:func:`.imu_epochs`).

**The no-slip test.** With the velocity along the body forward axis x_b, the
specific force along it is frame-invariant: f_b . x_b = f_n . v_n / |v_n|
(the GNSS side includes gravity along the grade). x_b (the IMU's mounting in
the vehicle) is fitted by least squares over the moving epochs; a slip angle
beta turns x_b away from the velocity and moves f_b . x_b by about
-beta a_lat, so an epoch passes when its residual is within ``k_sigma_slip``
robust sigmas of the residuals plus ``slip_allowance_rad`` x a_lat. The test
bounds the slip angle; the yaw-rate error is its rate of change, which stays
small while the slip angle stays within the allowance over the epoch.

Epochs are used where the GNSS epoch is valid (the quality gate of
:mod:`.specific_force`, including the stated speed accuracy eps), the speed
is above the floor at both ends, the turn rate is above ``min_rate_rad_s``
and ``min_rate_sigmas`` times its noise, the horizontal acceleration is below
``max_horizontal_acc_m_s2`` (hard manoeuvres) and the no-slip test holds, in
the epoch and next to it (a run of epochs beside one that slipped or was a
hard manoeuvre is dropped whole: ``slip_in_turn``).

**Gyro F0 in turns** per used epoch: F0 = 1/2 (|omega_imu|^2 / |omega_ref|^2 - 1)
fails when |F0| > limit + k sigma_F0, the limit being the larger of the
certificate's gyro F0 limit and what the bias and scale-factor limits allow at
this rate (e_max + b_max / |omega_ref|), sigma_F0 propagated from the gyro
white noise of the epoch mean, the course-rate noise and a residual latency
of ``latency_tolerance_s`` times the rate's change.

**Scale factor and bias in turns**: to first order
|omega_imu| - |omega_ref| = sum_j (e_j omega_j^2 + b_j omega_j) / |omega| with
e_j the relative scale-factor error and b_j the bias (rad/s) of gyro j; a
weighted least-squares fit of the 6 with a prior at the certificate
(``prior_factor`` limits). On a level road the turns excite the vertical gyro
only: the other axes' parameters stay undetermined ("the turns did not excite
it"); misalignments enter |omega| at second order for turns about one axis and
are never estimated here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..certificate import TriadModel
from ..diagnosis.params import cause_unit, sensor_of
from ..earth import earth_rate_ned, transport_rate_ned
from .specific_force import REASONS, GateConfig, GnssEpochs, ImuEpochs, velocity_sigma
from .tpv import GnssTrack

ASSUMPTION = (
    "no-slip assumption: a land vehicle on the road surface moves along its forward axis, so "
    "its heading rate is the GNSS course rate; pitch and roll rates small (level-ish road), so "
    "|omega| = |course rate + Earth rate + transport rate| to first order"
)

#: Reasons a moving epoch is not used by the turn check, in the order they are tested
#: (GNSS gate reasons of :mod:`.specific_force` come first, as they are).
TURN_REASONS = ("slow", "imu", "straight", "hard_manoeuvre", "slip", "slip_in_turn")

#: The 6 parameters of the fit: biases then scale-factor errors, certificate units.
FIT_CAUSES = ("bias",) * 3 + ("scale_factor",) * 3


@dataclass
class CourseConfig:
    """Options of the turn check (units in the names)."""

    min_speed_m_s: float = 3.0  #: course undefined below: both ends of an epoch above it
    min_rate_rad_s: float = 0.02  #: a turn (1.15 deg/s: highway curves reach 2 deg/s)
    min_rate_sigmas: float = 5.0  #: and above this many course-rate noise std
    max_horizontal_acc_m_s2: float = 4.0  #: harder manoeuvres are rejected (0.4 g)
    slip_allowance_rad: float = 0.035  #: slip angle (2 deg) the no-slip test lets through
    k_sigma_slip: float = 3.0  #: no-slip test: residual within k robust sigmas + allowance
    latency_tolerance_s: float = 0.02  #: residual GNSS latency error, s
    min_fit_epochs: int = 10  #: used epochs the scale/bias fit needs
    #: F0 in turns is a fault when k of n consecutive turns fail
    f0_persist_turns: tuple[int, int] = (3, 5)
    forward_norm_tolerance: float = 0.2  #: |x_b| fitted must be 1 within this
    #: m/s^2: epochs with less lateral acceleration (v |course rate|) fit the forward axis
    straight_max_lat_m_s2: float = 0.3


@dataclass
class CourseEpochs:
    """The GNSS course over K epochs: rate (K,) rad/s (meaningful where the epoch is valid
    and speed_min well above 0), sigma_rate (K,) rad/s, ref_rate (K,) rad/s |omega_ref|,
    speed_min (K,) m/s the lowest horizontal speed of the epoch's fixes, v_dir (K, 3) unit
    mid-epoch velocity (NED), a_h (K,) m/s^2 horizontal acceleration."""

    rate: np.ndarray
    sigma_rate: np.ndarray
    ref_rate: np.ndarray
    speed_min: np.ndarray
    v_dir: np.ndarray
    a_h: np.ndarray


def course_epochs(track: GnssTrack, ep: GnssEpochs, gate: GateConfig | None = None) -> CourseEpochs:
    """The course rate over the epochs ``ep`` of ``track`` (module doc)."""
    gate = gate or GateConfig()
    t = track.t
    v = track.vel_ned
    s = np.clip(np.searchsorted(t, ep.t0), 0, max(len(track) - 1, 0))
    e = np.clip(np.searchsorted(t, ep.t1), 0, max(len(track) - 1, 0))
    vh = np.hypot(v[:, 0], v[:, 1])
    chi = np.arctan2(v[:, 1], v[:, 0])
    # per-pair wrapped increments, summed: the unwrapped change over an epoch of many fixes
    d = np.angle(np.exp(1j * np.diff(chi))) if len(track) > 1 else np.zeros(0)
    cum = np.concatenate([[0.0], np.cumsum(np.nan_to_num(d))])
    with np.errstate(invalid="ignore", divide="ignore"):
        dt = ep.t1 - ep.t0
        # lowest horizontal speed over the epoch's fixes (nan where a velocity is missing)
        vmin = np.array(
            [np.min(vh[a : b + 1]) if b >= a else np.nan for a, b in zip(s, e, strict=True)]
        )
        rate = (cum[e] - cum[s]) / dt
        sig = velocity_sigma(track, gate)[:, 0]
        sigma_rate = np.sqrt((sig[s] / vh[s]) ** 2 + (sig[e] / vh[e]) ** 2) / dt
        vm = 0.5 * (v[s] + v[e])
        v_dir = vm / np.linalg.norm(vm, axis=1)[:, None]
        lat = 0.5 * (track.lat_deg[s] + track.lat_deg[e])
        alt = 0.5 * (track.alt_m[s] + track.alt_m[e])
        lat = np.where(np.isfinite(lat), lat, 45.0)
        alt = np.where(np.isfinite(alt), alt, 0.0)
        w = earth_rate_ned(lat) + transport_rate_ned(lat, alt, vm)
        w[:, 2] += rate
        ref = np.linalg.norm(w, axis=1)
        acc = (v[e] - v[s]) / dt[:, None]
        a_h = np.hypot(acc[:, 0], acc[:, 1])
    return CourseEpochs(rate, sigma_rate, ref, vmin, v_dir, a_h)


@dataclass
class ForwardAxis:
    """The vehicle's forward axis in the IMU body frame, fitted (module doc)."""

    axis: np.ndarray  #: (3,) unit, body
    norm: float  #: |x| of the unconstrained fit (1 when consistent)
    sigma_m_s2: float  #: robust std of the residuals f_b . x - f_n . v, m/s^2
    epochs: int
    determined: bool
    reason: str = ""

    def to_json(self) -> dict:
        """JSON-ready record."""
        return {
            "axis_body": [round(float(x), 4) for x in self.axis],
            "norm": round(self.norm, 4) if math.isfinite(self.norm) else None,
            "residual_sigma_m_s2": round(self.sigma_m_s2, 4)
            if math.isfinite(self.sigma_m_s2)
            else None,
            "epochs": self.epochs,
            "determined": self.determined,
            "reason": self.reason,
        }


def fit_forward_axis(
    f_body: np.ndarray, f_along: np.ndarray, tolerance: float = 0.2, rcond: float = 0.02
) -> ForwardAxis:
    """Least-squares x with f_body x = f_along (m/s^2) over straight epochs, twice (the
    second without the residuals beyond 4 robust sigmas: bumps, outliers). Straight, the
    specific force spans the vertical and the forward axis only: the solution is the
    minimum-norm one, singular values below ``rcond`` times the largest dropped (the
    lateral direction). Determined when braking or grades give the second direction and
    |x| is 1 within ``tolerance``."""
    k = f_body.shape[0]
    nan = np.full(3, np.nan)
    if k < 10:
        return ForwardAxis(nan, math.nan, math.nan, k, False, f"{k} straight epochs (10 needed)")
    keep = np.ones(k, dtype=bool)
    x = nan
    sigma = math.nan
    sv = np.zeros(3)
    for _ in range(2):
        u, sv, vt = np.linalg.svd(f_body[keep], full_matrices=False)
        big = sv >= rcond * sv[0]
        x = vt[big].T @ ((u[:, big].T @ f_along[keep]) / sv[big])
        r = f_body @ x - f_along
        sigma = float(np.median(np.abs(r[keep] - np.median(r[keep]))) / 0.6745)
        keep = np.abs(r) <= 4.0 * max(sigma, 1e-6)
    norm = float(np.linalg.norm(x))
    axis = x / norm if norm > 0 else nan
    if not sv[1] >= rcond * sv[0]:
        return ForwardAxis(
            axis, norm, sigma, k, False,
            "the straight epochs did not vary the specific force along the vehicle (no "
            "braking, accelerating or grade)",
        )  # fmt: skip
    if abs(norm - 1.0) > tolerance:
        return ForwardAxis(
            axis, norm, sigma, k, False,
            f"|x| = {norm:.3f}: the specific force along the velocity is not that of a "
            "vehicle moving along one body axis",
        )  # fmt: skip
    return ForwardAxis(axis, norm, sigma, int(np.sum(keep)), True)


def turn_limit(gyro: TriadModel, ref_rate: np.ndarray) -> np.ndarray:
    """F0 limit (K,) in turns at |omega_ref| rad/s: the larger of the certificate's gyro F0
    limit and e_max + b_max / |omega_ref| (the bias and scale-factor limits at this rate)."""
    e_max = float(np.max(gyro.limits.scale_factor_error / gyro.scale_factor))
    b_max = float(np.max(gyro.limits.bias / gyro.scale_factor)) * gyro.unit_to_si
    return np.maximum(gyro.limits.f0, e_max + b_max / ref_rate)


def _spans(t0: np.ndarray, t1: np.ndarray) -> list[list[float]]:
    """Consecutive epochs merged into [start, end] spans, s."""
    out: list[list[float]] = []
    for a, b in zip(t0, t1, strict=True):
        if out and a - out[-1][1] < 1e-6:
            out[-1][1] = round(float(b), 3)
        else:
            out.append([round(float(a), 3), round(float(b), 3)])
    return out


def turn_check(
    track: GnssTrack,
    ep: GnssEpochs,
    im: ImuEpochs,
    gyro: TriadModel,
    sigma_gyro_si: np.ndarray,
    *,
    k_sigma_f0: float,
    k_sigma: float,
    prior_factor: float,
    determined_std_ratio: float,
    cfg: CourseConfig | None = None,
    gate: GateConfig | None = None,
) -> dict:
    """The ``gyro_turns`` report object (module doc). ``im`` the IMU epochs (with
    ``gyro_mean``, rad/s, certificate-corrected) over the same epochs as ``ep``;
    ``sigma_gyro_si`` (3,) rad/s per sample; the thresholds are the moving base's
    (:class:`~.moving.MovingConfig`): F0 limit + ``k_sigma_f0`` sigma, faults beyond the
    limit and ``k_sigma`` std, prior std ``prior_factor`` limits, determined at a std of
    ``determined_std_ratio`` limits."""
    cfg = cfg or CourseConfig()
    ce = course_epochs(track, ep, gate)
    out: dict = {"assumption": ASSUMPTION, "epochs": len(ep)}
    reason = np.where(ep.valid, "", ep.reason).astype(object)
    with np.errstate(invalid="ignore"):
        reason[(reason == "") & ~(ce.speed_min > cfg.min_speed_m_s)] = "slow"
        gm = im.gyro_mean if im.gyro_mean is not None else np.full((len(ep), 3), np.nan)
        w_imu = np.linalg.norm(gm, axis=1)
        reason[(reason == "") & ~(im.covered & np.isfinite(w_imu) & np.isfinite(im.mag))] = "imu"
        moving = reason == ""
        # the forward axis where the vehicle goes straight (no lateral acceleration, so
        # no slip angle): braking, accelerating and grades vary f along it
        a_lat = np.abs(ce.rate) * ce.speed_min
        fwd_in = moving & (a_lat < cfg.straight_max_lat_m_s2)
        fwd_in &= ce.a_h <= cfg.max_horizontal_acc_m_s2
        f_along = np.sum(ep.f_n * ce.v_dir, axis=1)
        fwd = fit_forward_axis(im.mean_si[fwd_in], f_along[fwd_in], cfg.forward_norm_tolerance)
        turning = np.abs(ce.rate) > np.maximum(
            cfg.min_rate_rad_s, cfg.min_rate_sigmas * ce.sigma_rate
        )
        reason[(reason == "") & ~turning] = "straight"
        reason[(reason == "") & ~(ce.a_h <= cfg.max_horizontal_acc_m_s2)] = "hard_manoeuvre"
        if fwd.determined:
            resid = im.mean_si @ fwd.axis - f_along
            slip_ok = np.abs(resid) <= cfg.k_sigma_slip * fwd.sigma_m_s2 + (
                cfg.slip_allowance_rad * a_lat
            )
            reason[(reason == "") & ~slip_ok] = "slip"
    out["min_speed_m_s"] = cfg.min_speed_m_s
    out["min_rate_deg_s"] = round(math.degrees(cfg.min_rate_rad_s), 3)
    out["forward_axis"] = fwd.to_json()
    out["slip_test"] = {
        "allowance_deg": round(math.degrees(cfg.slip_allowance_rad), 3),
        "k_sigma": cfg.k_sigma_slip,
        "applied": fwd.determined,
    }
    _drop_turns_next_to(reason, ("slip", "hard_manoeuvre"), "slip_in_turn")
    counts = {r: int(np.sum(reason == r)) for r in REASONS + TURN_REASONS if np.any(reason == r)}
    out["rejected"] = counts
    use = reason == ""
    out["used"] = int(np.sum(use))
    out["used_spans"] = _spans(ep.t0[use], ep.t1[use])
    if not fwd.determined:
        return _undetermined(
            out, f"the no-slip test cannot run: the forward axis is not found ({fwd.reason})"
        )
    if not np.any(use):
        return _undetermined(out, "no turn epoch passed the tests (speed, turn rate, no slip)")
    # noise of both sides per epoch: gyro white noise of the epoch mean, course-rate noise
    wref = ce.ref_rate[use]
    wi = w_imu[use]
    g = gm[use]
    u = g / wi[:, None]
    s_imu2 = np.sum(u * u * sigma_gyro_si**2, axis=1) / np.maximum(im.count[use], 1)
    ratio = wi / wref
    out["epoch_ratio"] = {
        "median": round(float(np.median(ratio)), 5),
        "p10": round(float(np.percentile(ratio, 10)), 5),
        "p90": round(float(np.percentile(ratio, 90)), 5),
        "text": "|omega| of the gyros over the course-rate |omega| per used epoch (a changing "
        "slip angle, of the antenna ahead of the rear axle too, moves single epochs)",
    }
    out["rate_deg_s"] = {
        "min": round(math.degrees(float(np.min(wref))), 2),
        "max": round(math.degrees(float(np.max(wref))), 2),
    }
    share = np.sum(g * g, axis=0) / np.sum(wi * wi)
    out["axes"] = {
        sensor_of("gyro", j): {
            "share_of_rate2": round(float(share[j]), 4),
            "max_deg_s": round(math.degrees(float(np.max(np.abs(g[:, j])))), 2),
        }
        for j in range(3)
    }
    # whole turns: consecutive used epochs summed, so the GNSS course noise, a latency
    # error and the slip angle count at the turn's two ends only, not at every epoch
    dt = (ep.t1 - ep.t0)[use]
    idx = np.flatnonzero(use)
    span_id = np.cumsum(np.concatenate([[1], np.abs(ep.t0[idx[1:]] - ep.t1[idx[:-1]]) > 1e-6]))
    m = int(span_id[-1])
    rows = _rows(gyro, g, wi) * dt[:, None]
    a_turn = np.stack([np.bincount(span_id - 1, rows[:, c], minlength=m) for c in range(6)], 1)
    angle = np.bincount(span_id - 1, wref * dt, minlength=m)
    angle_imu = np.bincount(span_id - 1, wi * dt, minlength=m)
    duration = np.bincount(span_id - 1, dt, minlength=m)
    first = idx[np.searchsorted(span_id, np.arange(1, m + 1))]
    last = idx[np.searchsorted(span_id, np.arange(1, m + 1), side="right") - 1]
    var_turn = (
        np.bincount(span_id - 1, s_imu2 * dt * dt, minlength=m)
        + _end_course_var(track, ep, first, last, gate)
        + (w_imu[first] ** 2 + w_imu[last] ** 2) * cfg.latency_tolerance_s**2
        + _end_slip_var(reason, first, last, cfg.slip_allowance_rad)
    )
    f0 = 0.5 * ((angle_imu / angle) ** 2 - 1.0)
    sig_f0 = np.sqrt(var_turn) * angle_imu / angle**2
    thr = turn_limit(gyro, angle / duration) + k_sigma_f0 * sig_f0
    failed = np.abs(f0) > thr
    k, n = cfg.f0_persist_turns
    runs = np.convolve(failed.astype(int), np.ones(n, dtype=int), mode="full")
    f0_fault = bool(np.max(runs) >= k)
    out["turns"] = {
        "count": m,
        "angle_deg_max": round(math.degrees(float(np.max(angle))), 1),
        "angle_deg_total": round(math.degrees(float(np.sum(angle))), 1),
        "ratio_median": round(float(np.median(angle_imu / angle)), 5),
        "ratio_total": round(float(np.sum(angle_imu) / np.sum(angle)), 5),
        "text": "per turn (consecutive used epochs): the gyro-integrated |omega| over the "
        "GNSS course change",
    }
    out["f0"] = {
        "checked": m,
        "failed": int(np.sum(failed)),
        "fault": f0_fault,
        "f0_median": round(float(np.median(f0)), 5),
        "threshold_median": round(float(np.median(thr)), 5),
        "sigma_median": round(float(np.median(sig_f0)), 5),
        "persist": f"{k} of {n} consecutive turns",
    }
    out.update(
        _fit(
            gyro,
            a_turn,
            angle_imu - angle,
            var_turn,
            k_sigma,
            prior_factor,
            determined_std_ratio,
            cfg,
            share,
            int(np.sum(use)),
        )  # fmt: skip
    )
    faults = out["faults"]
    if f0_fault:
        faults.insert(0, {"triad": "gyro", "cause": "f0", "named": False})
    out["verdict"] = "fault" if faults else "ok"
    return out


def _undetermined(out: dict, why: str) -> dict:
    out["verdict"] = "unknown"
    out["reason"] = why
    out["determined"] = []
    out["undetermined"] = [
        {"triad": "gyro", "sensor": sensor_of("gyro", i % 3), "cause": FIT_CAUSES[i], "reason": why}
        for i in range(6)
    ]
    out["faults"] = []
    return out


def _rows(gyro: TriadModel, g: np.ndarray, wi: np.ndarray) -> np.ndarray:
    """d|omega| (rad/s) per certificate unit of the 6 parameters (K, 6), at the gyro
    rates g (K, 3) rad/s of norms wi (K,): bias count -> rate, scale count/(unit) ->
    relative (module doc)."""
    s = gyro.scale_factor
    return np.hstack([g / wi[:, None] * (gyro.unit_to_si / s), g * g / wi[:, None] / s])


def _end_course_var(
    track: GnssTrack, ep: GnssEpochs, first: np.ndarray, last: np.ndarray, gate: GateConfig | None
) -> np.ndarray:
    """Variance (rad^2) of the course change from the start of epochs ``first`` to the end
    of epochs ``last``: the cross-track velocity noise over the speed at the two ends."""
    sig = velocity_sigma(track, gate or GateConfig())[:, 0]
    vh = np.hypot(track.vel_ned[:, 0], track.vel_ned[:, 1])
    s = np.searchsorted(track.t, ep.t0[first])
    e = np.searchsorted(track.t, ep.t1[last])
    return (sig[s] / vh[s]) ** 2 + (sig[e] / vh[e]) ** 2


def _drop_turns_next_to(reason: np.ndarray, bad: tuple[str, ...], why: str) -> None:
    """Mark (in place, as ``why``) every run of usable epochs next to an epoch rejected for
    one of ``bad``: the slip angle at that end of the turn is unknown."""
    k = reason.shape[0]
    ok = reason == ""
    i = 0
    while i < k:
        if not ok[i]:
            i += 1
            continue
        j = i
        while j + 1 < k and ok[j + 1]:
            j += 1
        if (i > 0 and reason[i - 1] in bad) or (j + 1 < k and reason[j + 1] in bad):
            reason[i : j + 1] = why
        i = j + 1


def _end_slip_var(
    reason: np.ndarray, first: np.ndarray, last: np.ndarray, allowance_rad: float
) -> np.ndarray:
    """Variance (rad^2) of the slip angle at a turn's ends: none where the epoch beyond the
    end is straight (no lateral acceleration, no slip), else uniform within the allowance."""
    k = reason.shape[0]
    out = np.zeros(first.shape[0])
    for ends, step in ((first, -1), (last, 1)):
        nb = ends + step
        inside = (nb >= 0) & (nb < k)
        straight = np.zeros(ends.shape[0], dtype=bool)
        straight[inside] = reason[nb[inside]] == "straight"
        out += np.where(straight, 0.0, allowance_rad**2 / 3.0)
    return out


def _fit(
    gyro: TriadModel,
    a: np.ndarray,
    y: np.ndarray,
    var: np.ndarray,
    k_sigma: float,
    prior_factor: float,
    ratio: float,
    cfg: CourseConfig,
    share: np.ndarray,
    n_epochs: int,
) -> dict:
    """Biases and scale-factor errors of the gyros (certificate units) from the turns:
    y (M,) rad, the gyro-integrated |omega| minus the course change of each turn, rows a
    (M, 6) rad per certificate unit, variances var (M,) rad^2 (module doc)."""
    lim = np.concatenate([gyro.limits.bias, gyro.limits.scale_factor_error]).astype(float)
    w = 1.0 / var
    n_mat = a.T @ (a * w[:, None]) + np.diag(1.0 / (prior_factor * lim) ** 2)
    cov = np.linalg.inv(n_mat)
    est = cov @ (a.T @ (w * y))
    r = y - a @ est
    dof = max(len(y) - 2, 1)  # a level road: the vertical gyro's bias and scale
    chi2_dof = float(np.sum(w * r * r) / dof)
    std = np.sqrt(np.diag(cov)) * math.sqrt(max(1.0, chi2_dof))
    cert = np.concatenate([gyro.bias, gyro.scale_factor_error]).astype(float)
    enough = n_epochs >= cfg.min_fit_epochs
    determined = enough & (std <= ratio * lim)
    corr = cov / np.sqrt(np.outer(np.diag(cov), np.diag(cov)))
    det_list, undet, faults = [], [], []
    fit_json = {}
    for i in range(6):
        name = sensor_of("gyro", i % 3)
        key = f"{name} {FIT_CAUSES[i]}"
        fit_json[key] = {
            "deviation": float(est[i]),
            "std": float(std[i]),
            "limit": float(lim[i]),
            "estimate": float(cert[i] + est[i]),
            "certificate": float(cert[i]),
            "unit": cause_unit(gyro, FIT_CAUSES[i]),
        }
        if determined[i]:
            det_list.append({"triad": "gyro", "sensor": name, "cause": FIT_CAUSES[i]})
            if abs(est[i]) > lim[i] + k_sigma * std[i]:
                faults.append(
                    {
                        "triad": "gyro",
                        "sensor": name,
                        "cause": FIT_CAUSES[i],
                        "named": True,
                        "estimate": float(cert[i] + est[i]),
                        "certificate": float(cert[i]),
                        "deviation": float(est[i]),
                        "std": float(std[i]),
                        "limit": float(lim[i]),
                        "unit": cause_unit(gyro, FIT_CAUSES[i]),
                    }
                )
            continue
        if not enough:
            why = f"{n_epochs} turn epochs used ({cfg.min_fit_epochs} needed)"
        elif share[i % 3] < 0.05:
            why = (
                f"the turns did not excite it: {name} carried {100 * share[i % 3]:.1f} % of "
                "|omega|^2 in the turns used"
            )
        else:
            j = int(np.argmax(np.where(np.arange(6) == i, 0.0, np.abs(corr[i]))))
            why = (
                f"std {std[i]:.3g} against the limit {lim[i]:.3g}: its trace in |omega| is "
                f"that of {sensor_of('gyro', j % 3)} {FIT_CAUSES[j]} "
                f"(correlation {corr[i, j]:+.2f}) on this drive"
            )
        undet.append({"triad": "gyro", "sensor": name, "cause": FIT_CAUSES[i], "reason": why})
    for m in range(6, 9):
        undet.append(
            {
                "triad": "gyro",
                "sensor": sensor_of("gyro", m),
                "cause": "misalignment",
                "reason": "second order in |omega| for turns about one axis: not estimated here",
            }
        )
    return {
        "fit": {
            "parameters": fit_json,
            "chi2_dof": round(chi2_dof, 3),
            "turns": len(y),
            "epochs": n_epochs,
        },
        "determined": det_list,
        "undetermined": undet,
        "faults": faults,
    }


__all__ = [
    "ASSUMPTION",
    "TURN_REASONS",
    "CourseConfig",
    "CourseEpochs",
    "ForwardAxis",
    "course_epochs",
    "fit_forward_axis",
    "turn_check",
    "turn_limit",
]

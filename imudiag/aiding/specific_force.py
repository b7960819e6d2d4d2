"""Specific force per GNSS epoch, from GNSS velocities and from the IMU.

GNSS side (navigation frame NED, no attitude needed). Between two GNSS
velocities v_k, v_{k+1} at t_k, t_{k+1} (dt = t_{k+1} - t_k):

    f_n = (v_{k+1} - v_k) / dt - g_n + (2 Omega_ie + omega_en) x v_mid

is the mean specific force at the antenna over the epoch (exact for the
first term when the velocities are instantaneous, Doppler-derived ones are);
g_n = (0, 0, gamma(lat, h)) is WGS-84 normal gravity (:mod:`.earth`),
evaluated with the Coriolis and transport terms at the epoch's mid point.

Noise: with per-axis velocity standard deviations s_k (horizontal from gpsd's
``eps``, vertical from ``epc``, both read as ``eps_sigmas``-sigma values),
Cov(f_n) = (S_k + S_{k+1}) / dt^2 and the magnitude's standard deviation is
sqrt(u^T Cov u) with u = f_n / |f_n| (first order). Consecutive epochs share a
velocity, so their errors correlate at -1/2.

IMU side (body frame): the mean specific force over the same epoch, shifted
by the GNSS latency (the GNSS velocity labelled t describes the motion at
IMU time t - latency). Each sample is rotated into the body frame at the
epoch's mid time with the gyro-integrated rotation before averaging, so that
|mean| matches the GNSS |mean f_n| in turns (without it the horizontal part
shrinks by about (omega dt)^2 / 24). A lever arm l (body, m, from the IMU to
the antenna) adds omega' x l + omega x (omega x l) to the IMU's specific force
to give the antenna's.

Quality gate (GNSS side only, so a sensor fault can never gate itself away):
fix mode, speed accuracy, outages (gaps longer than ``max_gap_factor`` times
the nominal period) and velocity outliers (a velocity that leaves the
straight line through its neighbours by more than ``outlier_sigmas`` times the
noise plus a jerk allowance).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..earth import coriolis_term, normal_gravity
from ..kernels import kernel
from ..rotations import skew
from .tpv import GnssTrack

#: Reasons an epoch is not used, in the order they are tested.
REASONS = ("mode", "no_velocity", "accuracy", "outage", "outlier", "imu_coverage")


@dataclass
class GateConfig:
    """Quality gate and noise model of the GNSS side."""

    min_mode: int = 3  #: 3D fix: the vertical velocity is needed
    eps_sigmas: float = 2.0  #: gpsd eps/epc read as this many sigma
    max_sigma_m_s: float = 0.5  #: m/s, largest stated speed std (eps / eps_sigmas) accepted
    default_sigma_h_m_s: float = 0.05  #: m/s, horizontal velocity std when eps is absent
    default_sigma_v_m_s: float = 0.10  #: m/s, vertical velocity std when epc is absent
    max_gap_factor: float = 1.6  #: an epoch longer than this times the period is an outage
    #: "measured": velocity noise per axis from the data (robust second differences,
    #: where a receiver's stated eps/epc are often pessimistic); "stated": from eps/epc
    velocity_noise: str = "measured"
    min_sigma_m_s: float = 0.003  #: m/s, floor of a measured velocity std
    outlier_sigmas: float = 5.0  #: outlier threshold in combined sigmas
    jerk_allowance_m_s3: float = 3.0  #: m/s^3, jerk a smooth drive may have


@dataclass
class GnssEpochs:
    """Specific force over consecutive GNSS epochs [t0, t1] (GNSS time tags), K of them.

    f_n (K, 3) m/s^2 NED; mag (K,) m/s^2; sigma_mag (K,) m/s^2; gravity (K,)
    m/s^2; speed (K,) m/s (mid); valid (K,) bool; reason (K,) str ("" when valid).
    """

    t0: np.ndarray
    t1: np.ndarray
    f_n: np.ndarray
    mag: np.ndarray
    sigma_mag: np.ndarray
    gravity: np.ndarray
    speed: np.ndarray
    valid: np.ndarray
    reason: np.ndarray
    period_s: float = float("nan")
    counts: dict = field(default_factory=dict)  #: reason -> epochs rejected

    def __len__(self) -> int:
        return int(self.t0.shape[0])

    def select(self, mask: np.ndarray) -> GnssEpochs:
        """The epochs where ``mask`` is true."""
        return GnssEpochs(
            self.t0[mask],
            self.t1[mask],
            self.f_n[mask],
            self.mag[mask],
            self.sigma_mag[mask],
            self.gravity[mask],
            self.speed[mask],
            self.valid[mask],
            self.reason[mask],
            self.period_s,
            dict(self.counts),
        )


def measured_velocity_sigma(track: GnssTrack, min_sigma: float = 0.003) -> np.ndarray:
    """Per-axis white velocity noise (3,), m/s, from the second differences of the fixes.

    For white noise s, r_k = v_k - (v_{k-1} + v_{k+1}) / 2 has variance 1.5 s^2; the
    median absolute value (robust to outliers and manoeuvres) / 0.6745 estimates its std.
    Smooth motion adds (dt^2 / 4) jerk, so the estimate errs on the high side.
    """
    v = track.vel_ned
    ok = np.all(np.isfinite(v), axis=1) & (track.mode >= 2)
    v = v[ok]
    if v.shape[0] < 5:
        return np.full(3, np.nan)
    r = v[1:-1] - 0.5 * (v[:-2] + v[2:])
    sig = np.median(np.abs(r), axis=0) / 0.6745 / np.sqrt(1.5)
    return np.maximum(sig, min_sigma)


def velocity_sigma(track: GnssTrack, gate: GateConfig) -> np.ndarray:
    """Per-axis velocity standard deviations (K, 3), m/s: measured from the data
    (``gate.velocity_noise == "measured"``), else from eps/epc or the defaults."""
    if gate.velocity_noise == "measured":
        m = measured_velocity_sigma(track, gate.min_sigma_m_s)
        if np.all(np.isfinite(m)):
            return np.broadcast_to(m, (len(track), 3)).copy()
    sh = np.where(np.isfinite(track.eps), track.eps / gate.eps_sigmas, gate.default_sigma_h_m_s)
    sv = np.where(np.isfinite(track.epc), track.epc / gate.eps_sigmas, gate.default_sigma_v_m_s)
    # gpsd eps is a speed error: read it as the std of each horizontal axis
    return np.stack([sh, sh, sv], 1)


def gnss_epochs(track: GnssTrack, gate: GateConfig | None = None, span: int = 1) -> GnssEpochs:
    """Specific force over consecutive GNSS epochs, gated (module doc).

    ``span``: GNSS periods per epoch (1: every pair of consecutive fixes). Longer
    epochs divide the velocity noise's contribution to |f| by ``span``; an epoch is
    rejected when any fix pair inside it is (the first reason is kept).
    """
    gate = gate or GateConfig()
    span = max(1, int(span))
    n = len(track)
    k = max(n - 1, 0)
    t = track.t
    v = track.vel_ned
    sig = velocity_sigma(track, gate)
    period = track.period_s()
    reason = np.full(k, "", dtype=object)

    def mark(bad_point: np.ndarray, why: str) -> None:
        bad_epoch = bad_point[:-1] | bad_point[1:]
        reason[(reason == "") & bad_epoch] = why

    mark(track.mode < gate.min_mode, "mode")
    mark(~np.all(np.isfinite(v), axis=1), "no_velocity")
    # the receiver's speed accuracy (eps); gpsd's epc is derived from the altitude error
    # over the cycle (8 m/s from a u-blox vAcc of 0.8 m at 5 Hz), not a velocity accuracy
    mark(
        np.where(np.isfinite(track.eps), track.eps / gate.eps_sigmas, 0.0) > gate.max_sigma_m_s,
        "accuracy",
    )
    dt = np.diff(t) if n else np.zeros(0)
    if k:
        gap = dt > gate.max_gap_factor * period
        reason[(reason == "") & gap] = "outage"
    # velocity outliers: distance of v_k from the line through v_{k-1}, v_{k+1}
    if n >= 3:
        w = (t[1:-1] - t[:-2]) / (t[2:] - t[:-2])
        pred = v[:-2] + (v[2:] - v[:-2]) * w[:, None]
        r = np.linalg.norm(v[1:-1] - pred, axis=1)
        span2 = t[2:] - t[:-2]
        wc = w[:, None]
        sr = np.sqrt(
            np.sum(sig[1:-1] ** 2 + (1 - wc) ** 2 * sig[:-2] ** 2 + wc**2 * sig[2:] ** 2, axis=1)
        )
        allow = gate.jerk_allowance_m_s3 * span2**2 / 8.0
        out = np.zeros(n, dtype=bool)
        ok = np.isfinite(r)
        exceed = np.zeros(n - 2, dtype=bool)
        exceed[ok] = r[ok] > gate.outlier_sigmas * sr[ok] + allow[ok]
        # a bad v_k also moves its neighbours' residuals (by half): flag the local maxima
        rr = np.where(ok, r, -np.inf)
        left = np.concatenate([[-np.inf], rr[:-1]])
        right = np.concatenate([rr[1:], [-np.inf]])
        out[1:-1] = exceed & (rr >= left) & (rr >= right)
        mark(out, "outlier")

    # epochs of ``span`` fix pairs: fixes s_idx .. e_idx
    s_idx = np.arange(0, max(k - span + 1, 0), span)
    e_idx = s_idx + span
    if span > 1:
        pair_reason = reason
        reason = np.full(s_idx.shape[0], "", dtype=object)
        for off in range(span):
            r = pair_reason[s_idx + off]
            reason[(reason == "") & (r != "")] = r[(reason == "") & (r != "")]
    kk = s_idx.shape[0]
    with np.errstate(invalid="ignore", divide="ignore"):
        dte = t[e_idx] - t[s_idx] if kk else np.zeros(0)
        safe_dt = np.where(dte > 0, dte, np.nan)
        acc = (v[e_idx] - v[s_idx]) / safe_dt[:, None] if kk else np.zeros((0, 3))
        # a missing velocity (already rejected) must not poison the later epochs' sums
        cv = np.cumsum(np.vstack([np.zeros((1, 3)), np.nan_to_num(v)]), axis=0)
        vm = (cv[e_idx + 1] - cv[s_idx]) / (span + 1) if kk else np.zeros((0, 3))
        lat = 0.5 * (track.lat_deg[s_idx] + track.lat_deg[e_idx]) if kk else np.zeros(0)
        alt = 0.5 * (track.alt_m[s_idx] + track.alt_m[e_idx]) if kk else np.zeros(0)
        lat_c = np.where(np.isfinite(lat), lat, 45.0)
        alt_c = np.where(np.isfinite(alt), alt, 0.0)
        g = normal_gravity(lat_c, alt_c)
        f_n = acc + coriolis_term(lat_c, alt_c, vm)
        f_n[:, 2] -= g
        mag = np.linalg.norm(f_n, axis=1)
        u = f_n / mag[:, None]
        cov_diag = (
            (sig[e_idx] ** 2 + sig[s_idx] ** 2) / safe_dt[:, None] ** 2 if kk else np.zeros((0, 3))
        )
        sigma_mag = np.sqrt(np.sum(u * u * cov_diag, axis=1))
    reason[(reason == "") & ~np.isfinite(mag)] = "no_velocity"
    valid = reason == ""
    counts = {r: int(np.sum(reason == r)) for r in REASONS if np.any(reason == r)}
    return GnssEpochs(
        t0=t[s_idx].copy(),
        t1=t[e_idx].copy(),
        f_n=f_n,
        mag=mag,
        sigma_mag=sigma_mag,
        gravity=g,
        speed=np.linalg.norm(vm, axis=1),
        valid=valid,
        reason=reason,
        period_s=period * span,
        counts=counts,
    )


@dataclass
class ImuEpochs:
    """The IMU over K epochs (IMU time [a, b) = GNSS [t0, t1] - latency).

    mean_si (K, 3) m/s^2 body, rotated to the mid-epoch body frame and moved
    to the antenna by the lever arm; mag (K,) m/s^2 its norm; sigma_mag (K,)
    m/s^2 from the white noise of the samples; mean_raw (K, 3) output units
    (plain means, if raw outputs were given); comp_si (K, 3) m/s^2 what the
    rotation and the lever arm added to the plain SI mean; count (K,) samples;
    covered (K,) bool: the samples span the epoch (no gap in the IMU stream).
    """

    mean_si: np.ndarray
    mag: np.ndarray
    sigma_mag: np.ndarray
    comp_si: np.ndarray
    count: np.ndarray
    covered: np.ndarray
    mean_raw: np.ndarray | None = None
    gyro_mean: np.ndarray | None = None  #: (K, 3) rad/s


def _running_integral(t: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(x[0], trapezoid integral of x - x[0] from t[0] to each t_i, components in
    contiguous rows (3, N)), for :func:`_mean_of_integral`; t (N,) s with N >= 2."""
    ref = x[0]
    xc = x - ref  # keeps the running integral small (raw counts are ~3e4)
    steps = 0.5 * (xc[1:] + xc[:-1]) * np.diff(t)[:, None]
    big = np.vstack([np.zeros((1, 3)), np.cumsum(steps, axis=0)])
    return ref, np.ascontiguousarray(big.T)  # np.interp reads a contiguous row uncopied


def _mean_of_integral(
    t: np.ndarray, ref: np.ndarray, big: np.ndarray, a: np.ndarray, b: np.ndarray
) -> np.ndarray:
    """Mean over [a, b] (K,) from a :func:`_running_integral` (rows (3, N)) of samples at
    instants t."""
    out = np.empty((a.shape[0], 3))
    for c in range(3):
        fa = np.interp(a, t, big[c])
        fb = np.interp(b, t, big[c])
        out[:, c] = (fb - fa) / (b - a)
    return out + ref


def _interval_mean(t: np.ndarray, x: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Mean over [a, b] (K,) of the samples x (N, 3) at instants t, linearly interpolated."""
    if t.shape[0] < 2:
        return np.full((a.shape[0], 3), np.nan)
    ref, big = _running_integral(t, x)
    return _mean_of_integral(t, ref, big, a, b)


def _rodrigues(theta: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Rotate vectors x (N, 3) by rotation vectors theta (N, 3), rad."""
    ang = np.linalg.norm(theta, axis=1)
    small = ang < 1e-12
    k = np.where(small[:, None], 0.0, theta / np.where(small, 1.0, ang)[:, None])
    c, s = np.cos(ang)[:, None], np.sin(ang)[:, None]
    kx = np.cross(k, x)
    kd = np.sum(k * x, axis=1)[:, None]
    return x * c + kx * s + k * kd * (1.0 - c)


def _rodrigues_rows(theta: np.ndarray, x: np.ndarray) -> np.ndarray:
    """:func:`_rodrigues` on components in rows: theta, x (3, N) contiguous, rad and any
    unit; returns (3, N). The same operations in the same order, on contiguous rows (equal
    to :func:`_rodrigues` bit for bit, tests/test_imu_series.py)."""
    a2 = theta[0] * theta[0]
    a2 += theta[1] * theta[1]
    a2 += theta[2] * theta[2]
    ang = np.sqrt(a2)  # np.linalg.norm's sum, in its order
    small = ang < 1e-12
    k = theta / np.where(small, 1.0, ang)
    k[:, small] = 0.0
    c, s = np.cos(ang), np.sin(ang)
    (k0, k1, k2), (x0, x1, x2) = k, x
    kd = k0 * x0
    kd += k1 * x1
    kd += k2 * x2
    omc = 1.0 - c
    out = np.empty_like(x)
    crosses = (k1 * x2 - k2 * x1, k2 * x0 - k0 * x2, k0 * x1 - k1 * x0)  # np.cross's terms
    for i in range(3):
        r = out[i]
        np.multiply(x[i], c, out=r)
        r += crosses[i] * s
        r += (k[i] * kd) * omc
    return out


def imu_epochs(
    t: np.ndarray,
    accel_si: np.ndarray,
    t0: np.ndarray,
    t1: np.ndarray,
    gyro_si: np.ndarray | None = None,
    accel_raw: np.ndarray | None = None,
    sigma_sample_si: np.ndarray | float = 0.0,
    latency_s: float = 0.0,
    lever_arm_m: np.ndarray | None = None,
    gyro_means: bool = True,
) -> ImuEpochs:
    """Mean IMU specific force over the GNSS epochs [t0, t1] - ``latency_s`` (see module doc).

    t (N,) s increasing; accel_si (N, 3) m/s^2 corrected; gyro_si (N, 3)
    rad/s corrected (rotation compensation and lever arm need it);
    sigma_sample_si (3,) or scalar m/s^2: white-noise std of one sample;
    ``gyro_means``: the epochs' mean rates too (``gyro_mean``; the latency search needs
    only |f|).
    """
    t = np.asarray(t, dtype=float)
    f = np.asarray(accel_si, dtype=float)
    a = np.asarray(t0, dtype=float) - latency_s
    b = np.asarray(t1, dtype=float) - latency_s
    kk = a.shape[0]
    n = t.shape[0]
    # sample i belongs to the epoch j with a_j <= t_i < b_j (epochs do not overlap)
    j = np.searchsorted(a, t, side="right") - 1
    inside = (j >= 0) & (j < kk)
    inside[inside] &= t[inside] < b[j[inside]]
    idx = np.where(inside, j, kk)  # bin kk collects the rest
    count = np.bincount(idx, minlength=kk + 1)[:kk]
    fc = f.copy()
    gyro_mean = None
    if gyro_si is not None and n > 1:
        w = np.asarray(gyro_si, dtype=float)
        dt = np.diff(t, append=t[-1] + (t[-1] - t[-2]))
        big = np.cumsum(w * dt[:, None], axis=0) - w * dt[:, None]  # integral up to t_i
        if gyro_means:
            gsum = np.stack([np.bincount(idx, w[:, c], minlength=kk + 1)[:kk] for c in range(3)], 1)
            with np.errstate(invalid="ignore", divide="ignore"):
                gyro_mean = gsum / count[:, None]
        if lever_arm_m is not None and np.any(lever_arm_m):
            lev = np.asarray(lever_arm_m, dtype=float)
            wdot = np.gradient(w, t, axis=0)
            fc = fc + np.cross(wdot, lev) + np.cross(w, np.cross(w, lev))
        # rotation vector at the epoch's mid time (interpolated), per sample of the epoch
        mid = 0.5 * (a + b)
        big_mid = np.stack([np.interp(mid, t, big[:, c]) for c in range(3)], 1)
        theta = np.zeros_like(big)
        theta[inside] = big[inside] - big_mid[j[inside]]
        # v_mid = R(mid <- t) v_t: rotation by the integral from mid to t
        fc = _rodrigues(theta, fc)
    sums = np.stack([np.bincount(idx, fc[:, c], minlength=kk + 1)[:kk] for c in range(3)], 1)
    plain = np.stack([np.bincount(idx, f[:, c], minlength=kk + 1)[:kk] for c in range(3)], 1)
    with np.errstate(invalid="ignore", divide="ignore"):
        # the mean itself as the integral of the linearly interpolated samples over [a, b]
        # (trapezoid: samples are instants, no half-sample shift)
        interval_mean = _interval_mean(t, f, a, b)
        mean_raw = None
        if accel_raw is not None:
            mean_raw = _interval_mean(t, np.asarray(accel_raw, dtype=float), a, b)
    ends = None
    if n > 1:  # each epoch's first and last sample time
        first = np.full(kk, np.inf)
        last = np.full(kk, -np.inf)
        np.minimum.at(first, idx[inside], t[inside])
        np.maximum.at(last, idx[inside], t[inside])
        ends = (first, last, float(np.median(np.diff(t))))
    return _epochs_of(
        sums, plain, count, interval_mean, sigma_sample_si, a, b, ends, mean_raw, gyro_mean
    )


def _epochs_of(
    sums: np.ndarray,
    plain: np.ndarray,
    count: np.ndarray,
    interval_mean: np.ndarray,
    sigma_sample_si: np.ndarray | float,
    a: np.ndarray,
    b: np.ndarray,
    ends: tuple[np.ndarray, np.ndarray, float] | None,
    mean_raw: np.ndarray | None,
    gyro_mean: np.ndarray | None,
) -> ImuEpochs:
    """The epochs of :func:`imu_epochs` (and :meth:`ImuSeries.epochs`) from each epoch's
    sums of the compensated and of the plain samples (K, 3), sample counts, interval means
    (K, 3, m/s^2), epoch bounds [a, b] (K,) s, and ``ends``: each epoch's first and last
    sample time (K,) s and the sample period, s (None: fewer than 2 samples)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        # the rotation and lever-arm terms from the samples of each epoch
        comp = (sums - plain) / count[:, None]
        mean = interval_mean + comp
        mag = np.linalg.norm(mean, axis=1)
        u = mean / mag[:, None]
        s2 = np.broadcast_to(np.asarray(sigma_sample_si, dtype=float) ** 2, (3,))
        sigma_mag = np.sqrt(np.sum(u * u * s2, axis=1) / count)
    # covered: samples reach both ends of the epoch within 1.5 sample periods
    if ends is not None:
        first, last, period = ends
        expected = (b - a) / period
        covered = (
            (first - a <= 1.5 * period)
            & (b - last <= 1.5 * period)
            & (count >= np.maximum(1, 0.9 * expected - 1))
        )
    else:
        covered = np.zeros(a.shape[0], dtype=bool)
    return ImuEpochs(
        mean_si=mean,
        mag=mag,
        sigma_mag=sigma_mag,
        comp_si=comp,
        count=count,
        covered=covered,
        mean_raw=mean_raw,
        gyro_mean=gyro_mean,
    )


def _binned_sums(idx: np.ndarray, rows: np.ndarray, kk: int) -> np.ndarray:
    """Sums (kk, 3) of the components in rows (3, N) per bin idx (N,) < kk (the sums of
    :func:`imu_epochs`: bincount, in sample order)."""
    return np.stack([np.bincount(idx, rows[c], minlength=kk + 1)[:kk] for c in range(3)], 1)


class ImuSeries:
    """One IMU record cut into GNSS epochs again and again (the latency search, the joint
    latency and lever-arm solve, the final epochs): :meth:`epochs` gives what
    :func:`imu_epochs` gives for the same arguments, equal to it
    (tests/test_imu_series.py), with what depends on neither the epochs nor the latency
    made once here (the gyro integral, the accelerometer's running integral, the sample
    period, the angular acceleration of the lever-arm term) and each epoch's samples taken
    as the slice of the time-ordered record between two ``searchsorted`` bounds instead
    of a search per sample. :func:`imu_epochs` stays the plain path.

    t (N,) s increasing; accel_si (N, 3) m/s^2 corrected; gyro_si (N, 3) rad/s corrected
    (None: no rotation compensation, no lever arm).
    """

    def __init__(
        self, t: np.ndarray, accel_si: np.ndarray, gyro_si: np.ndarray | None = None
    ) -> None:
        self.t = np.asarray(t, dtype=float)
        self.accel_si = np.asarray(accel_si, dtype=float)
        self.gyro_si = None if gyro_si is None else np.asarray(gyro_si, dtype=float)
        n = self.t.shape[0]
        #: s, the median sample period (nan below 2 samples)
        self.period_s = float(np.median(np.diff(self.t))) if n > 1 else math.nan
        self._accel_integral = _running_integral(self.t, self.accel_si) if n > 1 else None
        # components in contiguous rows (3, N): the per-sample work of every cut runs on them
        self._accel_rows = np.ascontiguousarray(self.accel_si.T)
        self._gyro_rows: np.ndarray | None = None
        self._gyro_integral: np.ndarray | None = None  #: (3, N) rad, up to each t_i
        self._wdot: np.ndarray | None = None
        self._centripetal: np.ndarray | None = None
        if self.gyro_si is not None:
            self._gyro_rows = np.ascontiguousarray(self.gyro_si.T)
        if self.gyro_si is not None and n > 1:
            w, t = self.gyro_si, self.t
            dt = np.diff(t, append=t[-1] + (t[-1] - t[-2]))
            big = np.cumsum(w * dt[:, None], axis=0) - w * dt[:, None]
            self._gyro_integral = np.ascontiguousarray(big.T)

    def __len__(self) -> int:
        return int(self.t.shape[0])

    def _bounds(self, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(first sample (K,), end (K,)): epoch k holds samples start_k <= i < end_k,
        a_k <= t_i < b_k, a sample in two overlapping epochs in the later one (as
        :func:`imu_epochs`)."""
        start = np.searchsorted(self.t, a, side="left")
        end = np.searchsorted(self.t, b, side="left")
        if a.shape[0] > 1:
            end[:-1] = np.minimum(end[:-1], start[1:])
        return start, np.maximum(end, start)

    @staticmethod
    def _bins(start: np.ndarray, end: np.ndarray, lo: int, hi: int) -> np.ndarray:
        """The epoch index (kk for none) of each sample lo <= i < hi, from the epochs'
        :meth:`_bounds` (lo <= start_0, end_{K-1} <= hi)."""
        kk = start.shape[0]
        bounds = np.empty(2 * kk + 2, dtype=np.intp)
        bounds[0], bounds[-1] = lo, hi
        bounds[1:-1:2], bounds[2:-1:2] = start, end
        values = np.full(2 * kk + 1, kk, dtype=np.intp)
        values[1::2] = np.arange(kk)
        return np.repeat(values, np.diff(bounds))

    def bins(
        self, t0: np.ndarray, t1: np.ndarray, latency_s: float = 0.0
    ) -> tuple[np.ndarray, int, int, np.ndarray]:
        """(epoch index of each sample lo <= i < hi, K for none; lo; hi; samples per epoch
        (K,)) of the GNSS epochs [t0, t1] - ``latency_s`` (s): the samples of every epoch
        lie in lo..hi, each in the epoch :func:`imu_epochs` puts it in."""
        a = np.asarray(t0, dtype=float) - latency_s
        b = np.asarray(t1, dtype=float) - latency_s
        start, end = self._bounds(a, b)
        lo = int(start[0]) if a.shape[0] else 0
        hi = int(end[-1]) if a.shape[0] else 0
        return self._bins(start, end, lo, hi), lo, hi, end - start

    def centripetal(self) -> np.ndarray | None:
        """[w]x [w]x per sample (N, 9, row-major 3x3), rad^2/s^2, made once (the lever-arm
        rows at every latency tried); None without gyro."""
        if self.gyro_si is None:
            return None
        if self._centripetal is None:
            sw = skew(self.gyro_si)
            self._centripetal = (sw @ sw).reshape(-1, 9)
        return self._centripetal

    def epochs(
        self,
        t0: np.ndarray,
        t1: np.ndarray,
        accel_raw: np.ndarray | None = None,
        sigma_sample_si: np.ndarray | float = 0.0,
        latency_s: float = 0.0,
        lever_arm_m: np.ndarray | None = None,
        gyro_means: bool = True,
    ) -> ImuEpochs:
        """:func:`imu_epochs` of this record over the GNSS epochs [t0, t1] - ``latency_s``.

        Only the samples from the first epoch's first to the last epoch's end are cut (the
        rest fall in no epoch). Where the compiled kernels are on (:mod:`imudiag.kernels`)
        the per-sample work (rotation vector, Rodrigues rotation, binned sums) is one
        compiled pass (:func:`imudiag.numba_kernels.epoch_cut`): the same operations in the
        same order, each bin summed in sample order as ``np.bincount`` does, so equal to
        the plain path but for the last bit of a sine or cosine where numba's libm and
        numpy's differ (tests/test_epoch_kernel.py)."""
        t, f, w = self.t, self.accel_si, self.gyro_si
        a = np.asarray(t0, dtype=float) - latency_s
        b = np.asarray(t1, dtype=float) - latency_s
        kk, n = a.shape[0], len(self)
        start, end = self._bounds(a, b)
        lo = int(start[0]) if kk else 0
        hi = int(end[-1]) if kk else 0
        count = end - start
        fc = self._accel_rows
        gyro_mean = None
        big = self._gyro_integral
        w_rows = self._gyro_rows
        rotate = w is not None and w_rows is not None and big is not None
        if rotate and lever_arm_m is not None and np.any(lever_arm_m):
            assert w is not None
            lev = np.asarray(lever_arm_m, dtype=float)
            if self._wdot is None:
                self._wdot = np.gradient(w, t, axis=0)
            lever = f + np.cross(self._wdot, lev) + np.cross(w, np.cross(w, lev))
            fc = np.ascontiguousarray(lever.T)
        big_mid = None
        if rotate:
            assert big is not None
            # rotation vector from the epoch's mid time (interpolated) to each sample
            mid = 0.5 * (a + b)
            big_mid = np.zeros((3, kk + 1))
            for c in range(3):
                big_mid[c, :kk] = np.interp(mid, t, big[c])
        cut = kernel("epoch_cut")
        if cut is not None:
            empty = np.zeros((3, 0))
            sums, plain, gsum = cut(
                self._accel_rows,
                fc,
                w_rows if rotate and w_rows is not None else empty,
                big if rotate and big is not None else empty,
                big_mid if big_mid is not None else empty,
                start.astype(np.int64),
                end.astype(np.int64),
                rotate,
                rotate and gyro_means,
            )
            if rotate and gyro_means:
                with np.errstate(invalid="ignore", divide="ignore"):
                    gyro_mean = gsum / count[:, None]
        else:
            idx = self._bins(start, end, lo, hi)
            if rotate and gyro_means and w_rows is not None:
                gsum = _binned_sums(idx, w_rows[:, lo:hi], kk)
                with np.errstate(invalid="ignore", divide="ignore"):
                    gyro_mean = gsum / count[:, None]
            if rotate and big is not None and big_mid is not None:
                theta = np.empty((3, hi - lo))
                for c in range(3):
                    np.subtract(big[c, lo:hi], big_mid[c][idx], out=theta[c])
                theta[:, idx == kk] = 0.0
                rotated = _rodrigues_rows(theta, fc[:, lo:hi])
            else:
                rotated = fc[:, lo:hi]
            sums = _binned_sums(idx, rotated, kk)
            plain = _binned_sums(idx, self._accel_rows[:, lo:hi], kk)
        with np.errstate(invalid="ignore", divide="ignore"):
            if self._accel_integral is None:
                interval_mean = np.full((kk, 3), np.nan)
            else:
                interval_mean = _mean_of_integral(t, *self._accel_integral, a, b)
            mean_raw = None
            if accel_raw is not None:
                mean_raw = _interval_mean(t, np.asarray(accel_raw, dtype=float), a, b)
        ends = None
        if n > 1:  # each epoch's first and last sample: the ends of its slice
            some = count > 0
            first = np.where(some, t[np.minimum(start, n - 1)], np.inf)
            last = np.where(some, t[np.maximum(end - 1, 0)], -np.inf)
            ends = (first, last, self.period_s)
        return _epochs_of(
            sums, plain, count, interval_mean, sigma_sample_si, a, b, ends, mean_raw, gyro_mean
        )


def noise_floor(epochs: GnssEpochs) -> float:
    """Median GNSS |f| standard deviation over valid epochs, m/s^2 (nan when none)."""
    s = epochs.sigma_mag[epochs.valid]
    return float(np.median(s)) if s.size else math.nan


__all__ = [
    "REASONS",
    "GateConfig",
    "GnssEpochs",
    "ImuEpochs",
    "ImuSeries",
    "gnss_epochs",
    "imu_epochs",
    "measured_velocity_sigma",
    "noise_floor",
    "velocity_sigma",
]

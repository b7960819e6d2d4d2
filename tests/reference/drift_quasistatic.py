"""WHY THIS FILE STAYS (issue 30 item 6): the shipped detector's speed machinery is
checked against plain definitions in ``tests/test_quasistatic_paths.py``: the window
statistics from prefix sums against sums added up window by window, the drift tests'
trailing spreads against their definition, and the whole detector on plain window sums
gives the same flags as on prefix sums (the shared detectors against separate ones:
``tests/test_shared_detector.py``). Those checks share the detector's decisions (the
variance and rate-band tests, the restarts, the drift, curve and step tests, the noise
estimate), which the per-call cost work (issue 14) rewrote too and which have no second,
plain implementation in the package: this frozen code is that second implementation,
and ``tests/test_detector_equivalence.py`` holds the shipped flags to it sample for sample.

FROZEN REFERENCE (tests only): the quasi-static detector with the moving-base drift
tests (issue 15) as it was at commit ff7f524, before its per-call cost was cut (issue 14),
with the ``PrefixSums`` of ``imudiag/trailing.py`` of that commit. Kept verbatim (imports
made absolute) so ``tests/test_detector_equivalence.py`` can check that the shipped
detector's static flags equal these, sample for sample. Do not edit.

Quasi-static detection: which samples were taken while the IMU was still.

The scalar checks need a known magnitude (gravity, Earth rate), which only
holds while the unit is still (design note §1). A sample is *static* when the
trailing window of ``window_s`` seconds that ends at it shows

- a short-window variance of each triad no larger than its white noise
  explains (the sum over the three axes of ``var_j / sigma_j^2``, a scaled
  chi-square variable, below its mean plus ``k_sigma`` standard deviations,
  and at most ``variance_factor`` times the noise), the stance detector of
  pedestrian navigation applied to both triads;
- a gyro window mean whose component about the vertical (the gravity direction
  of the accelerometer window mean, corrected with the certificate) stays within
  the bias band: at most ``bias_margin`` times the largest bias limit plus Earth
  rate plus ``k_sigma`` standard deviations of the window mean, in input units.
  A slow constant rotation about the vertical leaves both variances untouched,
  and this is the only rotation the accelerometers cannot see; a rotation about
  a horizontal axis turns gravity in the body and shows in the accelerometer
  variance. Restricting the band to the vertical keeps a gross bias fault of a
  gyro axis that is not vertical "still", so it can be diagnosed, instead of
  hiding every later check (a bias on the vertical axis is truly
  indistinguishable from a slow yaw rotation for a MEMS gyro);
- no saturation or ADC-error flag in the window;
- no drift over seconds (below): of the accelerometer window mean over the
  last ``drift_window_s``, and not the rate about the vertical together with
  the specific force over the last ``rate_drift_window_s``.

**Rest is rest without aiding.** A smooth manoeuvre of a vehicle (the peak of a
raised-cosine acceleration, a long gentle curve) has almost no jerk: over half
a second the accelerometers read a constant vector whose magnitude is not g,
which the variance test cannot tell from a tilted unit at rest, and the F0
check then fails a healthy unit. Over seconds the two differ: at rest the
specific force in the body changes only when the body rotates, so its window
mean stays put; in a smooth acceleration or curve it drifts. No test uses
|f| = g, so a scale or bias fault of any size leaves a still unit still.

- *Short drift*: the spread (per-axis max - min, as a vector norm in m/s^2) of
  the accelerometer window means kept every ``drift_step_s`` over the last
  ``drift_window_s`` must stay within ``drift_f0_fraction`` x F0 limit x g (an
  unseen acceleration of that size along gravity changes F0 by that fraction of
  its limit) plus ``k_sigma`` noise standard deviations of two window means.
- *Curve*: over ``rate_drift_window_s``, the rate about the vertical (means
  over ``rate_mean_s``) drifting beyond ``rate_drift_fraction`` of the gyro
  bias limit (plus noise) *and* the specific force drifting beyond the limit
  above: a vehicle's curve, where the lateral acceleration is speed x rate. A
  gyro fault (a bias step, a stuck output) changes the rate alone and keeps a
  still unit still.
- *Restarts*: the histories start afresh one window after the gyro rate's
  magnitude exceeded the ``bias_margin`` band (turning), or after a window
  far beyond the variance test (``restart_variance_factor`` times its limit)
  while the rate exceeded ``restart_margin`` bias limits (rotation, not
  acceleration); ``settle_s`` after a window whose accelerometer variance is
  that of gravity sweeping ``settle_angle_deg`` within it (a unit re-oriented
  by hand settles into its hold for a second or two, measured on the real
  MPU-6050 session, and the hold must not be lost); and at once at a step of
  the accelerometer mean between two still windows (a change no smooth motion
  makes: a sensor step or a knock), so a sensor fault is judged at once, as at
  rest. A restart only shortens a history, so it can only let more samples be
  still.

What it cannot tell: a constant-speed straight and level cruise (or a
constant grade) is rest for the scalar check (|f| = g exactly, so F0 is
right there); a steady turn at a constant rate about the vertical below the
band (8 bias limits) with a constant lateral acceleration looks like a unit at
rest with a vertical gyro bias; a manoeuvre whose specific force changes by
less than the drift limit over the histories (the peak of a very slow speed
change); the first ``drift_step_s`` of a history. The cost: a vehicle that
stops after braking is still only ``drift_window_s`` later.

Per-sample noise ``sigma = density * sqrt(rate / 2)`` (output units) comes
from the certificate's noise density; where the certificate has none, the
detector estimates it from the data as the low quantile of the short-window
variances seen so far (the quietest stretches are noise only).

The window is trailing, so decisions are causal: the first ``W - 1`` samples
of a stream are never static, a static stretch starts ``W - 1`` samples after
the unit stops, and motion is flagged as soon as it shows in the window.
State (the last ``W - 1`` samples, the noise estimate) carries across blocks;
inside a block everything is vectorised with cumulative sums.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from imudiag.certificate import Certificate
from imudiag.samples import (
    FLAG_ACCEL_SATURATED,
    FLAG_ADC_ERROR,
    FLAG_GYRO_SATURATED,
    FLAG_SELF_TEST,
    SampleBlock,
)


class PrefixSums:
    """Prefix sums of a stream of rows, the last ones kept in a circular buffer.

    The sum of the ``w`` rows ending at stream row ``s`` is ``P[s] - P[s - w]``
    (``P[j] = 0`` before the stream's start), so any number of trailing windows
    up to ``reach`` rows long come from one cumulative sum of each new block and
    one gather: the work per block is proportional to the block, whatever the
    windows. All stored sums are shifted back to zero every ``2**20`` rows so
    they never grow large enough to lose precision; differences are unchanged.
    Rows must be finite (callers zero non-finite values and count them in a
    column of their own).
    """

    def __init__(self, width: int, reach: int) -> None:
        if reach < 1:
            raise ValueError(f"prefix-sum reach must be >= 1 row, got {reach}")
        self.width = int(width)
        self.reach = int(reach)
        self.depth = 1 << int(reach + 1024).bit_length()  # power of two > reach + 1024
        self._p = np.zeros((self.depth, self.width))  # slot s % depth holds P[s]
        self._last = np.zeros(self.width)  # P of the last row
        self._rows = 0  #: rows seen
        self._next_rebase = 1 << 20

    def update(
        self, rows: np.ndarray, offsets: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(P at the new rows (N, k), P ``offsets`` rows back (N, len(offsets), k), stream
        index of each new row (N,)); ``rows`` (N, k), each offset in 1..reach."""
        n = rows.shape[0]
        chunk = self.depth - self.reach - 1
        if n > chunk:  # keep every slot a window reaches unwritten until it is read
            parts = [self.update(rows[i : i + chunk], offsets) for i in range(0, n, chunk)]
            return (
                np.concatenate([p[0] for p in parts]),
                np.concatenate([p[1] for p in parts]),
                np.concatenate([p[2] for p in parts]),
            )
        first = self._rows
        now = np.cumsum(rows, axis=0)
        now += self._last
        idx = np.arange(first, first + n)
        slots = idx & (self.depth - 1)
        self._p[slots] = now
        back_idx = idx[:, None] - offsets[None, :]
        back = self._p[back_idx & (self.depth - 1)]
        if first < self.reach:  # P before the stream's start is 0
            back[back_idx < 0] = 0.0
        self._last = now[-1].copy()
        self._rows = first + n
        if self._rows >= self._next_rebase:
            shift = self._last.copy()
            self._p -= shift
            self._last -= shift
            now = now - shift
            back = back - shift
            self._next_rebase = self._rows + (1 << 20)
        return now, back, idx


#: Flag bits that make a sample unusable for the static check (and so for F0 and the
#: diagnosis intervals): saturation, ADC errors, and self-test, whose outputs are
#: deflected on purpose.
BAD_FLAGS = FLAG_GYRO_SATURATED | FLAG_ACCEL_SATURATED | FLAG_ADC_ERROR | FLAG_SELF_TEST

#: Standard normal quantile used for the data-driven noise estimate.
_NOISE_QUANTILE = 0.05
_Z_NOISE_QUANTILE = -1.6448536269514729


def _chi2_quantile_ratio(dof: float, z: float) -> float:
    """chi2_p(dof) / dof by the Wilson-Hilferty approximation (z: normal quantile of p)."""
    a = 2.0 / (9.0 * dof)
    return max((1.0 - a + z * math.sqrt(a)) ** 3, 1e-3)


def _windowed_mean_var(x: np.ndarray, w: int) -> tuple[np.ndarray, np.ndarray]:
    """Means and unbiased variances (per column) of every full trailing window of ``w`` rows.

    ``x`` (M, C) with M >= w; returns two (M - w + 1, C) arrays, row i for rows i..i+w-1.
    Values are centred on the first row first, so large offsets (ADC counts) do
    not cancel catastrophically.
    """
    xc = x - x[0]
    s1 = np.concatenate([np.zeros((1, x.shape[1])), np.cumsum(xc, axis=0)])
    s2 = np.concatenate([np.zeros((1, x.shape[1])), np.cumsum(xc * xc, axis=0)])
    w1 = s1[w:] - s1[:-w]
    w2 = s2[w:] - s2[:-w]
    mean_c = w1 / w
    var = np.maximum((w2 - w1 * mean_c) / (w - 1), 0.0)
    return mean_c + x[0], var


class TrailingSpread:
    """Per-column spread (max - min) of a stream's values over a trailing history: the
    drift test of :class:`QuasiStaticDetector`.

    Values are kept every ``step`` stream rows (absolute row index a multiple of
    ``step``); the spread at row i covers the kept values from its history's first
    row (given) up to i, and row i's own value. Results depend on the absolute row
    indices only, not on the blocks.
    """

    _BIG = 1 << 62

    def __init__(self, columns: int, step: int, span: int) -> None:
        self.columns = int(columns)
        self.step = max(1, int(step))
        self.span = max(self.step, int(span))
        self.k = self.span // self.step + 1  #: kept values a history holds at most
        self.reset()

    def reset(self) -> None:
        """Forget the history."""
        c = self.columns
        self._idx = np.zeros(0, dtype=np.int64)
        self._val = np.zeros((0, c))
        self._start = np.zeros(0, dtype=np.int64)
        self._max = np.zeros((0, c))
        self._min = np.zeros((0, c))

    def update(self, idx: np.ndarray, values: np.ndarray, start: np.ndarray) -> np.ndarray:
        """Spreads (M, C) for stream rows ``idx`` (M,) increasing, with ``values`` (M, C)
        and the first row of each row's history ``start`` (M,)."""
        big = self._BIG
        sel = idx % self.step == 0
        k = self.k
        d_idx = np.concatenate([self._idx, idx[sel]])
        d_val = np.concatenate([self._val, values[sel]])
        d_start = np.concatenate([self._start, start[sel]])
        old = self._idx.shape[0]
        new = d_idx.shape[0] - old
        d_max = np.concatenate([self._max, np.empty((new, self.columns))])
        d_min = np.concatenate([self._min, np.empty((new, self.columns))])
        if new:
            pad = k - 1
            pi = np.concatenate([np.full(pad, -big), d_idx])
            pv = np.concatenate([np.zeros((pad, self.columns)), d_val])
            vi = np.lib.stride_tricks.sliding_window_view(pi, k)[old:]  # (new, k)
            vv = np.lib.stride_tricks.sliding_window_view(pv, k, axis=0)[old:]  # (new, C, k)
            use = (vi >= d_start[old:, None])[:, None, :]
            d_max[old:] = np.max(np.where(use, vv, -np.inf), axis=2)
            d_min[old:] = np.min(np.where(use, vv, np.inf), axis=2)
        p = np.searchsorted(d_idx, idx, side="right") - 1
        pc = np.maximum(p, 0)
        have = (p >= 0) & (d_idx[pc] >= start) if d_idx.size else np.zeros(idx.shape, bool)
        if d_idx.size:
            hi = np.maximum(d_max[pc], values)
            lo = np.minimum(d_min[pc], values)
            spread = np.where(have[:, None] & np.isfinite(hi - lo), hi - lo, 0.0)
        else:
            spread = np.zeros(values.shape)
        keep = slice(max(0, d_idx.shape[0] - k), None)
        self._idx, self._val, self._start = d_idx[keep], d_val[keep], d_start[keep]
        self._max, self._min = d_max[keep], d_min[keep]
        return spread


class QuasiStaticDetector:
    """Streaming quasi-static detector over both triads.

    ``certificate``: the unit's certificate (noise density, bias, limits).
    ``rate_hz``: sample rate (Hz); defaults to the certificate's.
    ``window_s``: length of the trailing window (s).
    ``k_sigma``: how many standard deviations of the noise statistics to allow.
    ``variance_factor``: floor of the allowed window variance as a multiple of
    the noise variance (margin for real noise that is not quite white).
    ``bias_margin``: gyro mean band in multiples of the bias limit (faults of
    several times the limit must still be seen as static so they can be diagnosed);
    ``None`` disables the mean check.
    ``gyro_floor_si``: rate jitter (rad/s, per axis, rms) accepted as still even
    where the gyro noise is lower: a hand-held or vibrating unit is still enough
    for the scalar checks when its rate jitters by a fraction of a degree per
    second (a motion that matters also moves the accelerometers or the gyro mean).
    ``drift_window_s``: how far back the window mean must not have drifted (s);
    ``drift_f0_fraction``: the drift allowed, as a fraction of the accelerometer F0
    limit times gravity (m/s^2), beyond the noise of two window means; None
    disables the drift test. ``drift_step_s``: spacing of the past window means
    it compares (s). ``rate_mean_s``, ``rate_drift_window_s``,
    ``rate_drift_fraction``, ``rate_drift_step_s``: the same for the gyro rate about
    the vertical (means over ``rate_mean_s``; drift allowed: the fraction of the
    largest gyro bias limit, beyond the noise of two such means).
    ``restart_margin``, ``restart_variance_factor``: the histories also restart after
    a window whose variance exceeded the variance limit by this factor while the gyro
    rate exceeded this many bias limits. ``settle_s``, ``settle_angle_deg``: the
    short history restarts ``settle_s`` after a window whose accelerometer variance
    is that of gravity sweeping this angle (module doc).
    ``certificate_noise``: use the certificate's noise density; when False (or
    when the certificate has none) the noise is estimated from the data, from
    the quietest windows seen so far: a data sheet's figure is often wrong by a
    factor 1.5-3, and a figure too low leaves no window still.
    """

    _ref: np.ndarray | None  #: the first sample of the stream, the running sums' origin

    def __init__(
        self,
        certificate: Certificate,
        rate_hz: float | None = None,
        window_s: float = 0.5,
        k_sigma: float = 4.0,
        variance_factor: float = 2.0,
        bias_margin: float | None = 8.0,
        gyro_floor_si: float = math.radians(0.5),
        certificate_noise: bool = True,
        triads: tuple[str, ...] = ("gyro", "accel"),
        drift_window_s: float = 5.0,
        drift_f0_fraction: float | None = 0.25,
        drift_step_s: float = 0.1,
        rate_mean_s: float = 2.0,
        rate_drift_window_s: float = 30.0,
        rate_drift_fraction: float = 0.5,
        rate_drift_step_s: float = 0.5,
        restart_margin: float = 2.0,
        restart_variance_factor: float = 3.0,
        settle_s: float = 2.5,
        settle_angle_deg: float = 10.0,
    ) -> None:
        self.certificate = certificate
        #: the triads whose stillness is checked (``("gyro",)``: a gyro-only log on a
        #: turntable, where "still" means a constant rate and the accelerometers are absent)
        self.triads = tuple(triads)
        if not self.triads or any(t not in ("gyro", "accel") for t in self.triads):
            raise ValueError(f"triads must name gyro and/or accel, got {triads!r}")
        self.rate_hz = float(rate_hz if rate_hz else certificate.sample_rate)
        if self.rate_hz <= 0:
            raise ValueError(f"rate_hz must be > 0, got {rate_hz!r}")
        self.window = max(3, int(round(window_s * self.rate_hz)))
        self.k_sigma = float(k_sigma)
        self.variance_factor = float(variance_factor)
        self.bias_margin = bias_margin
        g = certificate.gyro
        #: per-axis variance floor of the gyro check, output units^2
        self._gyro_floor_var = (float(gyro_floor_si) / g.unit_to_si * g.scale_factor) ** 2
        dof = 3.0 * (self.window - 1)
        # sum_j var_j / sigma_j^2 ~ chi2(dof) * 3 / dof: mean 3, std sqrt(2 * 9 / dof)
        self.variance_ratio_limit = 3.0 * max(
            1.0 + self.k_sigma * math.sqrt(2.0 / dof), self.variance_factor
        )
        #: the drift tests (module doc): accelerometer mean (m/s^2) and rate about the
        #: vertical (gyro input units), each over its own history
        self.drift_enabled = (
            drift_f0_fraction is not None
            and bias_margin is not None
            and "accel" in self.triads
            and "gyro" in self.triads
        )
        a = certificate.accel
        self.drift_limit_si = (
            float(drift_f0_fraction) * float(a.limits.f0) * float(certificate.gravity)
            if drift_f0_fraction is not None
            else math.inf
        )
        self.restart_margin = float(restart_margin)
        self.restart_variance_factor = float(restart_variance_factor)
        #: rows after a turn before the short history restarts (at least one window)
        self._settle = max(self.window, int(round(settle_s * self.rate_hz)))
        #: accelerometer window variance (sum over axes, (m/s^2)^2) of a turn through
        #: settle_angle_deg within one window: gravity sweeping that angle linearly
        self._settle_var_si = (
            float(certificate.gravity) * math.radians(settle_angle_deg)
        ) ** 2 / 12.0
        self.rate_window = max(self.window, int(round(rate_mean_s * self.rate_hz)))
        self.rate_drift_limit = float(rate_drift_fraction) * float(
            np.max(g.limits.bias / g.scale_factor)
        )
        self._short_step = max(1, int(round(drift_step_s * self.rate_hz)))
        self._short_span = int(round(drift_window_s * self.rate_hz))
        self._long_step = max(1, int(round(rate_drift_step_s * self.rate_hz)))
        self._long_span = int(round(rate_drift_window_s * self.rate_hz))
        self._noise_var: dict[str, np.ndarray | None] = {}
        self._noise_fixed: dict[str, bool] = {}
        for name in ("gyro", "accel"):
            sigma = certificate.triad(name).noise_sigma(self.rate_hz) if certificate_noise else None
            if sigma is not None and np.all(sigma > 0):
                self._noise_var[name] = np.asarray(sigma, dtype=float) ** 2
                self._noise_fixed[name] = True
            else:
                self._noise_var[name] = None
                self._noise_fixed[name] = False
        self.reset()
        # the certificate's inverse matrices, once (inverting them per block cost more than
        # the detection itself on a daemon's small blocks)
        self._n_inv_t = {name: certificate.triad(name).n_inverse_t() for name in ("gyro", "accel")}

    # -- noise ---------------------------------------------------------------

    def noise_sigma(self, triad: str) -> np.ndarray | None:
        """Per-sample noise standard deviation (output units) used for ``triad``, or None yet."""
        v = self._noise_var[triad]
        return None if v is None else np.sqrt(v)

    def _update_noise_estimate(self, triad: str, var: np.ndarray) -> None:
        if self._noise_fixed[triad] or var.shape[0] < 10:
            return
        ratio = _chi2_quantile_ratio(self.window - 1, _Z_NOISE_QUANTILE)
        # ``var`` is the caller's boolean-mask copy: partitioned in place, not copied again
        est = np.quantile(var, _NOISE_QUANTILE, axis=0, overwrite_input=True) / ratio
        est = np.maximum(est, 1e-30)
        prev = self._noise_var[triad]
        self._noise_var[triad] = est if prev is None else np.minimum(prev, est)

    # -- detection -----------------------------------------------------------

    def _rate_band(
        self, mean: np.ndarray, sigma2: np.ndarray, gyro_long: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """For window means (M, 6): whose gyro rate about the vertical is within the band
        (M,); whose rate magnitude is beyond it (M,): the unit is turning; whose rate
        magnitude is beyond the rest level (``restart_margin`` bias limits instead of
        ``bias_margin``) (M,); and the rate about the vertical (M,), gyro input units, of
        the longer gyro means ``gyro_long`` (M, 3) output units."""
        cert = self.certificate
        g, a = cert.gyro, cert.accel
        rate = g.inverse(mean[:, 0:3], n_inv_t=self._n_inv_t["gyro"])  # gyro input units
        down = a.inverse(mean[:, 3:6], n_inv_t=self._n_inv_t["accel"])
        norm = np.sqrt(np.einsum("ij,ij->i", down, down))
        vertical = np.einsum("ij,ij->i", rate, down) / np.where(norm > 0, norm, 1.0)
        margin = self.bias_margin
        assert margin is not None  # the caller checks the band only with a margin
        bias = float(np.max(g.limits.bias / g.scale_factor))
        floor = cert.earth_rate / g.unit_to_si + self.k_sigma * float(
            np.max(np.sqrt(sigma2 / self.window) / g.scale_factor)
        )
        band = float(margin) * bias + floor
        magnitude = np.sqrt(np.einsum("ij,ij->i", rate, rate))
        turning = magnitude > band
        rotating = magnitude > self.restart_margin * bias + floor
        rate_long = g.inverse(gyro_long, n_inv_t=self._n_inv_t["gyro"])
        vertical_long = np.einsum("ij,ij->i", rate_long, down) / np.where(norm > 0, norm, 1.0)
        return np.abs(vertical) <= band, turning, rotating, vertical_long

    def _jump(
        self,
        idx: np.ndarray,
        sums: np.ndarray,
        prev_sums: np.ndarray,
        still: np.ndarray,
        sigma2: np.ndarray,
    ) -> np.ndarray:
        """Accelerometer windows (M,) whose mean stepped from the window before it, both
        still: a change no smooth motion makes (a ramp across two windows that pass the
        variance test moves the mean by at most sqrt(12 (L - 3)) sigma from one window to
        the next, L the variance ratio limit; the threshold, sqrt(12 L) sigma, keeps a
        margin of 2 in the squares), so a sensor step or a knock, not an acceleration."""
        w = self.window
        s1, p1 = sums[:, 3:6], prev_sums[:, 3:6]
        p_mean = p1 / w
        p_var = np.maximum((prev_sums[:, 9:12] - p1 * p_mean) / (w - 1), 0.0)
        prev_still = np.sum(p_var / sigma2, axis=1) <= self.variance_ratio_limit
        step = (s1 - p1) / w
        size = np.sum(step * step / sigma2, axis=1)
        return still & prev_still & (idx + 1 >= 2 * w) & (size > 12.0 * self.variance_ratio_limit)

    def _starts(
        self, key: int, idx: np.ndarray, marks: list[tuple[np.ndarray, int]], span: int
    ) -> np.ndarray:
        """First row of each row's history (M,): ``lag`` rows after the last row each
        (flags, lag) of ``marks`` flags, ``span`` rows back at most."""
        at = np.full(idx.shape, -(1 << 62), dtype=np.int64)
        for flags, lag in marks:
            at = np.maximum(at, np.where(flags, idx + lag, -(1 << 62)))
        last = np.maximum.accumulate(np.concatenate([[self._restart[key]], at]))[1:]
        if last.size:
            self._restart[key] = int(last[-1])
        return np.maximum(last, idx - span)

    def _drift_ok(
        self,
        idx: np.ndarray,
        accel_mean: np.ndarray,
        vertical_rate: np.ndarray,
        restarts: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    ) -> np.ndarray:
        """The drift tests (module doc) for the windows ending at stream rows ``idx`` (M,):
        accelerometer window means (M, 3) output units, rates about the vertical (M,) gyro
        input units; ``restarts`` (each (M,) flags): rows after which the short history
        restarts one window later, the same for the long history, rows where both
        restart at once (a step), rows after which the short one restarts ``settle_s``
        later (a re-orientation by hand)."""
        a, g = self.certificate.accel, self.certificate.gyro
        spread_short, spread_long = self._drift
        short_mark, long_mark, jump, settle = restarts
        to_si = a.unit_to_si / np.asarray(a.scale_factor, dtype=float)
        sigma2 = self._noise_var["accel"]
        noise = 0.0
        if sigma2 is not None:
            noise = self.k_sigma * math.sqrt(2.0 * float(np.sum(sigma2 * to_si**2)) / self.window)
        limit = self.drift_limit_si + noise
        start = self._starts(
            0, idx, [(short_mark, self.window), (jump, 0), (settle, self._settle)], self._short_span
        )
        spread = spread_short.update(idx, accel_mean, start) * to_si
        ok = np.sqrt(np.einsum("ij,ij->i", spread, spread)) <= limit
        # a curve: the rate about the vertical and the specific force changed together
        start = self._starts(1, idx, [(long_mark, self.rate_window), (jump, 0)], self._long_span)
        spread = spread_long.update(idx, np.column_stack([accel_mean, vertical_rate]), start)
        acc = spread[:, :3] * to_si
        gyro_var = self._noise_var["gyro"]
        assert gyro_var is not None  # the caller tests the drift with a gyro noise only
        var = np.maximum(gyro_var, self._gyro_floor_var) / np.asarray(g.scale_factor) ** 2
        rate_limit = self.rate_drift_limit + self.k_sigma * math.sqrt(
            2.0 * float(np.max(var)) / self.rate_window
        )
        curve = (np.sqrt(np.einsum("ij,ij->i", acc, acc)) > limit) & (spread[:, 3] > rate_limit)
        return ok & ~curve

    def update(self, block: SampleBlock) -> np.ndarray:
        """Static flags (N,) bool for the samples of ``block``, in order."""
        n = len(block)
        if n == 0:
            return np.zeros(0, dtype=bool)
        x_new = np.concatenate([block.gyro, block.accel], axis=1)
        bad_new = np.zeros(n, dtype=bool)
        if block.flags is not None:
            bad_new = (np.asarray(block.flags).astype(np.int64) & BAD_FLAGS) != 0
        cols = np.concatenate(
            [
                np.arange(3 * k, 3 * k + 3)
                for k, name in enumerate(("gyro", "accel"))
                if name in self.triads
            ]
        )
        bad_new |= ~np.all(np.isfinite(x_new[:, cols]), axis=1)
        x_new = np.where(np.isfinite(x_new), x_new, 0.0)
        w = self.window
        # running sums of the window: prefix sums of the outputs (centred on the stream's
        # first sample, so squares of ADC counts stay small), their squares and the bad
        # flags; each window's sums are two rows of them, whatever the window's length
        if self._ref is None:
            self._ref = x_new[0].copy()
        xc = x_new - self._ref
        rows = np.empty((n, 13))
        rows[:, :6] = xc
        np.multiply(xc, xc, out=rows[:, 6:12])
        rows[:, 12] = bad_new
        now, back, idx = self._prefix.update(rows, self._offsets)
        sums = now - back[:, 0, :]
        long_sums = now - back[:, 1, :]  # the gyro means over rate_window rows
        prev_sums = back[:, 0, :] - back[:, 2, :]  # the window before the window
        out = np.zeros(n, dtype=bool)
        full = idx + 1 >= w  # the first w - 1 samples of a stream have no whole window
        if full.any():
            if not full.all():
                sums, long_sums, prev_sums = sums[full], long_sums[full], prev_sums[full]
            count_long = np.minimum(idx[full] + 1, self.rate_window)[:, None]
            gyro_long = long_sums[:, 0:3] / count_long + self._ref[0:3]
            s1 = sums[:, :6]
            mean_c = s1 / w
            var = np.maximum((sums[:, 6:12] - s1 * mean_c) / (w - 1), 0.0)
            mean = mean_c + self._ref
            ok = sums[:, 12] < 0.5  # no bad sample in the window
            for k, name in enumerate(("gyro", "accel")):
                v = var[:, 3 * k : 3 * k + 3]
                self._update_noise_estimate(name, v[ok] if ok.any() else v[:0])
            turning = np.zeros(ok.shape, dtype=bool)
            vertical_long = np.zeros(ok.shape)
            jump = np.zeros(ok.shape, dtype=bool)
            rotating = np.zeros(ok.shape, dtype=bool)
            moved = np.zeros(ok.shape, dtype=bool)  # far beyond the variance test
            settle = np.zeros(ok.shape, dtype=bool)
            for k, name in enumerate(("gyro", "accel")):
                if name not in self.triads:
                    continue
                sigma2 = self._noise_var[name]
                if sigma2 is None:
                    ok[:] = False
                    continue
                v = var[:, 3 * k : 3 * k + 3]
                ref = np.maximum(sigma2, self._gyro_floor_var) if name == "gyro" else sigma2
                still = np.sum(v / ref, axis=1) <= self.variance_ratio_limit
                ok &= still
                ratio = np.sum(v / ref, axis=1)
                moved |= ratio > self.restart_variance_factor * self.variance_ratio_limit
                if name == "accel":
                    # a re-orientation by a large angle inside one window (by hand)
                    to_si = self.certificate.accel.unit_to_si / self.certificate.accel.scale_factor
                    settle = np.sum(v * to_si**2, axis=1) > self._settle_var_si
                if name == "accel":
                    jump = self._jump(idx[full], sums, prev_sums, still, ref)
                if name == "gyro" and self.bias_margin is not None and "accel" in self.triads:
                    vertical_ok, turning, rotating, vertical_long = self._rate_band(
                        mean, sigma2, gyro_long
                    )
                    ok &= vertical_ok
            if self.drift_enabled and self._noise_var["gyro"] is not None:
                bad = (sums[:, 12] >= 0.5) | (long_sums[:, 12] >= 0.5)
                restarts = (turning | (rotating & moved) | bad, turning | bad, jump, settle)
                ok &= self._drift_ok(idx[full], mean[:, 3:6], vertical_long, restarts)
            out[full] = ok
        return out

    def reset(self) -> None:
        """Forget the carried samples (after a gap in the stream); the noise estimate stays."""
        self._prefix = PrefixSums(13, max(self.rate_window, 2 * self.window))
        self._offsets = np.array([self.window, self.rate_window, 2 * self.window])
        self._ref = None
        self._drift = (
            TrailingSpread(3, self._short_step, self._short_span),
            TrailingSpread(4, self._long_step, self._long_span),
        )
        self._restart = [-(1 << 62), -(1 << 62)]  # rows where the histories restarted last


def static_mask(
    block: SampleBlock,
    certificate: Certificate,
    rate_hz: float | None = None,
    window_s: float = 0.5,
    **options: Any,
) -> np.ndarray:
    """One-shot static flags (N,) bool for a whole block (see :class:`QuasiStaticDetector`)."""
    det = QuasiStaticDetector(certificate, rate_hz, window_s=window_s, **options)
    if not det._noise_fixed["gyro"] or not det._noise_fixed["accel"]:
        # estimate the noise from the whole block first, then decide
        det.update(block)
        det.reset()
    return det.update(block)


__all__ = ["QuasiStaticDetector", "static_mask", "BAD_FLAGS"]

"""Quasi-static detection: which samples were taken while the IMU was still.

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
variances seen so far (the quietest stretches are noise only). A window whose
variance on a channel is zero to the rounding of its sums (every sample equal:
a stuck output) measures no noise and is left out of that channel's quantile
(:func:`flat_windows`): a gyro axis frozen at 40 s of a session had driven its
estimate to zero, after which no window where it was alive passed the variance
test, and in one block the samples before it froze lost their stillness too.

The window is trailing, so decisions are causal: the first ``W - 1`` samples
of a stream are never static, a static stretch starts ``W - 1`` samples after
the unit stops, and motion is flagged as soon as it shows in the window.
State (the last ``W - 1`` samples, the noise estimate) carries across blocks;
inside a block everything is vectorised with cumulative sums.

The speed machinery sits beside this module behind named interfaces:
:mod:`.windows` (the window statistics from prefix sums), :mod:`.spread` (the drift
tests' trailing spreads), :mod:`.sharing` and :mod:`.pool` (one detector run for two
consumers of a stream, ``imudiag diagnose``).
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np

from ..certificate import Certificate
from ..kernels import kernel
from ..samples import SampleBlock
from .sharing import RunReader
from .spread import TrailingSpread
from .windows import WindowStage, WindowStats

#: Standard normal quantile used for the data-driven noise estimate.
_NOISE_QUANTILE = 0.05
_Z_NOISE_QUANTILE = -1.6448536269514729


#: A window variance within this many times the rounding bound of the prefix sums it comes
#: from is zero (:func:`flat_windows`).
_FLAT_ROUNDING_FACTOR = 64.0


def rounding_bound(
    b1: np.ndarray, b2: np.ndarray, s1: np.ndarray | float, s2: np.ndarray, window: int
) -> np.ndarray:
    """The largest window variance that is zero to rounding, output units^2, for a window of
    ``window`` rows whose variance (S2 - S1^2 / W) / (W - 1) comes from sums that are
    differences of prefix sums P - B of the centred outputs (S1, B1) and their squares (S2,
    B2), each difference carrying about eps (|P| + |B|) of rounding: that bound times
    :data:`_FLAT_ROUNDING_FACTOR` (the largest ratio seen on frozen outputs was 7). The
    arguments are magnitudes (|B1|, |B2|, |S1|, |S2|), arrays or bounds of them."""
    w = float(window)
    scale = _FLAT_ROUNDING_FACTOR * float(np.finfo(float).eps) / (w - 1.0)
    return scale * ((2.0 * b2 + s2) + 2.0 * s1 * (2.0 * b1 + s1) / w)


def flat_windows(st: WindowStats, window: int, cols: slice) -> np.ndarray:
    """(M, k) bool: the windows of ``st`` (``window`` rows) whose variance on the channels
    ``cols`` (of the 6) is zero to rounding (:func:`rounding_bound`): every sample of the
    window equal, a stuck output. A working channel's noise variance is orders above it:
    the bound follows the sums' magnitudes."""
    sq = slice(cols.start + 6, cols.stop + 6)
    b1, b2 = np.abs(st.back_w[:, cols]), np.abs(st.back_w[:, sq])
    s1, s2 = np.abs(st.sums[:, cols]), np.abs(st.sums[:, sq])
    return st.var[:, cols] <= rounding_bound(b1, b2, s1, s2, window)


def flat_ceiling(st: WindowStats, window: int, rows: int) -> np.ndarray:
    """(6,) an upper bound, per channel, of :func:`rounding_bound` over every window of
    ``st``, from a few of its rows (``rows``: the stream's rows so far): the prefix sums of
    squares are monotonic over a block, so their largest magnitude q is at its ends and a
    window's S2 <= 2 q; a window sum of centred outputs is at most W times the largest
    centred window mean; a prefix sum of centred outputs over C <= ``rows`` rows is at most
    sqrt(C q) (Cauchy-Schwarz). A noise estimate above it cannot have come from flat
    windows."""
    back = st.back_w[[0, -1], 6:12]  # B2 at the block's ends, then P2 = B2 + S2 there
    q = np.abs(np.concatenate([back, back + st.sums[[0, -1], 6:12]])).max(axis=0)
    ref = np.asarray(st._stage.ref, dtype=float)
    centred = max(float(st.mean.max() - ref.min()), float(ref.max() - st.mean.min()), 0.0)
    return rounding_bound(np.sqrt(max(rows, 1) * q), q, window * centred, 2.0 * q, window)


def _chi2_quantile_ratio(dof: float, z: float) -> float:
    """chi2_p(dof) / dof by the Wilson-Hilferty approximation (z: normal quantile of p)."""
    a = 2.0 / (9.0 * dof)
    return max((1.0 - a + z * math.sqrt(a)) ** 3, 1e-3)


class _Limits(NamedTuple):
    """The detector's thresholds that depend on its noise figures (worked out once each)."""

    var_ref: np.ndarray  #: (6,) per-axis noise variance of the variance test, output units^2
    checked: tuple[int, ...]  #: triads (0 gyro, 1 accel) checked, with a noise figure
    missing: bool  #: a triad to check has no noise figure yet: nothing is still
    band: float | None  #: gyro rate band about the vertical, input units (None: no band)
    rot_band: float | None  #: the rest level of the rate magnitude, input units
    drift_limit: float  #: the drift tests' accelerometer limit, m/s^2
    rate_limit: float  #: the curve test's limit on the rate about the vertical, input units


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
        self._set_variance_test(gyro_floor_si)
        self._set_drift_tests(
            drift_f0_fraction, drift_window_s, drift_step_s, rate_mean_s,
            rate_drift_window_s, rate_drift_fraction, rate_drift_step_s,
        )  # fmt: skip
        self._set_restarts(restart_margin, restart_variance_factor, settle_s, settle_angle_deg)
        self._set_noise(certificate_noise)
        #: what explains the static flags given so far (:meth:`_note_windows`): windows
        #: judged, per triad those within the variance limit and the least variance ratio
        #: to that limit, and the static samples
        self.explain: dict[str, Any] = {
            "windows": 0,
            "static": 0,
            "gyro_variance_ok": 0,
            "accel_variance_ok": 0,
            "gyro_least_ratio": math.inf,
            "accel_least_ratio": math.inf,
        }
        #: the columns (gyro 0-2, accel 3-5) of the triads checked
        self._cols = np.array(
            [
                3 * k + j
                for k, name in enumerate(("gyro", "accel"))
                if name in self.triads
                for j in range(3)
            ]
        )
        #: accelerometer output units to m/s^2, per axis
        a = certificate.accel
        self._to_si = a.unit_to_si / np.asarray(a.scale_factor, dtype=float)
        self._to_si2 = self._to_si**2
        # the certificate's inverse matrices, once (inverting them per block cost more than
        # the detection itself on a daemon's small blocks)
        self._n_inv_t = {name: certificate.triad(name).n_inverse_t() for name in ("gyro", "accel")}
        self.reset()

    # -- settings (the constructor's steps) --------------------------------------

    def _set_variance_test(self, gyro_floor_si: float) -> None:
        """The variance test's limit on the sum of var_j / sigma_j^2 and the gyro floor."""
        g = self.certificate.gyro
        #: per-axis variance floor of the gyro check, output units^2
        self._gyro_floor_var = (float(gyro_floor_si) / g.unit_to_si * g.scale_factor) ** 2
        dof = 3.0 * (self.window - 1)
        # sum_j var_j / sigma_j^2 ~ chi2(dof) * 3 / dof: mean 3, std sqrt(2 * 9 / dof)
        self.variance_ratio_limit = 3.0 * max(
            1.0 + self.k_sigma * math.sqrt(2.0 / dof), self.variance_factor
        )

    def _set_drift_tests(
        self,
        drift_f0_fraction: float | None,
        drift_window_s: float,
        drift_step_s: float,
        rate_mean_s: float,
        rate_drift_window_s: float,
        rate_drift_fraction: float,
        rate_drift_step_s: float,
    ) -> None:
        """The drift tests' limits (m/s^2; gyro input units) and histories (rows)."""
        certificate = self.certificate
        g = certificate.gyro
        #: the drift tests (module doc): accelerometer mean (m/s^2) and rate about the
        #: vertical (gyro input units), each over its own history
        self.drift_enabled = (
            drift_f0_fraction is not None
            and self.bias_margin is not None
            and "accel" in self.triads
            and "gyro" in self.triads
        )
        a = certificate.accel
        self.drift_limit_si = (
            float(drift_f0_fraction) * float(a.limits.f0) * float(certificate.gravity)
            if drift_f0_fraction is not None
            else math.inf
        )
        self.rate_window = max(self.window, int(round(rate_mean_s * self.rate_hz)))
        self.rate_drift_limit = float(rate_drift_fraction) * float(
            np.max(g.limits.bias / g.scale_factor)
        )
        self._short_step = max(1, int(round(drift_step_s * self.rate_hz)))
        self._short_span = int(round(drift_window_s * self.rate_hz))
        self._long_step = max(1, int(round(rate_drift_step_s * self.rate_hz)))
        self._long_span = int(round(rate_drift_window_s * self.rate_hz))

    def _set_restarts(
        self,
        restart_margin: float,
        restart_variance_factor: float,
        settle_s: float,
        settle_angle_deg: float,
    ) -> None:
        """When the drift histories start afresh (module doc, *Restarts*)."""
        self.restart_margin = float(restart_margin)
        self.restart_variance_factor = float(restart_variance_factor)
        #: rows after a turn before the short history restarts (at least one window)
        self._settle = max(self.window, int(round(settle_s * self.rate_hz)))
        #: accelerometer window variance (sum over axes, (m/s^2)^2) of a turn through
        #: settle_angle_deg within one window: gravity sweeping that angle linearly
        self._settle_var_si = (
            float(self.certificate.gravity) * math.radians(settle_angle_deg)
        ) ** 2 / 12.0

    def _set_noise(self, certificate_noise: bool) -> None:
        """The noise variances (output units^2): the certificate's, or None until the data
        give an estimate."""
        self._noise_var: dict[str, np.ndarray | None] = {}
        self._noise_fixed: dict[str, bool] = {}
        for name in ("gyro", "accel"):
            triad = self.certificate.triad(name)
            sigma = triad.noise_sigma(self.rate_hz) if certificate_noise else None
            if sigma is not None and np.all(sigma > 0):
                self._noise_var[name] = np.asarray(sigma, dtype=float) ** 2
                self._noise_fixed[name] = True
            else:
                self._noise_var[name] = None
                self._noise_fixed[name] = False
        self._lim: _Limits | None = None

    # -- noise ---------------------------------------------------------------

    def noise_sigma(self, triad: str) -> np.ndarray | None:
        """Per-sample noise standard deviation (output units) used for ``triad``, or None yet."""
        v = self._noise_var[triad]
        return None if v is None else np.sqrt(v)

    def _update_noise_estimate(
        self,
        triad: str,
        windows_var: np.ndarray,
        ok: np.ndarray,
        ceiling: np.ndarray | None = None,
        flat: Callable[[], tuple[np.ndarray, np.ndarray]] | None = None,
    ) -> None:
        """The data-driven noise variances of ``triad`` from this block's window variances
        ``windows_var`` (M, 3) where ``ok`` (M,): the windows without a bad sample. Where an
        axis's quantile is at most ``ceiling`` (3,), windows flat on it (a stuck output) may
        have made it: ``flat()`` gives the kept windows' variances again and which are flat
        (K, 3), and those are left out (module doc)."""
        if self._noise_fixed[triad]:
            return
        ratio = _chi2_quantile_ratio(self.window - 1, _Z_NOISE_QUANTILE)
        prev = self._noise_var[triad]
        above = kernel("quantile_above")
        if above is not None and prev is not None and ceiling is not None:
            # (compiled kernels) a block whose window variances' quantile is above both the
            # present estimate's and the flat windows' ceiling cannot lower the estimate nor
            # call for the flat windows: it changes nothing
            thr = np.maximum(prev * ratio, ceiling) * (1.0 + 1e-9)
            if above(windows_var, ok, thr, _NOISE_QUANTILE):
                return
        if int(np.count_nonzero(ok)) < 10:
            return
        select = kernel("masked_quantile")  # (compiled kernels) numpy's, found by selection
        found = select(windows_var, ok, _NOISE_QUANTILE) if select is not None else None
        if found is not None and found[1]:
            q = found[0]
        else:  # the boolean-mask copy, partitioned in place: not copied again
            q = np.quantile(windows_var[ok], _NOISE_QUANTILE, axis=0, overwrite_input=True)
        stands: list[int] = []
        if ceiling is not None and flat is not None and np.any(q <= ceiling):
            fresh, frozen = flat()
            for j in np.flatnonzero(frozen.any(axis=0)):
                live = fresh[~frozen[:, j], j]
                if live.shape[0] >= 10:
                    q[j] = np.quantile(live, _NOISE_QUANTILE)
                elif prev is not None:  # nothing alive on it here: the estimate stands
                    stands.append(int(j))
                # else frozen since the stream began: no noise figure to be had (the floor)
        est = q / ratio
        est = np.maximum(est, 1e-30)
        if stands and prev is not None:
            est[stands] = prev[stands]
        if prev is not None:
            est = np.minimum(prev, est)
            if np.array_equal(est, prev):
                return
        self._noise_var[triad] = est
        self._lim = None  # the thresholds follow the estimate

    # -- detection -----------------------------------------------------------

    def _limits(self) -> _Limits:
        """The thresholds that depend on the noise figures, worked out once per figure."""
        if self._lim is not None:
            return self._lim
        cert = self.certificate
        g = cert.gyro
        k = self.k_sigma
        var_ref = np.ones(6)  # per-axis noise variance of the variance test (output units^2)
        checked = []
        missing = False
        for c, name in enumerate(("gyro", "accel")):
            if name not in self.triads:
                continue
            sigma2 = self._noise_var[name]
            if sigma2 is None:
                missing = True
                continue
            checked.append(c)
            var_ref[3 * c : 3 * c + 3] = (
                np.maximum(sigma2, self._gyro_floor_var) if name == "gyro" else sigma2
            )
        band = rot_band = None
        gyro_var = self._noise_var["gyro"]
        if (
            gyro_var is not None
            and 0 in checked
            and self.bias_margin is not None
            and "accel" in self.triads
        ):
            bias = float(np.max(g.limits.bias / g.scale_factor))
            floor = cert.earth_rate / g.unit_to_si + k * float(
                np.max(np.sqrt(gyro_var / self.window) / g.scale_factor)
            )
            band = float(self.bias_margin) * bias + floor
            rot_band = self.restart_margin * bias + floor
        accel_var = self._noise_var["accel"]
        noise = 0.0
        if accel_var is not None:
            noise = k * math.sqrt(2.0 * float(np.sum(accel_var * self._to_si**2)) / self.window)
        rate_limit = math.inf
        if gyro_var is not None:
            var = np.maximum(gyro_var, self._gyro_floor_var) / np.asarray(g.scale_factor) ** 2
            rate_limit = self.rate_drift_limit + k * math.sqrt(
                2.0 * float(np.max(var)) / self.rate_window
            )
        self._lim = _Limits(
            var_ref,
            tuple(checked),
            missing,
            band,
            rot_band,
            self.drift_limit_si + noise,
            rate_limit,
        )
        return self._lim

    def _starts(
        self, key: int, idx: np.ndarray, marks: list[tuple[np.ndarray, int]], span: int
    ) -> np.ndarray:
        """First row of each row's history (M,): ``lag`` rows after the last row each
        (flags, lag) of ``marks`` flags, ``span`` rows back at most."""
        compiled = kernel("history_starts")
        if compiled is not None and 1 <= len(marks) <= 3:  # the same integers in one pass
            (f0, lag0), (f1, lag1), (f2, lag2) = (marks + marks[:1] * 2)[:3]  # (a mark twice)
            out, last = compiled(
                np.ascontiguousarray(idx, dtype=np.int64), f0, lag0, f1, lag1, f2, lag2,
                self._restart[key], span,
            )  # fmt: skip
            self._restart[key] = int(last)
            return out
        marks = [(flags, lag) for flags, lag in marks if flags.any()]
        if not marks:  # no restart in this block
            return np.maximum(idx - span, self._restart[key])
        at = np.full(idx.shape, -(1 << 62), dtype=np.int64)
        for flags, lag in marks:
            at = np.maximum(at, np.where(flags, idx + lag, -(1 << 62)))
        last = np.maximum.accumulate(np.concatenate([[self._restart[key]], at]))[1:]
        self._restart[key] = int(last[-1])
        return np.maximum(last, idx - span)

    def update(self, block: SampleBlock) -> np.ndarray:
        """Static flags (N,) bool for the samples of ``block``, in order."""
        out = self._update(block)
        self.explain["static"] += int(np.count_nonzero(out))
        return out

    def _note_windows(self, ratio: np.ndarray, still: np.ndarray) -> None:
        """Keep what explains a stream without a still sample (:attr:`explain`): windows
        judged, per triad those within the variance limit, and the least ratio of a window's
        variance to that limit (``ratio`` (M, 2) over the limit, gyro then accel)."""
        e = self.explain
        e["windows"] += int(ratio.shape[0])
        for c, name in enumerate(("gyro", "accel")):
            e[f"{name}_variance_ok"] += int(np.count_nonzero(still[:, c]))
            if ratio.shape[0]:
                least = float(np.min(ratio[:, c]))
                e[f"{name}_least_ratio"] = min(e[f"{name}_least_ratio"], least)

    def _update(self, block: SampleBlock) -> np.ndarray:
        n = len(block)
        if n == 0:
            return np.zeros(0, dtype=bool)
        st = self._stage.run(block)
        out = np.zeros(n, dtype=bool)
        if st.skip >= n:
            return out
        w = self.window
        skip, first, idx, m = st.skip, st.first, st.idx, n - st.skip
        sums, var, mean = st.sums, st.var, st.mean
        ok = sums[:, 12] < 0.5  # no bad sample in the window
        if not (self._noise_fixed["gyro"] and self._noise_fixed["accel"]):
            ceiling = flat_ceiling(st, w, first + m)
            for c, name in enumerate(("gyro", "accel")):
                cols = slice(3 * c, 3 * c + 3)

                def flat(cols: slice = cols) -> tuple[np.ndarray, np.ndarray]:
                    return st.var[:, cols][ok], flat_windows(st, w, cols)[ok]

                self._update_noise_estimate(name, var[:, cols], ok, ceiling[cols], flat)
        lim = self._limits()
        limit = self.variance_ratio_limit
        compiled = kernel("variance_test")
        settle_c = None
        if compiled is not None:  # the same sums and comparisons compiled: the same flags
            checked = np.zeros(2, dtype=bool)
            checked[list(lim.checked)] = True
            ratio, still, settle_c = compiled(
                np.ascontiguousarray(var), lim.var_ref, float(limit), checked,
                bool(lim.missing), self._to_si2, float(self._settle_var_si), ok,
            )  # fmt: skip
            if not lim.missing:
                self._note_windows(ratio / limit, still)
        else:
            # sum over each triad's axes of var_j / sigma_j^2
            ratio = (var / lim.var_ref).reshape(m, 2, 3).sum(axis=2)
            still = ratio <= limit
            if not lim.missing:
                self._note_windows(ratio / limit, still)
            if lim.missing:
                ok[:] = False
            for c in lim.checked:
                ok &= still[:, c]
        if not self.drift_enabled or lim.band is None:
            if lim.band is not None:
                ok &= self._rate_band(st)[0]
            out[skip:] = ok
            return out
        vertical_ok, turning, rotating, vertical_long = self._rate_band(st)
        ok &= vertical_ok
        # the histories' restarts (module doc)
        bad = st.long_sums[:, 12] >= 0.5  # in either window (the long one holds the short one)
        long_mark = turning | bad
        short_mark = long_mark
        if rotating.any():  # and far beyond the variance test
            moved = (ratio[:, lim.checked] > self.restart_variance_factor * limit).any(axis=1)
            short_mark = long_mark | (rotating & moved)
        jump = settle = np.zeros(m, dtype=bool)
        if 1 in lim.checked:
            # a re-orientation by a large angle inside one window (by hand)
            settle = (
                settle_c
                if settle_c is not None
                else np.sum(var[:, 3:6] * self._to_si2, axis=1) > self._settle_var_si
            )
            jump = self._jump(first, sums, st.back_w, st.back_2w, still[:, 1], lim.var_ref[3:6])
        if (short_mark | jump | settle).any():
            start_short = self._starts(
                0, idx, [(short_mark, w), (jump, 0), (settle, self._settle)], self._short_span
            )
            start_long = self._starts(
                1, idx, [(long_mark, self.rate_window), (jump, 0)], self._long_span
            )
        else:  # no restart in this block
            start_short = np.maximum(idx - self._short_span, self._restart[0])
            start_long = np.maximum(idx - self._long_span, self._restart[1])
        # the drift tests (module doc): the accelerometer window mean over the short history
        accel_mean = mean[:, 3:6]
        within = kernel("drift_within")
        if within is not None:  # the same products and sums compiled, in place
            spread = self._drift[0].update(first, accel_mean, start_short)
            within(np.ascontiguousarray(spread), self._to_si, float(lim.drift_limit), ok)
        else:
            spread = self._drift[0].update(first, accel_mean, start_short) * self._to_si
            ok &= np.sqrt(np.einsum("ij,ij->i", spread, spread)) <= lim.drift_limit
        # a curve: the rate about the vertical and the specific force changed together
        values = np.column_stack([accel_mean, vertical_long])
        spread = self._drift[1].update(first, values, start_long)
        curved = kernel("curve_test")
        if curved is not None:  # the same products, sums and comparisons compiled, in place
            curved(spread, self._to_si, float(lim.rate_limit), float(lim.drift_limit), ok)
        else:
            curve = spread[:, 3] > lim.rate_limit
            if curve.any():  # (the specific force only where the rate drifted)
                acc = spread[:, :3] * self._to_si
                curve &= np.sqrt(np.einsum("ij,ij->i", acc, acc)) > lim.drift_limit
                ok &= ~curve
        if skip:
            out[skip:] = ok
            return out
        return ok

    def _rate_band(self, st: WindowStats) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """For the windows of ``st``: whose gyro rate about the vertical is within the band
        (M,); whose rate magnitude is beyond it (M,): the unit is turning; whose rate
        magnitude is beyond the rest level (``restart_margin`` bias limits instead of
        ``bias_margin``) (M,); and the rate about the vertical (M,), gyro input units, of
        the longer gyro means (over ``rate_window`` rows)."""
        lim = self._limits()
        assert lim.band is not None and lim.rot_band is not None
        vertical, vertical_long, magnitude = st.rates()
        return (
            np.abs(vertical) <= lim.band,
            magnitude > lim.band,
            magnitude > lim.rot_band,
            vertical_long,
        )

    def _jump(
        self,
        first: int,
        sums: np.ndarray,
        back_w: np.ndarray,
        back_2w: np.ndarray,
        still: np.ndarray,
        sigma2: np.ndarray,
    ) -> np.ndarray:
        """Accelerometer windows (M,) whose mean stepped from the window before it, both
        still: a change no smooth motion makes (a ramp across two windows that pass the
        variance test moves the mean by at most sqrt(12 (L - 3)) sigma from one window to
        the next, L the variance ratio limit; the threshold, sqrt(12 L) sigma, keeps a
        margin of 2 in the squares), so a sensor step or a knock, not an acceleration.
        ``back_w``, ``back_2w`` (M, 13): the prefix sums one and two windows back;
        ``sigma2``: the accelerometers' noise variance (output units^2)."""
        w = self.window
        limit = self.variance_ratio_limit
        compiled = kernel("jump_test")  # the same operations and sums compiled: same flags
        if compiled is not None:
            out: np.ndarray = compiled(
                sums, back_w, back_2w, np.ascontiguousarray(still, dtype=bool),
                np.ascontiguousarray(sigma2, dtype=float), int(w), float(limit), int(first),
            )  # fmt: skip
            return out
        p1 = back_w[:, 3:6] - back_2w[:, 3:6]  # the window before the window
        step = (sums[:, 3:6] - p1) / w
        jump = still & (np.sum(step * step / sigma2, axis=1) > 12.0 * limit)
        if first + 1 < 2 * w:
            jump &= np.arange(first + 1, first + 1 + sums.shape[0]) >= 2 * w
        if jump.any():  # and the window before was still too
            p_mean = p1 / w
            p_var = np.maximum((back_w[:, 9:12] - back_2w[:, 9:12] - p1 * p_mean) / (w - 1), 0.0)
            jump &= np.sum(p_var / sigma2, axis=1) <= limit
        return jump

    def copy(self) -> QuasiStaticDetector:
        """An independent copy of the detector in its present state (the certificate shared):
        fed the same blocks, it gives what this one would."""
        new = copy.copy(self)
        new._stage = self._stage.copy()
        # a TrailingSpread replaces its arrays, never writes into them: a shallow copy is one
        new._drift = (copy.copy(self._drift[0]), copy.copy(self._drift[1]))
        new._restart = list(self._restart)
        new._noise_var = dict(self._noise_var)
        new._noise_fixed = dict(self._noise_fixed)
        new.explain = dict(self.explain)
        return new

    def reset(self) -> None:
        """Forget the carried samples (after a gap in the stream); the noise estimate stays."""
        self._stage: WindowStage | RunReader[WindowStats] = WindowStage(
            self.certificate, self.window, self.rate_window, self._cols, self._n_inv_t
        )
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

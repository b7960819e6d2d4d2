"""WHY THIS FILE STAYS (issue 30 item 6): a part of the reference of
``tests/test_monitor_equivalence.py``; the note at the top of ``old_monitor.py`` says why
it is kept. Do not edit.

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
- no saturation or ADC-error flag in the window.

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

import numpy as np

from imudiag.certificate import Certificate
from imudiag.samples import FLAG_ACCEL_SATURATED, FLAG_ADC_ERROR, FLAG_GYRO_SATURATED, SampleBlock

#: Flag bits that make a sample unusable for the static check.
BAD_FLAGS = FLAG_GYRO_SATURATED | FLAG_ACCEL_SATURATED | FLAG_ADC_ERROR

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
    ) -> None:
        self.certificate = certificate
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
        self._tail = np.zeros((0, 6))
        self._tail_bad = np.zeros(0, dtype=bool)

    # -- noise ---------------------------------------------------------------

    def noise_sigma(self, triad: str) -> np.ndarray | None:
        """Per-sample noise standard deviation (output units) used for ``triad``, or None yet."""
        v = self._noise_var[triad]
        return None if v is None else np.sqrt(v)

    def _update_noise_estimate(self, triad: str, var: np.ndarray) -> None:
        if self._noise_fixed[triad] or var.shape[0] < 10:
            return
        ratio = _chi2_quantile_ratio(self.window - 1, _Z_NOISE_QUANTILE)
        est = np.quantile(var, _NOISE_QUANTILE, axis=0) / ratio
        est = np.maximum(est, 1e-30)
        prev = self._noise_var[triad]
        self._noise_var[triad] = est if prev is None else np.minimum(prev, est)

    # -- detection -----------------------------------------------------------

    def _vertical_rate_ok(self, mean: np.ndarray, sigma2: np.ndarray) -> np.ndarray:
        """Window means (M, 6) whose gyro rate about the vertical is within the band (M,)."""
        cert = self.certificate
        g, a = cert.gyro, cert.accel
        rate = g.inverse(mean[:, 0:3])  # gyro input units
        down = a.inverse(mean[:, 3:6])
        norm = np.sqrt(np.einsum("ij,ij->i", down, down))
        vertical = np.einsum("ij,ij->i", rate, down) / np.where(norm > 0, norm, 1.0)
        band = (
            float(self.bias_margin) * float(np.max(g.limits.bias / g.scale_factor))
            + cert.earth_rate / g.unit_to_si
            + self.k_sigma * float(np.max(np.sqrt(sigma2 / self.window) / g.scale_factor))
        )
        return np.abs(vertical) <= band

    def update(self, block: SampleBlock) -> np.ndarray:
        """Static flags (N,) bool for the samples of ``block``, in order."""
        n = len(block)
        if n == 0:
            return np.zeros(0, dtype=bool)
        x_new = np.concatenate([block.gyro, block.accel], axis=1)
        bad_new = np.zeros(n, dtype=bool)
        if block.flags is not None:
            bad_new = (np.asarray(block.flags).astype(np.int64) & BAD_FLAGS) != 0
        bad_new |= ~np.all(np.isfinite(x_new), axis=1)
        x_new = np.where(np.isfinite(x_new), x_new, 0.0)
        x = np.concatenate([self._tail, x_new])
        bad = np.concatenate([self._tail_bad, bad_new])
        w = self.window
        out = np.zeros(n, dtype=bool)
        m = x.shape[0]
        if m >= w:
            mean, var = _windowed_mean_var(x, w)
            nbad = np.concatenate([[0], np.cumsum(bad)])
            bad_win = (nbad[w:] - nbad[:-w]) > 0
            ok = ~bad_win
            for k, name in enumerate(("gyro", "accel")):
                v = var[:, 3 * k : 3 * k + 3]
                self._update_noise_estimate(name, v[ok] if ok.any() else v[:0])
            ok = ok.copy()
            for k, name in enumerate(("gyro", "accel")):
                sigma2 = self._noise_var[name]
                if sigma2 is None:
                    ok[:] = False
                    continue
                v = var[:, 3 * k : 3 * k + 3]
                ref = np.maximum(sigma2, self._gyro_floor_var) if name == "gyro" else sigma2
                ok &= np.sum(v / ref, axis=1) <= self.variance_ratio_limit
                if name == "gyro" and self.bias_margin is not None:
                    ok &= self._vertical_rate_ok(mean, sigma2)
            # row i of the window arrays ends at concat index i + w - 1
            first_end = w - 1
            start_in_concat = m - n
            idx = np.arange(start_in_concat, m) - first_end
            valid = idx >= 0
            out[valid] = ok[idx[valid]]
        keep = min(w - 1, m)
        self._tail = x[m - keep :].copy()
        self._tail_bad = bad[m - keep :].copy()
        return out

    def reset(self) -> None:
        """Forget the carried samples (after a gap in the stream); the noise estimate stays."""
        self._tail = np.zeros((0, 6))
        self._tail_bad = np.zeros(0, dtype=bool)


def static_mask(
    block: SampleBlock,
    certificate: Certificate,
    rate_hz: float | None = None,
    window_s: float = 0.5,
    **options: float,
) -> np.ndarray:
    """One-shot static flags (N,) bool for a whole block (see :class:`QuasiStaticDetector`)."""
    det = QuasiStaticDetector(certificate, rate_hz, window_s=window_s, **options)
    if not det._noise_fixed["gyro"] or not det._noise_fixed["accel"]:
        # estimate the noise from the whole block first, then decide
        det.update(block)
        det.reset()
    return det.update(block)


__all__ = ["QuasiStaticDetector", "static_mask", "BAD_FLAGS"]

"""GNSS latency: cross-correlate the two specific-force magnitudes.

For a candidate latency tau the IMU's mean |f| over every GNSS epoch shifted
by tau (:func:`~.specific_force.imu_epochs`) is correlated with the GNSS
|f| over the valid epochs; the latency is the correlation's peak on a grid
of ``step_s`` refined by a parabola through the three best points. The
correlation needs |f| to vary (accelerations, braking, turns, bumps): on a
constant-speed straight road there is nothing to align, and the estimate is
reported as undetermined (peak correlation below ``min_correlation``, or the
peak at the edge of the searched range).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .specific_force import GnssEpochs, imu_epochs

#: spacing of the first, coarse pass over the lags, s (refined around its peak)
COARSE_LAG_S = 0.05
#: the finest lag grid, s: the sample period, but not below this (the parabola through
#: the best three points refines between them; at 1 kHz a 1 ms grid cost 124 passes over
#: the buffer instead of 44)
MIN_LAG_STEP_S = 0.005


@dataclass
class LatencyEstimate:
    """The GNSS latency (s; GNSS velocity tagged t is the motion at IMU time t - latency)."""

    latency_s: float  #: nan when undetermined
    correlation: float  #: peak correlation coefficient
    determined: bool
    reason: str  #: why not determined ("" when determined)
    epochs: int  #: epochs used
    lags_s: np.ndarray | None = None
    correlations: np.ndarray | None = None

    def to_json(self) -> dict:
        """The estimate as reported (diagnosis report, status)."""
        return {
            "latency_s": round(self.latency_s, 4) if math.isfinite(self.latency_s) else None,
            "correlation": round(self.correlation, 4) if math.isfinite(self.correlation) else None,
            "determined": self.determined,
            "reason": self.reason,
            "epochs": self.epochs,
        }


def estimate_latency(
    t: np.ndarray,
    accel_si: np.ndarray,
    epochs: GnssEpochs,
    gyro_si: np.ndarray | None = None,
    max_latency_s: float = 1.0,
    step_s: float | None = None,
    min_correlation: float = 0.5,
    min_epochs: int = 20,
) -> LatencyEstimate:
    """Latency in [-max_latency_s, max_latency_s] maximising the |f| correlation (module doc)."""
    t = np.asarray(t, dtype=float)
    if step_s is None:
        step_s = max(float(np.median(np.diff(t))), MIN_LAG_STEP_S) if t.size > 1 else 0.01
    use = epochs.select(epochs.valid)
    # keep epochs inside the IMU record at every lag
    inside = (use.t0 - max_latency_s >= t[0]) & (use.t1 + max_latency_s <= t[-1])
    use = use.select(inside)
    if len(use) < min_epochs:
        return LatencyEstimate(
            math.nan,
            math.nan,
            False,
            f"{len(use)} valid GNSS epochs over the IMU record, {min_epochs} needed",
            len(use),
        )
    g = use.mag - np.mean(use.mag)
    if np.std(g) <= float(np.median(use.sigma_mag)):
        return LatencyEstimate(
            math.nan,
            math.nan,
            False,
            "the GNSS |f| does not vary beyond its noise: nothing to align",
            len(use),
        )
    lags = np.arange(-max_latency_s, max_latency_s + 0.5 * step_s, step_s)
    corr = np.full(lags.shape, np.nan)
    done = np.zeros(lags.shape, dtype=bool)

    def correlate(indices: np.ndarray) -> None:
        for i in indices[~done[indices]]:
            done[i] = True
            im = imu_epochs(t, accel_si, use.t0, use.t1, gyro_si=gyro_si, latency_s=float(lags[i]))
            ok = np.isfinite(im.mag) & im.covered
            if np.sum(ok) < min_epochs:
                continue
            a = im.mag[ok] - np.mean(im.mag[ok])
            b = use.mag[ok] - np.mean(use.mag[ok])
            den = math.sqrt(float(np.sum(a * a) * np.sum(b * b)))
            corr[i] = float(np.sum(a * b) / den) if den > 0 else np.nan

    # coarse to fine: every lag costs a pass over the whole record (the daemon's aiding
    # batch took 3 s of CPU with 401 lags of 5 ms over 210 s at 200 Hz). The correlation
    # of 1 s epoch means is smooth on the scale of COARSE_LAG_S, so the grid's peak lies
    # within one coarse step of the coarse peak: only that neighbourhood is refined
    stride = max(1, int(round(COARSE_LAG_S / step_s)))
    coarse = np.unique(np.append(np.arange(0, lags.size, stride), lags.size - 1))
    correlate(coarse)
    if stride > 1 and np.any(np.isfinite(corr)):
        c = int(np.nanargmax(corr))
        correlate(np.arange(max(0, c - stride - 1), min(lags.size, c + stride + 2)))
    if not np.any(np.isfinite(corr)):
        return LatencyEstimate(
            math.nan, math.nan, False, "the IMU does not cover the epochs", len(use), lags, corr
        )
    i = int(np.nanargmax(corr))
    peak = float(corr[i])
    if i == 0 or i == len(lags) - 1:
        return LatencyEstimate(
            float(lags[i]),
            peak,
            False,
            f"correlation peaks at the edge of +-{max_latency_s:g} s",
            len(use),
            lags,
            corr,
        )
    y0, y1, y2 = corr[i - 1], corr[i], corr[i + 1]
    den = y0 - 2 * y1 + y2
    off = 0.5 * (y0 - y2) / den if np.isfinite(den) and den < 0 else 0.0
    lat = float(lags[i] + np.clip(off, -1.0, 1.0) * step_s)
    if peak < min_correlation:
        return LatencyEstimate(
            lat,
            peak,
            False,
            f"peak correlation {peak:.2f} below {min_correlation:g}",
            len(use),
            lags,
            corr,
        )
    return LatencyEstimate(lat, peak, True, "", len(use), lags, corr)


__all__ = ["LatencyEstimate", "estimate_latency"]

"""GNSS latency: cross-correlate the two specific-force magnitudes.

For a candidate latency tau the IMU's mean |f| over every GNSS epoch shifted
by tau (:func:`~.specific_force.imu_epochs`) is correlated with the GNSS
|f| over the valid epochs; the latency is the correlation's peak on a grid
of ``step_s`` refined by a parabola through the three best points. The
correlation needs |f| to vary (accelerations, braking, turns, bumps): on a
constant-speed straight road there is nothing to align, and the estimate is
reported as undetermined (peak correlation below ``min_correlation``, or the
peak at the edge of the searched range).

Uncertainty: the larger of two stds (s), times ``STD_FACTOR`` (calibrated on
simulated drives, docs/moving-base.md). A delete-one-block jackknife over
``JACKKNIFE_BLOCKS`` contiguous blocks of epochs: each replicate drops one
block and takes the peak of the correlation of the rest over the lags already
searched (no further passes over the record); std = sqrt((n-1)/n sum (tau_j -
mean)^2). And the peak's curvature (:func:`curvature_std`), which sees a flat
correlation the jackknife misses (all blocks share one broad peak). The
estimate is determined only when that std is at most ``max_std_s``
(``LATENCY_TOLERANCE_S`` by default): a peak that moves by tens of ms when a
tenth of the drive is left out is not a measured latency, whatever its
correlation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .specific_force import GnssEpochs, ImuSeries

#: spacing of the first, coarse pass over the lags, s (refined around its peak)
COARSE_LAG_S = 0.05
#: the finest lag grid, s: the sample period, but not below this (the parabola through
#: the best three points refines between them; at 1 kHz a 1 ms grid cost 124 passes over
#: the buffer instead of 44)
MIN_LAG_STEP_S = 0.005
#: the latency is determined when its std is at most this, s (docs/moving-base.md)
LATENCY_TOLERANCE_S = 0.03
#: half-width of the lags around the peak whose parabola gives the curvature, s
CURVATURE_HALF_WIDTH_S = 0.15
#: contiguous blocks of epochs of the delete-one-block jackknife
JACKKNIFE_BLOCKS = 10
#: the latency std (the larger of the jackknife's and the curvature's) is multiplied by
#: this (calibrated on simulated drives: |error| <= 2 std on 96 % of 72, <= 3 std on all,
#: with 1, docs/moving-base.md)
STD_FACTOR = 1.0


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
    #: 1 sigma of latency_s, s (module doc); nan when not estimated, 0 when configured
    std_s: float = math.nan

    def to_json(self) -> dict:
        """The estimate as reported (diagnosis report, status)."""
        return {
            "latency_s": round(self.latency_s, 4) if math.isfinite(self.latency_s) else None,
            "correlation": round(self.correlation, 4) if math.isfinite(self.correlation) else None,
            "determined": self.determined,
            "reason": self.reason,
            "epochs": self.epochs,
            "std_s": round(self.std_s, 4) if math.isfinite(self.std_s) else None,
        }


def _pearson(a: np.ndarray, b: np.ndarray) -> float:
    """Correlation coefficient of two equal-length samples (nan when one is constant)."""
    a = a - np.mean(a)
    b = b - np.mean(b)
    den = math.sqrt(float(np.sum(a * a) * np.sum(b * b)))
    return float(np.sum(a * b) / den) if den > 0 else math.nan


def _peak(lags: np.ndarray, corr: np.ndarray) -> float:
    """Lag (s) of the largest finite ``corr``, refined by the parabola through it and its
    finite neighbours (spacing may differ on the two sides); nan when none is finite."""
    ok = np.flatnonzero(np.isfinite(corr))
    if ok.size == 0:
        return math.nan
    k = int(np.argmax(corr[ok]))
    if k == 0 or k == ok.size - 1:
        return float(lags[ok[k]])
    x = lags[ok[k - 1 : k + 2]]
    y = corr[ok[k - 1 : k + 2]]
    h1, h2 = x[1] - x[0], x[2] - x[1]
    # vertex of the parabola through three points (x0, x1, x2)
    num = h2 * h2 * (y[1] - y[0]) - h1 * h1 * (y[1] - y[2])
    den = h1 * (y[1] - y[2]) + h2 * (y[1] - y[0])
    off = 0.5 * num / den if den > 0 else 0.0
    return float(x[1] + np.clip(off, -h1, h2))


def curvature_std(
    lags: np.ndarray, corr: np.ndarray, peak_s: float, r: float, epochs: int
) -> float:
    """Std (s) of the correlation peak from its curvature: sigma^2 = (1 - r^2) / (N r c)
    with r the peak correlation, N the epochs and c = -d2r/dtau2 (s^-2) of the parabola
    fitted to the correlations within ``CURVATURE_HALF_WIDTH_S`` of the peak; inf when
    that parabola is not concave (a flat correlation fixes nothing)."""
    near = np.isfinite(corr) & (np.abs(lags - peak_s) <= CURVATURE_HALF_WIDTH_S)
    if np.sum(near) < 3 or not r > 0:
        return math.inf
    x = lags[near] - peak_s
    q = float(np.polyfit(x, corr[near], 2)[0])
    c = -2.0 * q
    if not c > 0:
        return math.inf
    return math.sqrt(max(1.0 - r * r, 0.0) / (epochs * r * c))


def jackknife_std(
    lags: np.ndarray, mags: dict[int, np.ndarray], gnss_mag: np.ndarray, min_epochs: int
) -> float:
    """Delete-one-block jackknife std (s) of the correlation peak (module doc): ``mags``
    maps a lag index to the IMU |f| per epoch at that lag (m/s^2, nan where not covered),
    ``gnss_mag`` the GNSS |f| per epoch (m/s^2), epochs in time order."""
    k = gnss_mag.size
    blocks = np.array_split(np.arange(k), JACKKNIFE_BLOCKS)
    peaks = []
    for drop in blocks:
        keep = np.ones(k, dtype=bool)
        keep[drop] = False
        corr = np.full(lags.shape, np.nan)
        for i, m in mags.items():
            ok = keep & np.isfinite(m)
            if np.sum(ok) >= min_epochs:
                corr[i] = _pearson(m[ok], gnss_mag[ok])
        peaks.append(_peak(lags, corr))
    x = np.asarray(peaks)
    if not np.all(np.isfinite(x)):
        return math.nan
    n = x.size
    return math.sqrt((n - 1) / n * float(np.sum((x - np.mean(x)) ** 2)))


def unknown_latency_std(max_latency_s: float) -> float:
    """Std (s) of a latency known only to lie in the searched +-``max_latency_s`` (s):
    spread evenly over it."""
    return max_latency_s / math.sqrt(3.0)


def used_latency(est: LatencyEstimate, max_latency_s: float) -> tuple[float, float]:
    """(latency s, its std s) the checks use: the estimate and its std when determined;
    when not, the best estimate anyway with its std (the checks widen by it,
    :func:`latency_sigma`), with the std of a latency spread evenly over the searched
    +-``max_latency_s`` (s) where the correlation is flat (infinite std); with no
    estimate at all (or a peak at the edge), 0 s with that std."""
    if math.isfinite(est.latency_s) and not math.isnan(est.std_s):
        return est.latency_s, min(est.std_s, unknown_latency_std(max_latency_s))
    return 0.0, unknown_latency_std(max_latency_s)


def latency_sigma(t_mid: np.ndarray, mag: np.ndarray, std_s: float) -> np.ndarray:
    """Per-epoch std (m/s^2) of |f| from a latency known to ``std_s`` (s): std_s x
    |d|f|/dt| with d|f|/dt (m/s^3) the larger of the differences of the epochs' |f|
    (``mag``, m/s^2, at mid times ``t_mid``, s) to the previous and the next epoch; 0
    where neither can be formed or std_s is 0."""
    out = np.zeros(np.shape(mag))
    if not std_s > 0 or out.size < 2:
        return out
    with np.errstate(invalid="ignore", divide="ignore"):
        d = np.abs(np.diff(np.asarray(mag, dtype=float)) / np.diff(np.asarray(t_mid, float)))
    d = np.where(np.isfinite(d), d, 0.0)
    out[1:] = d
    out[:-1] = np.maximum(out[:-1], d)
    return std_s * out


def estimate_latency(
    t: np.ndarray,
    accel_si: np.ndarray,
    epochs: GnssEpochs,
    gyro_si: np.ndarray | None = None,
    max_latency_s: float = 1.0,
    step_s: float | None = None,
    min_correlation: float = 0.5,
    min_epochs: int = 20,
    max_std_s: float = LATENCY_TOLERANCE_S,
    series: ImuSeries | None = None,
) -> LatencyEstimate:
    """Latency (s) in [-max_latency_s, max_latency_s] maximising the |f| correlation, with
    its jackknife std (s); determined when the peak correlation is at least
    ``min_correlation`` and the std at most ``max_std_s`` (s) (module doc). ``series``: the
    record made once (:class:`.ImuSeries` of t, accel_si, gyro_si) when the caller has it."""
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
    if series is None:  # every lag cuts the same record: what does not depend on it, once
        series = ImuSeries(t, accel_si, gyro_si)
    corr = np.full(lags.shape, np.nan)
    done = np.zeros(lags.shape, dtype=bool)
    mags: dict[int, np.ndarray] = {}  #: the IMU |f| per epoch at each lag searched

    def correlate(indices: np.ndarray) -> None:
        for i in indices[~done[indices]]:
            done[i] = True
            im = series.epochs(use.t0, use.t1, latency_s=float(lags[i]), gyro_means=False)
            ok = np.isfinite(im.mag) & im.covered
            if np.sum(ok) < min_epochs:
                continue
            mags[int(i)] = np.where(ok, im.mag, np.nan)
            corr[i] = _pearson(im.mag[ok], use.mag[ok])

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
    std_jk = jackknife_std(lags, mags, use.mag, min_epochs)
    std_cv = curvature_std(lags, corr, lat, peak, len(use))
    stds = [s for s in (std_jk, std_cv) if not math.isnan(s)]
    std = STD_FACTOR * max(stds) if stds else math.inf
    reason = ""
    if peak < min_correlation:
        reason = f"peak correlation {peak:.2f} below {min_correlation:g}"
    elif math.isinf(std):
        reason = "the correlation is flat around its peak: the drive's |f| changes do not fix it"
    elif not std <= max_std_s:
        reason = (
            f"latency std {1e3 * std:.0f} ms above the {1e3 * max_std_s:g} ms tolerance: "
            "the drive's |f| changes do not fix it"
        )
    return LatencyEstimate(lat, peak, reason == "", reason, len(use), lags, corr, std)


__all__ = [
    "JACKKNIFE_BLOCKS",
    "LATENCY_TOLERANCE_S",
    "LatencyEstimate",
    "estimate_latency",
    "curvature_std",
    "jackknife_std",
    "latency_sigma",
    "unknown_latency_std",
    "used_latency",
]

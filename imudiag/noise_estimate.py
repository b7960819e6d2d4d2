"""The unit's white noise measured from its own data, robust to motion and steps.

One figure per channel, used wherever a command needs the noise of a real unit
(the quasi-static detector of ``calibrate`` and ``diagnose``, their reports and
the certificate ``calibrate`` writes), beside the certificate's figure, which
is a data-sheet value taken on trust and often wrong by a factor 1.5-3.

Method (``"median-second-difference"``): the second difference
``d[i] = x[i+1] - 2 x[i] + x[i-1]`` of white noise of standard deviation
``sigma`` has standard deviation ``sqrt(6) sigma``; smooth motion (a turn, a
drift, a slow tilt) contributes ``x'' dt^2``, which is tiny at IMU rates, and a
step or a bump only touches a few differences, which a median ignores. So per
chunk of ``chunk_s`` seconds ``sigma = 1.4826 MAD(d) / sqrt(6)``, and the
figure of a channel is a low quantile of its chunk values (the quietest
stretches, where nothing but noise moves the signal), divided by the value
that quantile has on pure white noise (:func:`quantile_bias`), so a still
record gives its sigma without bias. For a signal quantised in
steps ``q`` finer than its noise this is unbiased; where the noise is below one
step the MAD can be 0, and the plain RMS of ``d`` is used (floored at the
quantisation noise ``q / sqrt(12)`` when ``q`` is known).
Density ``= sigma / sqrt(rate / 2)`` (white noise band up to Nyquist), the
inverse of :meth:`imudiag.certificate.Triad.noise_sigma`.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from statistics import NormalDist

import numpy as np

from .kernels import kernel
from .stats import chi2_ratio_quantile

#: Name of the method, printed beside every measured figure.
METHOD = "median-second-difference"

#: Consistency constant of the MAD for a normal distribution.
_MAD_TO_SIGMA = 1.482602218505602

#: Measured / certificate noise ratio beyond which the certificate's noise is reported wrong.
NOISE_MISMATCH_FACTOR = 1.5

#: Variance inflation of a mean of squared second differences of white noise: their
#: correlations are -2/3 (lag 1) and 1/6 (lag 2), so 1 + 2 (4/9 + 1/36) = 35/18.
_SECOND_DIFFERENCE_INFLATION = 35.0 / 18.0


def quantile_bias(samples_per_chunk: int, quantile: float) -> float:
    """Expected ``quantile`` of chunk sigmas over the true sigma, for white noise.

    A chunk of ``n`` samples gives a sigma whose square is a chi-square ratio
    with ``(n - 2) / (35/18)`` effective degrees of freedom; the low quantile
    the meter takes to ignore motion is therefore below the true sigma (about
    7 % at 100 samples, 2 % at 1000 for the lower quartile), and the figure is
    divided by this factor (Wilson-Hilferty).
    """
    dof = max(samples_per_chunk - 2, 1) / _SECOND_DIFFERENCE_INFLATION
    return math.sqrt(chi2_ratio_quantile(dof, NormalDist().inv_cdf(quantile)))


def second_difference_sigma(x: np.ndarray) -> np.ndarray:
    """Robust per-column white-noise standard deviation of ``x`` (N, C), same units as ``x``.

    NaN for a column with fewer than 5 finite rows.
    """
    x = np.asarray(x, dtype=float)
    if x.ndim == 1:
        x = x[:, None]
    out = np.full(x.shape[1], np.nan)
    if x.shape[0] < 5:
        return out
    d = x[2:] - 2.0 * x[1:-1] + x[:-2]
    for c in range(x.shape[1]):
        dc = d[:, c]
        dc = dc[np.isfinite(dc)]
        if dc.size < 3:
            continue
        dc = dc - np.median(dc)
        mad = float(np.median(np.abs(dc)))
        # a first robust scale (the MAD; the RMS where quantisation makes it 0) sets a
        # 5-sigma clip; the RMS of what remains is the figure (continuous, unlike a
        # median of quantised values)
        s0 = _MAD_TO_SIGMA * mad if mad > 0 else float(np.sqrt(np.mean(dc * dc)))
        kept = dc[np.abs(dc) <= 5.0 * s0] if s0 > 0 else dc
        out[c] = float(np.sqrt(np.mean(kept * kept) / 6.0))
    return out


def medians(x: np.ndarray) -> np.ndarray:
    """The medians along the last axis of ``x`` (same units), equal to ``np.median``'s
    (NaN where a row holds one); ``x`` is partitioned in place. Rows of numbers take one
    partition and the mean of the middle values, without ``np.median``'s generic path:
    the monitor's noise check, medians of 1 s windows every 0.1 s, at half the cost.
    An even row is partitioned at its upper middle value only and its lower middle value
    is the largest below it: one selection, not two (numpy's partition at two positions
    is about 4x the cost of one; issue 14)."""
    n = x.shape[-1]
    if n == 0 or np.isnan(x).any():
        return np.median(x, axis=-1, overwrite_input=True)
    h = n // 2
    x.partition(h, axis=-1)
    if n % 2:
        return x[..., h].copy()
    return (x[..., :h].max(axis=-1) + x[..., h]) / 2.0


def second_difference_sigmas(chunks: np.ndarray) -> np.ndarray:
    """:func:`second_difference_sigma` of each of ``chunks`` (K, N, C), all finite, N >= 5,
    in a few numpy calls over all of them: (K, C), same units."""
    # the operations of second_difference_sigma in its order, in place on arrays of our
    # own; the medians along the samples from copies with that axis last (partitioned in
    # place); the sums along the samples as before (the same order of additions). The
    # RMS fallback is computed only where a MAD is 0, the clipping only where a value is
    # beyond the clip (still data: neither; issue 14)
    d = np.multiply(2.0, chunks[:, 1:-1])
    np.subtract(chunks[:, 2:], d, out=d)
    d += chunks[:, :-2]
    d -= medians(d.transpose(0, 2, 1).copy())[:, None, :]
    ad = np.abs(d)
    mad = medians(ad.transpose(0, 2, 1).copy())
    compiled = kernel("clipped_sigmas")
    if compiled is not None:  # the clipping and the sums below in one pass: the same values
        out: np.ndarray = compiled(d, mad, _MAD_TO_SIGMA)
        return out
    d2 = np.multiply(d, d, out=d)
    if (mad > 0).all():
        kept = ad <= 5.0 * (_MAD_TO_SIGMA * mad)[:, None, :]
    else:
        rms = np.sqrt(np.mean(d2, axis=1))
        s0 = np.where(mad > 0, _MAD_TO_SIGMA * mad, rms)
        kept = (ad <= 5.0 * s0[:, None, :]) | (s0 <= 0)[:, None, :]
    if kept.all():
        return np.sqrt(np.sum(d2, axis=1) / d2.shape[1] / 6.0)
    np.copyto(d2, 0.0, where=~kept)
    mean_kept = np.sum(d2, axis=1) / np.sum(kept, axis=1)
    return np.sqrt(mean_kept / 6.0)


@dataclass
class NoiseFigure:
    """Measured white noise of one triad: per-sample sigma and density, output units."""

    sigma: np.ndarray  #: (3,) per-sample standard deviation, output units
    density: np.ndarray  #: (3,) density, output units / sqrt(Hz)
    rate_hz: float  #: sample rate the figure was measured at (Hz)
    chunks: int  #: chunks the figure was taken from
    method: str = METHOD

    def as_dict(self) -> dict[str, object]:
        """JSON form: density (output units/sqrt(Hz)), sigma (output units), method."""
        return {
            "density": [float(v) for v in self.density],
            "sigma": [float(v) for v in self.sigma],
            "rate_hz": float(self.rate_hz),
            "chunks": int(self.chunks),
            "method": self.method,
        }


class NoiseMeter:
    """Streaming measurement of both triads' white noise, block by block.

    ``rate_hz``: sample rate (Hz); ``chunk_s``: chunk length (s);
    ``quantile``: which quantile of the chunk figures is the unit's noise (the
    quietest chunks are noise only; 0.25 ignores up to three quarters of the
    record in motion); ``quantum``: per-channel (6,) output quantisation step,
    or None; ``max_chunks``: keep only the last so many chunk figures (a
    running daemon measures over a sliding window of that many chunks).
    """

    def __init__(
        self,
        rate_hz: float,
        chunk_s: float = 1.0,
        quantile: float = 0.25,
        quantum: np.ndarray | None = None,
        max_chunks: int | None = None,
    ) -> None:
        if not rate_hz > 0:
            raise ValueError(f"rate_hz must be > 0, got {rate_hz!r}")
        self.rate_hz = float(rate_hz)
        self.chunk = max(8, int(round(chunk_s * self.rate_hz)))
        self.quantile = float(quantile)
        self.quantum = None if quantum is None else np.asarray(quantum, dtype=float)
        self._buf = np.zeros((0, 6))
        #: chunk figures kept: all, or the last ``max_chunks`` (a running daemon's window)
        self._chunks: deque[np.ndarray] = deque(maxlen=max_chunks)
        #: clean chunks measured so far (also those the window has dropped since): the
        #: result changes only when this does
        self.chunks_added = 0

    def update(self, gyro: np.ndarray, accel: np.ndarray, good: np.ndarray | None = None) -> None:
        """Add samples (N, 3) of each triad, output units; ``good`` (N,) marks usable rows."""
        x = np.concatenate([np.asarray(gyro, float), np.asarray(accel, float)], axis=1)
        if good is not None:
            x[~np.asarray(good, bool)] = np.nan  # (x: a new array of our own)
        buf = np.concatenate([self._buf, x]) if self._buf.size else x
        n = buf.shape[0] // self.chunk
        if n:
            parts = buf[: n * self.chunk].reshape(n, self.chunk, buf.shape[1])
            clean = np.isfinite(parts).all(axis=(1, 2))  # a chunk with a bad sample is left out
            if clean.any():
                figures = second_difference_sigmas(parts[clean])
                self._chunks.extend(figures)
                self.chunks_added += int(figures.shape[0])
        self._buf = buf[n * self.chunk :].copy()

    def gap(self) -> None:
        """Drop the unfinished chunk: the next samples do not follow the last ones."""
        self._buf = np.zeros((0, 6))

    def sample_sigma(self) -> np.ndarray:
        """(6,) per-sample sigma of gx gy gz ax ay az (output units); NaN before a chunk."""
        figures = self.result()
        if figures is None:
            return np.full(6, np.nan)
        return np.concatenate([figures["gyro"].sigma, figures["accel"].sigma])

    def result(self) -> dict[str, NoiseFigure] | None:
        """Measured noise per triad, or None when no complete clean chunk was seen."""
        if not self._chunks:
            return None
        figures = np.vstack(self._chunks)
        # np.quantile where no figure is NaN: the same partition and interpolation per
        # column as np.nanquantile, bit for bit, without its column-by-column Python loop
        # (a status line a second in the daemon: 0.1 ms instead of 0.7 ms)
        quantile = np.nanquantile if np.isnan(figures).any() else np.quantile
        sig = quantile(figures, self.quantile, axis=0)
        sig = sig / quantile_bias(self.chunk, self.quantile)
        if self.quantum is not None:
            sig = np.maximum(sig, self.quantum / math.sqrt(12.0))
        sig = np.where(np.isfinite(sig) & (sig > 0), sig, np.nan)
        band = math.sqrt(self.rate_hz / 2.0)
        out = {}
        for k, name in enumerate(("gyro", "accel")):
            s = sig[3 * k : 3 * k + 3]
            out[name] = NoiseFigure(s, s / band, self.rate_hz, len(self._chunks))
        return out


def compare(measured: np.ndarray, certified: np.ndarray | None) -> dict[str, object]:
    """Measured vs certificate density per axis: ratios and whether they disagree.

    ``disagrees`` is True when any axis differs by more than
    :data:`NOISE_MISMATCH_FACTOR` either way.
    """
    if certified is None:
        return {"certificate": None, "ratio": None, "disagrees": None}
    cert = np.asarray(certified, float)
    ratio = np.asarray(measured, float) / np.where(cert > 0, cert, np.nan)
    bad = (
        ~np.isfinite(ratio) | (ratio > NOISE_MISMATCH_FACTOR) | (ratio < 1 / NOISE_MISMATCH_FACTOR)
    )
    return {
        "certificate": [float(v) for v in cert],
        "ratio": [float(v) for v in ratio],
        "disagrees": bool(np.any(bad)),
    }


__all__ = [
    "METHOD",
    "NOISE_MISMATCH_FACTOR",
    "NoiseFigure",
    "NoiseMeter",
    "compare",
    "medians",
    "second_difference_sigma",
    "second_difference_sigmas",
]

"""Periodic disturbances: spectral lines above the noise floor, confirmed on held-out data.

On the first half of the session, each sensor's Welch PSD (of the quasi-static
residual) is compared bin by bin with a running median (the local noise
floor): an averaged periodogram of ``K`` segments is a chi-square variable of
about ``1.8 K`` degrees of freedom (Hann window, 50 % overlap), so every bin has
a significance, Bonferroni-corrected over all bins and sensors. At a
significant local maximum a sinusoid of amplitude A and frequency f is fitted
to the excess power with the exact spectral shape of the window. The line is
named when, on the second half, the PSD near f is explained better with the
line than without it (gamma log-likelihood of the averaged periodogram).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..stats import chi2_ratio_quantile, log_chi2_sf, z_from_log_p

SENSORS = ("gx", "gy", "gz", "ax", "ay", "az")
#: degrees of freedom of a Hann / 50 % Welch average, per segment (conservative)
EDF_PER_SEGMENT = 1.8
_HALF_WIDTH = 3  #: bins on each side of a line used for fitting and held-out scoring
_MEDIAN_BINS = 21


@dataclass
class Line:
    """A spectral line on one sensor."""

    sensor: str
    frequency: float  #: Hz
    amplitude: float  #: output units (sinusoid amplitude)
    significance: float  #: z, first half
    heldout: float  #: nats gained on the second half
    ratio: float  #: peak PSD / floor


def running_median(p: np.ndarray, width: int = _MEDIAN_BINS) -> np.ndarray:
    """Median over ``width`` neighbouring bins (edges: shrinking windows), per column."""
    n = p.shape[0]
    h = width // 2
    pad = np.concatenate([np.repeat(p[:1], h, axis=0), p, np.repeat(p[-1:], h, axis=0)])
    win = np.lib.stride_tricks.sliding_window_view(pad, width, axis=0)  # (n, cols, width)
    return np.median(win, axis=-1)[:n]


def line_shape(freq: np.ndarray, f: float, nperseg: int, rate_hz: float) -> np.ndarray:
    """Expected one-sided Welch PSD (per unit A^2) of ``A sin(2 pi f t)`` at bins ``freq``."""
    k = np.arange(nperseg)
    w = 0.5 - 0.5 * np.cos(2.0 * math.pi * k / nperseg)
    scale = 1.0 / (rate_hz * float(np.sum(w * w)))
    phase = 2.0 * math.pi * np.outer(f - freq, k) / rate_hz
    wf = (np.cos(phase) @ w) ** 2 + (np.sin(phase) @ w) ** 2
    phase2 = 2.0 * math.pi * np.outer(f + freq, k) / rate_hz
    wf2 = (np.cos(phase2) @ w) ** 2 + (np.sin(phase2) @ w) ** 2
    return 2.0 * scale * 0.25 * (wf + wf2)


def _floor(p: np.ndarray, dof: float) -> np.ndarray:
    """Noise floor: running median divided by the median of chi2(dof)/dof."""
    return running_median(p) / chi2_ratio_quantile(dof, 0.0)


def _fit_line(
    freq: np.ndarray, p: np.ndarray, floor: np.ndarray, k: int, nperseg: int, rate_hz: float
) -> tuple[float, float]:
    """(f Hz, A^2) of the sinusoid that best explains the excess around bin k."""
    df = freq[1] - freq[0]
    lo, hi = max(k - _HALF_WIDTH, 1), min(k + _HALF_WIDTH + 1, freq.shape[0])
    fb, pb, bb = freq[lo:hi], p[lo:hi], floor[lo:hi]
    best = (math.inf, float(freq[k]), 0.0)
    for f in np.linspace(freq[k] - 1.0 * df, freq[k] + 1.0 * df, 41):
        if f <= 0 or f >= rate_hz / 2:
            continue
        s = line_shape(fb, float(f), nperseg, rate_hz)
        w = 1.0 / bb**2
        a2 = max(float(np.sum(w * s * (pb - bb)) / max(float(np.sum(w * s * s)), 1e-300)), 0.0)
        cost = float(np.sum(w * (pb - bb - a2 * s) ** 2))
        if cost < best[0]:
            best = (cost, float(f), a2)
    return best[1], best[2]


def _gamma_loglik(p: np.ndarray, model: np.ndarray, dof: float) -> float:
    """Log-likelihood (up to a constant) of averaged periodogram values with ``dof``."""
    return float(-0.5 * dof * np.sum(np.log(model) + p / model))


def find_lines(
    fit: tuple[np.ndarray, np.ndarray, int],
    test: tuple[np.ndarray, np.ndarray, int],
    nperseg: int,
    rate_hz: float,
    z_min: float,
    max_lines: int,
    heldout_min: float = 0.0,
) -> tuple[list[Line], list[dict]]:
    """Lines found on ``fit`` (freq, PSD (F, 6), segments) and confirmed on ``test``.

    Returns the named lines and the strongest test per sensor (for the report).
    """
    freq, p1, k1 = fit
    _f2, p2, k2 = test
    lines: list[Line] = []
    tested: list[dict] = []
    if k1 == 0 or k2 == 0 or freq.shape[0] < 2 * _MEDIAN_BINS:
        return lines, tested
    dof1 = EDF_PER_SEGMENT * k1
    dof2 = EDF_PER_SEGMENT * k2
    floor1 = _floor(p1, dof1)
    floor2 = _floor(p2, dof2)
    n_bins = freq.shape[0]
    usable = np.arange(n_bins)
    usable = usable[(usable >= 3) & (usable <= n_bins - 3)]
    trials = float(usable.shape[0] * 6)
    for j, sensor in enumerate(SENSORS):
        ratio = p1[:, j] / np.maximum(floor1[:, j], 1e-300)
        # local maxima among usable bins
        cand = [
            k
            for k in usable.tolist()
            if ratio[k] >= ratio[k - 1] and ratio[k] >= ratio[k + 1] and ratio[k] > 1.0
        ]
        scored = []
        for k in cand:
            log_p = log_chi2_sf(dof1 * ratio[k], dof1) + math.log(trials)
            scored.append((z_from_log_p(min(log_p, 0.0)), k))
        scored.sort(reverse=True)
        if scored:
            z0, k0 = scored[0]
            tested.append(
                {
                    "name": "periodic_disturbance",
                    "sensor": sensor,
                    "significance": z0,
                    "frequency": float(freq[k0]),
                    "ratio": float(ratio[k0]),
                }
            )
        taken: list[int] = []
        for z, k in scored:
            if z < z_min or len(taken) >= max_lines:
                break
            if any(abs(k - o) <= 2 * _HALF_WIDTH for o in taken):
                continue
            f, a2 = _fit_line(freq, p1[:, j], floor1[:, j], k, nperseg, rate_hz)
            if a2 <= 0:
                continue
            lo, hi = max(k - _HALF_WIDTH, 1), min(k + _HALF_WIDTH + 1, n_bins)
            shape = line_shape(freq[lo:hi], f, nperseg, rate_hz)
            base = floor2[lo:hi, j]
            obs = p2[lo:hi, j]
            gain = _gamma_loglik(obs, base + a2 * shape, dof2) - _gamma_loglik(obs, base, dof2)
            tested[-1]["heldout"] = max(tested[-1].get("heldout", -math.inf), gain)
            if gain <= heldout_min:
                continue
            taken.append(k)
            lines.append(
                Line(
                    sensor=sensor,
                    frequency=f,
                    amplitude=math.sqrt(a2),
                    significance=z,
                    heldout=gain,
                    ratio=float(ratio[k]),
                )
            )
    return lines, tested


__all__ = ["Line", "find_lines", "line_shape", "running_median"]

"""Noise statistics of a sensor output: overlapping Allan deviation, PSD, noise identification.

Units: for a rate-like series ``y`` in output units u sampled at ``rate_hz``
(gyro counts, accelerometer counts, ...), the Allan deviation is in u, tau in s.
Identification follows IEEE Std 952 (Annex C) conventions:

- white noise (angle/velocity random walk) N, u/sqrt(Hz) (= u sqrt(s)): sigma(tau) = N / sqrt(tau),
  read on the slope -1/2 line at tau = 1 s. N^2 is the *two-sided* PSD level; the one-sided
  density of data sheets and of the certificate (per-sample sigma = density sqrt(rate/2))
  is ``sqrt(2) N``.
- bias instability B, u: the flat minimum of the curve divided by sqrt(2 ln 2 / pi) = 0.664.
- rate random walk K, u/sqrt(s): sigma(tau) = K sqrt(tau / 3), read on the slope +1/2 line
  at tau = 3 s (the certificate's ``bias_random_walk``).

The Allan deviation is computed from the cumulative sum (phase) exactly as
``allantools.oadev`` does (tests compare the two); the PSD is Welch's method with a
Hann window and 50 % overlap, one-sided, u^2/Hz.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .certificate import FLICKER_FACTOR  # 0.664, sigma floor / B (one definition)
from .certificate import markov_allan_shape as _markov_shape


@dataclass
class AllanResult:
    """Overlapping Allan deviation: tau (s), adev (u), error estimate adev/sqrt(n) (u),
    n the number of second differences averaged at each tau."""

    tau: np.ndarray
    adev: np.ndarray
    error: np.ndarray
    n: np.ndarray
    rate_hz: float
    samples: int

    @property
    def independent(self) -> np.ndarray:
        """Non-overlapping second differences at each tau (N // m - 1): the statistics' weight."""
        m = np.rint(self.tau * self.rate_hz).astype(np.int64)
        return np.maximum(self.samples // np.maximum(m, 1) - 1, 1)


def allan_m_values(
    n_samples: int, points_per_decade: int = 10, max_fraction: float = 0.5
) -> np.ndarray:
    """Log-spaced distinct cluster sizes m (tau = m / rate) from 1 to max_fraction * N."""
    m_max = max(1, int((n_samples - 1) * max_fraction))
    if m_max <= 1:
        return np.array([1], dtype=np.int64)
    k = int(math.ceil(math.log10(m_max) * points_per_decade)) + 1
    m = np.unique(np.round(np.logspace(0.0, math.log10(m_max), k)).astype(np.int64))
    return m[(m >= 1) & (m <= m_max)]


def overlapping_allan(
    y: np.ndarray,
    rate_hz: float,
    m: np.ndarray | None = None,
    points_per_decade: int = 10,
) -> AllanResult:
    """Overlapping Allan deviation of rate samples ``y`` (u) at ``rate_hz`` Hz.

    ``m``: cluster sizes (tau = m / rate_hz); default log-spaced, ``points_per_decade``
    per decade, up to half the record.
    """
    y = np.asarray(y, dtype=float).reshape(-1)
    n_samples = y.shape[0]
    if n_samples < 3:
        raise ValueError(f"Allan deviation needs at least 3 samples, got {n_samples}")
    if not np.all(np.isfinite(y)):
        raise ValueError("Allan deviation of non-finite samples")
    if m is None:
        m = allan_m_values(n_samples, points_per_decade)
    m = np.asarray(m, dtype=np.int64)
    m = m[(m >= 1) & (2 * m <= n_samples)]
    tau0 = 1.0 / float(rate_hz)
    # phase with a leading 0, after removing the mean (precision; second differences ignore it)
    x = np.empty(n_samples + 1)
    x[0] = 0.0
    np.cumsum(y - y.mean(), out=x[1:])
    x *= tau0
    adev = np.empty(m.shape[0])
    nterms = np.empty(m.shape[0], dtype=np.int64)
    buf = np.empty(n_samples + 1)  # one scratch array for every tau (no temporaries)
    for i, mj in enumerate(m.tolist()):  # one vectorised pass per tau
        # d = x[2m:] - 2 x[m:-m] + x[:-2m], in that order of operations (bit-identical)
        d = buf[: n_samples + 1 - 2 * mj]
        np.multiply(x[mj:-mj], 2.0, out=d)
        np.subtract(x[2 * mj :], d, out=d)
        np.add(d, x[: -2 * mj], out=d)
        nterms[i] = d.shape[0]
        adev[i] = math.sqrt(float(np.dot(d, d)) / (2.0 * d.shape[0])) / (mj * tau0)
    return AllanResult(
        tau=m * tau0,
        adev=adev,
        error=adev / np.sqrt(nterms),
        n=nterms,
        rate_hz=float(rate_hz),
        samples=n_samples,
    )


def theoretical_adev(
    tau: np.ndarray,
    white: float = 0.0,
    random_walk: float = 0.0,
    bias_instability: float = 0.0,
    quantization: float = 0.0,
    markov: tuple[float, float] | None = None,
) -> np.ndarray:
    """Allan deviation (u) of independent noise terms at ``tau`` (s).

    white N (u sqrt(s)): N^2/tau; random_walk K (u/sqrt(s)): K^2 tau / 3; bias_instability
    B (u): (0.664 B)^2; quantization Q (u s): 3 Q^2 / tau^2; markov (sigma u, T s):
    sigma^2 (T/tau)^2 (2 tau/T - 3 + 4 exp(-tau/T) - exp(-2 tau/T)).
    """
    tau = np.asarray(tau, dtype=float)
    var = white**2 / tau + random_walk**2 * tau / 3.0 + (FLICKER_FACTOR * bias_instability) ** 2
    var = var + 3.0 * quantization**2 / tau**2
    if markov is not None:
        sigma, tc = markov
        x = tau / tc
        var = var + sigma**2 * _markov_shape(x)
    return np.sqrt(var)


# ---------------------------------------------------------------------------
# power spectral density


@dataclass
class PSDResult:
    """One-sided PSD: frequency (Hz), density (u^2/Hz); ``segments`` averaged."""

    frequency: np.ndarray
    density: np.ndarray
    segments: int


def welch_psd(y: np.ndarray, rate_hz: float, nperseg: int | None = None) -> PSDResult:
    """Welch PSD: Hann window, 50 % overlap, mean removed per segment, one-sided (u^2/Hz).

    ``nperseg`` defaults to the largest power of two up to N/8 (at least 16, at most N).
    Same definition as ``scipy.signal.welch(..., scaling='density')``.
    """
    y = np.asarray(y, dtype=float).reshape(-1)
    n = y.shape[0]
    if n < 2:
        raise ValueError("PSD needs at least 2 samples")
    if nperseg is None:
        nperseg = 1 << max(4, int(math.log2(max(n // 8, 1))))
    nperseg = int(min(nperseg, n))
    step = max(nperseg // 2, 1)
    # periodic Hann window (scipy's default 'hann' for spectral analysis)
    k = np.arange(nperseg)
    window = 0.5 - 0.5 * np.cos(2.0 * math.pi * k / nperseg)
    scale = 1.0 / (rate_hz * np.sum(window**2))
    starts = np.arange(0, n - nperseg + 1, step)
    acc = np.zeros(nperseg // 2 + 1)
    batch = max(1, (1 << 22) // nperseg)  # bound the memory of one batch
    for b0 in range(0, starts.shape[0], batch):
        idx = starts[b0 : b0 + batch, None] + k[None, :]
        seg = y[idx]
        seg = seg - seg.mean(axis=1, keepdims=True)
        spec = np.fft.rfft(seg * window, axis=1)
        acc += np.sum(spec.real**2 + spec.imag**2, axis=0)
    p = acc / starts.shape[0] * scale
    if nperseg % 2 == 0:
        p[1:-1] *= 2.0
    else:
        p[1:] *= 2.0
    return PSDResult(np.fft.rfftfreq(nperseg, 1.0 / rate_hz), p, int(starts.shape[0]))


# ---------------------------------------------------------------------------
# identification


@dataclass
class NoiseTerms:
    """IEEE 952 readings of an Allan curve (units in the module docstring; None: not seen).

    white_noise N u/sqrt(Hz); density_one_sided = sqrt(2) N (the certificate's
    ``noise.density``); bias_instability B u with ``bias_instability_tau`` s and
    ``bias_floor`` (True when the minimum is a flat floor, otherwise B is an upper bound);
    random_walk K u/sqrt(s). ``*_taus`` the (low, high) tau range (s) each was read from.
    """

    white_noise: float | None
    density_one_sided: float | None
    bias_instability: float
    bias_instability_tau: float
    bias_floor: bool
    random_walk: float | None
    white_taus: tuple[float, float] | None = None
    random_walk_taus: tuple[float, float] | None = None
    fit: dict[str, float] = field(default_factory=dict)
    #: how N and K were read: "slope" (their slope region) or "fit" (the joint fit, used
    #: when the other terms leave no clean slope region but the term still dominates an end)
    sources: dict[str, str] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        """JSON-able form."""
        return {
            "white_noise": self.white_noise,
            "density_one_sided": self.density_one_sided,
            "bias_instability": self.bias_instability,
            "bias_instability_tau": self.bias_instability_tau,
            "bias_floor": self.bias_floor,
            "random_walk": self.random_walk,
            "white_taus": list(self.white_taus) if self.white_taus else None,
            "random_walk_taus": list(self.random_walk_taus) if self.random_walk_taus else None,
            "fit": dict(self.fit),
            "sources": dict(self.sources),
        }


def local_slopes(allan: AllanResult, half_width: int = 2) -> np.ndarray:
    """d log(adev) / d log(tau) at each point, a least-squares slope over +-half_width points."""
    lt, la = np.log10(allan.tau), np.log10(allan.adev)
    n = lt.shape[0]
    out = np.zeros(n)
    for i in range(n):  # one small fit per tau point (tens of points)
        a, b = max(0, i - half_width), min(n, i + half_width + 1)
        if b - a >= 2:
            out[i] = np.polyfit(lt[a:b], la[a:b], 1)[0]
    return out


def _line_reading(
    allan: AllanResult, mask: np.ndarray, slope: float, tau_read: float
) -> tuple[float, tuple[float, float]] | None:
    """Value at ``tau_read`` of the line of fixed ``slope`` through the masked points
    (log-domain mean weighted by the number of terms)."""
    if not np.any(mask):
        return None
    lt, la = np.log10(allan.tau[mask]), np.log10(allan.adev[mask])
    w = np.sqrt(allan.independent[mask].astype(float))  # ~ 1 / relative error
    intercept = float(np.sum(w * (la - slope * lt)) / np.sum(w))
    value = 10.0 ** (intercept + slope * math.log10(tau_read))
    return value, (float(allan.tau[mask].min()), float(allan.tau[mask].max()))


def _random_walk_reading(
    allan: AllanResult, ok: np.ndarray, slopes: np.ndarray, white: float | None, floor_var: float
) -> tuple[float, tuple[float, float]] | None:
    """K from the rising part of the curve: points with slope >= 0.2 where, after removing
    the white-noise variance N^2/tau and the flicker floor ``floor_var``, at least half the
    variance is left; each gives K = sqrt(3 rest / tau) (the +1/2 line read at tau = 3 s)."""
    var = allan.adev**2
    rest = var - (white**2 / allan.tau if white is not None else 0.0) - floor_var
    mask = ok & (slopes >= 0.2) & (rest >= 0.5 * var)
    if not np.any(mask):
        return None
    k = np.log(3.0 * rest[mask] / allan.tau[mask]) / 2.0
    w = np.sqrt(allan.independent[mask].astype(float))
    value = float(np.exp(np.sum(w * k) / np.sum(w)))
    return value, (float(allan.tau[mask].min()), float(allan.tau[mask].max()))


def identify_noise(allan: AllanResult, min_terms: int = 8, floor_terms: int = 100) -> NoiseTerms:
    """Read N, B and K from an Allan curve (IEEE Std 952), plus a least-squares model fit.

    N: the slope -1/2 region (local slope within +-0.1 of -1/2), read at tau = 1 s.
    K: the rising (slope +1/2) part with the white variance removed, read at tau = 3 s.
    B: the minimum / 0.664 over points with at least ``floor_terms`` independent
    differences. Otherwise points with at least ``min_terms`` independent
    (non-overlapping) differences are used. ``fit`` holds the non-negative least-squares
    fit of N, B, K and quantisation Q to the whole curve; N and K fall back on it when
    no clean slope region exists (``sources``).
    """
    ok = allan.independent >= min_terms
    slopes = local_slopes(allan)
    fit = fit_allan_terms(allan, min_terms=min_terms)
    rel = np.flatnonzero(ok) if np.any(ok) else np.arange(allan.tau.shape[0])
    var_lo, tau_lo = allan.adev[rel[0]] ** 2, allan.tau[rel[0]]
    var_hi, tau_hi = allan.adev[rel[-1]] ** 2, allan.tau[rel[-1]]
    sources: dict[str, str] = {}
    white = _line_reading(allan, ok & (np.abs(slopes + 0.5) <= 0.1), -0.5, 1.0)
    if white is not None:
        sources["white_noise"] = "slope"
    elif fit["white_noise"] ** 2 / tau_lo >= 0.5 * var_lo:  # white dominates the short end
        white = fit["white_noise"], (float(tau_lo), float(tau_lo))
        sources["white_noise"] = "fit"
    walk = _random_walk_reading(
        allan,
        ok,
        slopes,
        None if white is None else white[0],
        (FLICKER_FACTOR * fit["bias_instability"]) ** 2,
    )
    if walk is not None:
        sources["random_walk"] = "slope"
    elif fit["random_walk"] ** 2 * tau_hi / 3.0 >= 0.5 * var_hi:  # and the walk the long end
        walk = fit["random_walk"], (float(tau_hi), float(tau_hi))
        sources["random_walk"] = "fit"
    # the floor: the minimum over points averaging >= floor_terms independent differences
    # (the minimum of scattered estimates at long tau would be biased low)
    firm = allan.independent >= max(floor_terms, min_terms)
    cand = np.flatnonzero(firm) if np.any(firm) else rel
    i_min = int(cand[np.argmin(allan.adev[cand])])
    floor = allan.adev[i_min]
    near = ok & (allan.adev <= 1.2 * floor)
    span = np.log10(allan.tau[near].max() / allan.tau[near].min()) if np.any(near) else 0.0
    return NoiseTerms(
        white_noise=None if white is None else white[0],
        density_one_sided=None if white is None else math.sqrt(2.0) * white[0],
        bias_instability=float(floor / FLICKER_FACTOR),
        bias_instability_tau=float(allan.tau[i_min]),
        bias_floor=bool(span >= 1.0),
        random_walk=None if walk is None else walk[0],
        white_taus=None if white is None else white[1],
        random_walk_taus=None if walk is None else walk[1],
        fit=fit,
        sources=sources,
    )


def nnls_small(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Non-negative least squares for a few columns: the best feasible subset solution."""
    k = a.shape[1]
    best, best_cost = np.zeros(k), float(np.dot(b, b))
    for r in range(1, k + 1):
        for cols in itertools.combinations(range(k), r):
            sol, *_ = np.linalg.lstsq(a[:, cols], b, rcond=None)
            if np.any(sol < 0):
                continue
            x = np.zeros(k)
            x[list(cols)] = sol
            cost = float(np.sum((a @ x - b) ** 2))
            if cost < best_cost:
                best, best_cost = x, cost
    return best


def fit_allan_terms(allan: AllanResult, min_terms: int = 8) -> dict[str, float]:
    """Non-negative fit of sigma^2(tau) = N^2/tau + (0.664 B)^2 + K^2 tau/3 + 3 Q^2/tau^2,
    each point weighted by its relative error. Returns N, B, K, Q (units as above)."""
    ok = allan.independent >= min_terms
    if np.count_nonzero(ok) < 2:
        ok = np.ones_like(ok)
    tau, var = allan.tau[ok], allan.adev[ok] ** 2
    w = np.sqrt(allan.independent[ok].astype(float)) / var  # ~ 1 / error of var
    basis = np.stack([1.0 / tau, np.full_like(tau, FLICKER_FACTOR**2), tau / 3.0, 3.0 / tau**2], 1)
    coef = nnls_small(basis * w[:, None], var * w)
    return {
        "white_noise": math.sqrt(coef[0]),
        "bias_instability": math.sqrt(coef[1]),
        "random_walk": math.sqrt(coef[2]),
        "quantization": math.sqrt(coef[3]),
    }


def fit_gauss_markov(
    allan: AllanResult, min_terms: int = 8, with_white: bool = True
) -> tuple[float, float, float]:
    """Fit a first-order Gauss-Markov bias (sigma u, correlation time T s) plus white noise
    N (u sqrt(s)) to an Allan curve: grid over T, non-negative least squares for the rest.
    Returns (sigma, T, N)."""
    ok = allan.independent >= min_terms
    tau, var = allan.tau[ok], allan.adev[ok] ** 2
    w = np.sqrt(allan.independent[ok].astype(float)) / var

    def trial(tc: float) -> tuple[float, float, float, float]:
        """(cost, B, tau_c, white) of the fit at correlation time ``tc`` s."""
        cols = [_markov_shape(tau / tc)]
        if with_white:
            cols.append(1.0 / tau)
        a = np.stack(cols, 1)
        coef = nnls_small(a * w[:, None], var * w)
        cost = float(np.sum(((a @ coef) - var) ** 2 * w**2))
        return cost, math.sqrt(coef[0]), float(tc), math.sqrt(coef[1]) if with_white else 0.0

    grid = np.logspace(math.log10(tau.min() / 10.0), math.log10(tau.max() * 10.0), 161)
    # one small fit per trial; the sentinel stays if no fit has a finite cost
    best = min([(math.inf, 0.0, 1.0, 0.0), *(trial(tc) for tc in grid)], key=lambda r: r[0])
    # refine the correlation time around the best grid point
    refine = np.geomspace(best[2] / 1.06, best[2] * 1.06, 41)
    best = min([best, *(trial(tc) for tc in refine)], key=lambda r: r[0])
    return best[1], best[2], best[3]

"""The noise model the data support, from the Allan deviation of the longest still run.

Candidate models (every one has white noise N; u = output units):

- ``white``: N only;
- ``quantization``: N + quantisation Q (u s; Allan variance 3 Q^2 / tau^2: an integrating
  output counted in coarse steps. A rate output rounded sample by sample is white noise and
  stays ``white``);
- ``bias_instability``: N + flicker floor B (u);
- ``bias_drift``: N + rate random walk K (u/sqrt(s));
- ``rate_ramp``: N + rate ramp R (u/s; a steady drift of the bias, e.g. warming up);
- ``bias_instability+bias_drift``: N + B + K;
- ``bias_instability+rate_ramp``, ``bias_drift+rate_ramp``,
  ``bias_instability+bias_drift+rate_ramp``: the long-term terms jointly;
- ``gauss_markov``: N + first-order Gauss-Markov bias (sigma u, correlation time T s).

Selection on held-out data: the run is split in halves; each candidate is fitted on one
half's Allan curve and scored on the other's (both ways) by the Gaussian negative
log-likelihood of ln(adev) with variance 1 / (2 n_independent) per cluster time. A model
with more terms is kept only when it lowers that held-out score by ``z_min^2 / 2`` nats
per extra term (its likelihood-ratio significance is at least ``z_min``): the criterion
penalises extra terms. The chosen model is then fitted on the whole run, and its closed-form
Allan deviation (:meth:`imudiag.certificate.Noise.allan_deviation`) is compared with the
measured one at every cluster time from 0.1 s to a tenth of the run.

Each term of the chosen model carries a 95 % interval from the record length
(:func:`term_intervals`: the weighted least squares on the Allan variance, each point's
variance 2 / n_independent relative), and the report names the cluster times the record
supports (the measured deviation's 95 % interval within +-30 %).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..certificate import FLICKER_FACTOR, markov_allan_shape
from ..noise_stats import AllanResult, nnls_small, overlapping_allan

#: candidate models, simplest first, with the terms beyond white noise each adds
CANDIDATES: dict[str, tuple[str, ...]] = {
    "white": (),
    "quantization": ("quantization",),
    "bias_instability": ("bias_instability",),
    "bias_drift": ("bias_drift",),
    "gauss_markov": ("gauss_markov_sigma", "gauss_markov_time"),
    "rate_ramp": ("rate_ramp",),
    "bias_instability+bias_drift": ("bias_instability", "bias_drift"),
    # the long-term terms identified jointly (issue 29): a ramp beside a flicker floor or a
    # rate random walk, and all three
    "bias_instability+rate_ramp": ("bias_instability", "rate_ramp"),
    "bias_drift+rate_ramp": ("bias_drift", "rate_ramp"),
    "bias_instability+bias_drift+rate_ramp": ("bias_instability", "bias_drift", "rate_ramp"),
}
#: a cluster time is supported by the record when the 95 % interval of its measured Allan
#: deviation (1.96 / sqrt(2 n_independent)) is within this fraction
SUPPORTED_INTERVAL = 0.30
TAU_MIN_S = 0.1  #: s, shortest cluster time compared
MIN_RUN_S = 60.0  #: s, shorter still runs do not support a noise model (tau up to 6 s)
POINTS_PER_DECADE = 5
MAX_RATIO = 1.5  #: measured / predicted Allan deviation allowed, either way


def _worst_ratio(model: NoiseFit, allan: AllanResult, sel: np.ndarray) -> float:
    r = allan.adev[sel] / model.adev(allan.tau[sel])
    return float(np.max(np.maximum(r, 1.0 / r))) if r.shape[0] else 1.0


@dataclass
class NoiseFit:
    """One candidate fitted to an Allan curve: terms in u (white as the one-sided density)."""

    name: str
    terms: dict[str, float]

    def adev(self, tau: np.ndarray) -> np.ndarray:
        """Closed-form Allan deviation (u) at ``tau`` (s)."""
        return np.sqrt(_variance(self.terms, np.asarray(tau, dtype=float)))


def _variance(terms: dict[str, float], tau: np.ndarray) -> np.ndarray:
    var = terms.get("density", 0.0) ** 2 / 2.0 / tau
    var = var + 3.0 * terms.get("quantization", 0.0) ** 2 / tau**2
    var = var + (FLICKER_FACTOR * terms.get("bias_instability", 0.0)) ** 2
    var = var + terms.get("bias_drift", 0.0) ** 2 * tau / 3.0
    var = var + terms.get("rate_ramp", 0.0) ** 2 * tau**2 / 2.0
    if terms.get("gauss_markov_sigma"):
        var = var + terms["gauss_markov_sigma"] ** 2 * markov_allan_shape(
            tau / terms["gauss_markov_time"]
        )
    return var


def _window(allan: AllanResult, record_s: float) -> np.ndarray:
    """Cluster times compared: 0.1 s (or one sample) to a tenth of the record."""
    return (allan.tau >= max(TAU_MIN_S, allan.tau[0]) - 1e-12) & (
        allan.tau <= record_s / 10.0 + 1e-9
    )


def fit(name: str, allan: AllanResult, sel: np.ndarray) -> NoiseFit:
    """Fit candidate ``name`` to the selected points of ``allan`` (weighted non-negative
    least squares on the Allan variance; correlation time on a grid)."""
    tau, var = allan.tau[sel], allan.adev[sel] ** 2
    w = np.sqrt(allan.independent[sel].astype(float)) / var
    extra = CANDIDATES[name]
    cols = [1.0 / tau / 2.0]  # density^2 / 2 / tau
    keys = ["density"]
    if "quantization" in extra:
        cols.append(3.0 / tau**2)
        keys.append("quantization")
    if "bias_instability" in extra:
        cols.append(np.full_like(tau, FLICKER_FACTOR**2))
        keys.append("bias_instability")
    if "bias_drift" in extra:
        cols.append(tau / 3.0)
        keys.append("bias_drift")
    if "rate_ramp" in extra:
        cols.append(tau**2 / 2.0)
        keys.append("rate_ramp")
    if name != "gauss_markov":
        a = np.stack(cols, 1)
        coef = nnls_small(a * w[:, None], var * w)
        return NoiseFit(name, {k: math.sqrt(c) for k, c in zip(keys, coef, strict=True)})
    best: tuple[float, dict[str, float]] = (math.inf, {"density": 0.0})
    for tc in np.logspace(math.log10(tau.min() / 3.0), math.log10(tau.max() * 3.0), 49):
        a = np.stack([cols[0], markov_allan_shape(tau / tc)], 1)
        coef = nnls_small(a * w[:, None], var * w)
        cost = float(np.sum(((a @ coef) - var) ** 2 * w**2))
        if cost < best[0]:
            best = (
                cost,
                {
                    "density": math.sqrt(coef[0]),
                    "gauss_markov_sigma": math.sqrt(coef[1]),
                    "gauss_markov_time": float(tc),
                },
            )
    return NoiseFit(name, best[1])


def term_intervals(model: NoiseFit, allan: AllanResult, sel: np.ndarray) -> dict[str, list[float]]:
    """95 % interval [low, high] (u, as the terms) of each power-law term of ``model`` from
    the record: the covariance of the weighted linear fit of the Allan variance
    (relative standard error sqrt(2 / n_independent) per cluster time; overlapping cluster
    times are correlated, so the interval is a lower bound on the true one), the term the
    square root of its variance coefficient. Gauss-Markov terms get none."""
    keys = [
        k
        for k in ("density", "quantization", "bias_instability", "bias_drift", "rate_ramp")
        if k in model.terms
    ]
    tau = allan.tau[sel]
    basis = {
        "density": 1.0 / tau / 2.0,
        "quantization": 3.0 / tau**2,
        "bias_instability": np.full_like(tau, FLICKER_FACTOR**2),
        "bias_drift": tau / 3.0,
        "rate_ramp": tau**2 / 2.0,
    }
    if not keys or tau.shape[0] <= len(keys):
        return {}
    a = np.stack([basis[k] for k in keys], 1)
    sd = allan.adev[sel] ** 2 * np.sqrt(2.0 / np.maximum(allan.independent[sel], 1.0))
    aw = a / sd[:, None]
    try:
        cov = np.linalg.inv(aw.T @ aw)
    except np.linalg.LinAlgError:
        return {}
    out: dict[str, list[float]] = {}
    for i, k in enumerate(keys):
        c = model.terms[k] ** 2
        half = 1.96 * math.sqrt(max(float(cov[i, i]), 0.0))
        out[k] = [math.sqrt(max(c - half, 0.0)), math.sqrt(c + half)]
    return out


def supported_taus(allan: AllanResult, sel: np.ndarray) -> np.ndarray:
    """Mask (sel's points) of the cluster times whose measured Allan deviation has a 95 %
    interval within +-:data:`SUPPORTED_INTERVAL`."""
    ind = np.maximum(allan.independent[sel].astype(float), 1.0)
    return np.asarray(1.96 / np.sqrt(2.0 * ind) <= SUPPORTED_INTERVAL)


def nll(model: NoiseFit, allan: AllanResult, sel: np.ndarray) -> float:
    """Gaussian negative log-likelihood (nats, constants dropped) of ln(adev) at the
    selected points: variance 1 / (2 n_independent) each."""
    pred = model.adev(allan.tau[sel])
    with np.errstate(divide="ignore"):
        d = np.log(allan.adev[sel]) - np.log(np.maximum(pred, 1e-300))
    return float(np.sum(allan.independent[sel] * d * d))


@dataclass
class SensorNoise:
    """The selection for one sensor."""

    model: NoiseFit
    heldout_nll: dict[str, float]  #: nats per candidate (two-fold sum)
    whole_nll: dict[str, float]  #: nats per candidate fitted on the whole run, with penalty
    gain_nats: float  #: held-out nll of white minus that of the chosen model
    allan: AllanResult
    window: np.ndarray
    terms_named: list[str] = field(default_factory=list)
    #: the chosen model fitted on the first half of the run only (for scoring on the second)
    first_half: NoiseFit | None = None

    def significance(self) -> float:
        """Likelihood-ratio z of the chosen model against white noise."""
        return math.sqrt(max(2.0 * self.gain_nats, 0.0))

    def curves(self) -> dict[str, list[float]]:
        """tau (s), measured and predicted Allan deviation (u) and their ratio."""
        tau = self.allan.tau[self.window]
        meas = self.allan.adev[self.window]
        pred = self.model.adev(tau)
        ind = self.allan.independent[self.window].astype(float)
        return {
            "tau": tau.tolist(),
            "measured": meas.tolist(),
            "predicted": pred.tolist(),
            "ratio": (meas / pred).tolist(),
            # relative standard error of the measured deviation, 1 / sqrt(2 n_independent)
            "relative_error": (1.0 / np.sqrt(2.0 * ind)).tolist(),
        }


class NoNoiseSeen(ValueError):
    """The record does not vary at some compared cluster time (e.g. a still output that
    stays on one quantisation step): no noise model can be fitted to it."""


def select(y: np.ndarray, rate_hz: float, z_min: float = 5.0) -> SensorNoise:
    """Choose the noise model of a still series ``y`` (u) at ``rate_hz`` (Hz); raises
    :class:`NoNoiseSeen` when its Allan deviation is zero at a compared cluster time."""
    y = np.asarray(y, dtype=float)
    n = y.shape[0]
    halves = [y[: n // 2], y[n // 2 :]]
    curves = [overlapping_allan(h, rate_hz, points_per_decade=POINTS_PER_DECADE) for h in halves]
    sels = [_window(a, h.shape[0] / rate_hz) for a, h in zip(curves, halves, strict=True)]
    for a, sel in zip(curves, sels, strict=True):
        if not np.all(a.adev[sel] > 0):
            tau = float(a.tau[sel][np.argmin(a.adev[sel])])
            raise NoNoiseSeen(
                f"the output does not vary at a cluster time of {tau:.3g} s (stuck, or "
                "quantised in steps coarser than its noise): no noise model"
            )
    scores: dict[str, float] = {}
    for name in CANDIDATES:
        total = 0.0
        for k in (0, 1):
            m = fit(name, curves[k], sels[k])
            total += nll(m, curves[1 - k], sels[1 - k])
        scores[name] = total
    per_term = 0.5 * z_min**2  # nats each parameter beyond white noise must earn
    whole = overlapping_allan(y, rate_hz, points_per_decade=POINTS_PER_DECADE)
    win = _window(whole, n / rate_hz)
    fits = {name: fit(name, whole, win) for name in CANDIDATES}
    penalised = {name: nll(fits[name], whole, win) + per_term * _extra(name) for name in CANDIDATES}
    # a model must reproduce the measured curve within MAX_RATIO over the window: among the
    # candidates that do (all, if none does), the lowest penalised score
    worst = {name: _worst_ratio(fits[name], whole, win) for name in CANDIDATES}
    admissible = [m for m in CANDIDATES if worst[m] <= MAX_RATIO] or list(CANDIDATES)
    chosen = min(admissible, key=lambda name: (penalised[name], _extra(name)))
    if chosen != "white" and scores["white"] - scores[chosen] < per_term * _extra(chosen):
        chosen = "white"  # not confirmed on held-out data
    model = fits[chosen]
    named: list[str] = [
        t
        for t in ("quantization", "bias_instability", "bias_drift", "rate_ramp")
        if t in CANDIDATES[chosen]
    ]
    if chosen == "gauss_markov":
        named = ["gauss_markov"]
    return SensorNoise(
        model=model,
        heldout_nll=scores,
        whole_nll=penalised,
        gain_nats=scores["white"] - scores[chosen],
        allan=whole,
        window=win,
        terms_named=named,
        first_half=fit(chosen, curves[0], sels[0]),
    )


def _extra(name: str) -> int:
    """Parameters beyond white noise."""
    return len(CANDIDATES[name])


def agrees(ratio: np.ndarray, relative_error: np.ndarray) -> np.ndarray:
    """Per cluster time: measured / predicted within 1.5x, or within 2.5 standard errors of
    the measured Allan deviation (the longest cluster times average few terms)."""
    lr = np.abs(np.log(np.asarray(ratio, dtype=float)))
    return (lr <= math.log(MAX_RATIO)) | (lr <= 2.5 * np.asarray(relative_error, dtype=float))


def bin_means(y: np.ndarray, factor: int) -> np.ndarray:
    """Means of consecutive groups of ``factor`` rows (the tail dropped)."""
    if factor <= 1:
        return y
    n = (y.shape[0] // factor) * factor
    return y[:n].reshape(-1, factor, *y.shape[1:]).mean(axis=1)


#: how the noise model's white-noise density is obtained (the report names it beside the
#: figure; the model check's measured density is noise_estimate.METHOD's)
DENSITY_METHOD = (
    "Allan-curve fit beside the named terms (the figure the extended certificate carries; "
    "it equals the median-second-difference figure of comparison.noise_density where the "
    "model is white, and leaves out the quantisation that figure includes)"
)

UNITS = {
    "density": "u/sqrt(Hz) (one-sided white noise)",
    "quantization": "u s (quantisation Q: Allan variance 3 Q^2 / tau^2)",
    "bias_instability": "u (flicker floor B: Allan deviation 0.664 B)",
    "bias_drift": "u/sqrt(s) (rate random walk K, the certificate's bias_random_walk)",
    "rate_ramp": "u/s (rate ramp R, the certificate's rate_ramp)",
    "gauss_markov_sigma": "u",
    "gauss_markov_time": "s",
}


def report_entry(sn: SensorNoise, unit: str) -> dict[str, Any]:
    """The report's entry for one sensor (u replaced by ``unit``)."""
    c = sn.curves()
    ratio = np.asarray(c["ratio"])
    worst = float(np.max(np.maximum(ratio, 1.0 / ratio))) if ratio.shape[0] else None
    err = np.asarray(c["relative_error"])
    out = np.abs(np.log(ratio)) > math.log(MAX_RATIO)
    tau = np.asarray(c["tau"])
    sup = supported_taus(sn.allan, sn.window)
    return {
        "model": sn.model.name,
        "terms": dict(sn.model.terms),
        "terms_ci95": term_intervals(sn.model, sn.allan, sn.window),
        # the cluster times the record supports: measured 95 % interval within +-30 %
        "tau_supported_s": [float(tau[sup].min()), float(tau[sup].max())] if sup.any() else None,
        "density_method": DENSITY_METHOD,
        "units": {
            k: v.replace("u", unit, 1) if v.startswith("u") else v
            for k, v in UNITS.items()
            if k in sn.model.terms
        },
        "heldout_nll_nats": dict(sn.heldout_nll),
        "penalised_nll_nats": dict(sn.whole_nll),
        "heldout_loglik_gain_nats": sn.gain_nats,
        "allan": c,
        "allan_unit": unit,
        "max_ratio": worst,
        # cluster times where the prediction misses by more than 1.5x, and whether each miss
        # is within 2.5 standard errors of the measured deviation (then statistics, not model)
        "beyond_1_5": [
            {
                "tau": float(t),
                "ratio": float(r),
                "within_statistical_error": bool(abs(math.log(r)) <= 2.5 * e),
            }
            for t, r, e in zip(np.asarray(c["tau"])[out], ratio[out], err[out], strict=True)
        ],
    }


__all__ = [
    "CANDIDATES",
    "MIN_RUN_S",
    "NoNoiseSeen",
    "NoiseFit",
    "agrees",
    "SensorNoise",
    "bin_means",
    "fit",
    "nll",
    "report_entry",
    "select",
    "supported_taus",
    "term_intervals",
]


def longest_run(
    t_start: np.ndarray,
    t_end: np.ndarray,
    run: np.ndarray,
    accel: np.ndarray | None = None,
    max_gap_s: float = 2.0,
) -> tuple[float, float]:
    """(start, end) s of the longest still stretch of the chunks: consecutive still runs
    separated by less than ``max_gap_s`` whose accelerometer chunk means (``accel`` (C, 3))
    do not jump (less than 8 times the median change between neighbouring chunks) are one
    stretch: the quasi-static detector cuts a long still record at its false alarms."""
    order = np.argsort(t_start, kind="stable")
    t_start, t_end, run = t_start[order], t_end[order], run[order]
    acc = None if accel is None else np.asarray(accel, dtype=float)[order]
    same = run[1:] == run[:-1]
    thr = None
    if acc is not None and np.any(same):
        thr = 8.0 * np.median(np.abs(np.diff(acc, axis=0))[same], axis=0) + 1e-12
    best = (0.0, 0.0)
    a = float(t_start[0]) if t_start.shape[0] else 0.0
    for i in range(t_start.shape[0]):  # one step per chunk
        if i > 0 and not same[i - 1]:
            joined = t_start[i] - t_end[i - 1] <= max_gap_s and (
                thr is None or acc is None or bool(np.all(np.abs(acc[i] - acc[i - 1]) <= thr))
            )
            if not joined:
                a = float(t_start[i])
        b = float(t_end[i])
        if b - a > best[1] - best[0]:
            best = (a, b)
    return best


def run_samples(
    blocks: Any, t0: float, t1: float, rate_hz: float, bin_s: float = 0.05
) -> tuple[np.ndarray, float]:
    """Outputs (n, 6: gx gy gz ax ay az, u) of the samples with t0 <= t <= t1, as means of
    bins of at most ``bin_s`` s (bounded memory on long records), and the bin rate (Hz)."""
    factor = max(1, int(math.floor(rate_hz * bin_s)))
    parts: list[np.ndarray] = []
    carry = np.zeros((0, 6))
    for block in blocks:
        if len(block) == 0:
            continue
        sel = (block.t >= t0) & (block.t <= t1)
        if not np.any(sel):
            if block.t[0] > t1:
                break
            continue
        u = np.concatenate([carry, np.concatenate([block.gyro[sel], block.accel[sel]], 1)])
        k = (u.shape[0] // factor) * factor
        parts.append(bin_means(u[:k], factor))
        carry = u[k:]
    y = np.concatenate(parts) if parts else np.zeros((0, 6))
    return y, rate_hz / factor

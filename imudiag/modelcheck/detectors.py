"""Tests for the catalogue effects on a residual channel, with held-out confirmation.

For every channel (a gyro axis at rest, the accelerometer norm) the candidate
regressors of :mod:`.residuals` are tested by forward selection under the
random-walk GLS of :mod:`.kalman`:

- *significance*: the drop of the whitened chi-square when a candidate joins
  the model (nuisance and already selected effects projected out), scaled by
  the over-dispersion of the residuals when that exceeds 1, as a one-sided
  normal z (Bonferroni over the positions scanned for a step);
- *held-out gain*: two-fold cross-validation over alternate chunks: the
  coefficients are fitted on one half and the other half's predictive
  log-likelihood (nats) is compared with and without the candidate, summed
  over both folds.

A candidate is named when its significance reaches ``z_min`` and its held-out
gain is positive; the strongest enters the model and the search repeats. The
random-walk intensity (``bias_drift``) is re-estimated by profile likelihood
between rounds, so a wandering bias does not pass for a temperature effect or
a step, and is itself an effect when it exceeds the certificate's
``bias_random_walk`` significantly and predicts held-out chunks better.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .config import ModelCheckConfig
from .kalman import Innovations, orthonormal_basis, profile_loglik, run_filter
from .residuals import Candidate, Channel
from .stats import chi2_significance, log_chi2_sf, z_from_log_p


@dataclass
class Selected:
    """An effect that entered a channel's model."""

    candidate: Candidate
    cols: list[int]  #: its columns in the channel's design matrix
    significance: float
    heldout: float  #: nats gained on held-out chunks
    chi2: float = 0.0
    value: np.ndarray = field(default_factory=lambda: np.zeros(1))
    sigma: np.ndarray = field(default_factory=lambda: np.zeros(1))
    fold_values: list[np.ndarray] = field(default_factory=list)


@dataclass
class DriftResult:
    """Profile-likelihood estimate of the random-walk coefficient of one state sensor."""

    sensor: str
    value: float  #: K, output units / sqrt(s)
    low: float  #: about 1-sigma interval, output units / sqrt(s)
    high: float
    certificate: float
    significance: float
    heldout: float  #: nats
    first_half: float | None = None  #: K fitted on the first half in time


@dataclass
class ChannelResult:
    """Everything the extension and the report need from one channel."""

    channel: Channel
    selected: list[Selected]
    drift: list[DriftResult]
    k: np.ndarray  #: (d,) random-walk coefficients used, output units / sqrt(s)
    tested: list[dict]  #: the strongest test of every (effect, sensor), selected or not
    dispersion: float  #: chi-square per degree of freedom of the final whitened residual
    design: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))  #: (C, 1 + p) [y|cols]
    nuisance_cols: list[int] = field(default_factory=list)


# ---------------------------------------------------------------------------
# design matrix


def _design(ch: Channel) -> tuple[np.ndarray, list[int], list[list[int]]]:
    """Z = [y | nuisance | candidate columns], the nuisance indices and each candidate's."""
    cols = [ch.y[:, None], ch.nuisance]
    nuis = list(range(1, 1 + ch.nuisance.shape[1]))
    idx: list[list[int]] = []
    k = 1 + ch.nuisance.shape[1]
    for c in ch.candidates:
        cols.append(c.columns)
        idx.append(list(range(k, k + c.columns.shape[1])))
        k += c.columns.shape[1]
    return np.concatenate(cols, axis=1), nuis, idx


def _folds(n: int) -> list[np.ndarray]:
    """Alternate chunks: even and odd."""
    i = np.arange(n)
    return [i % 2 == 0, i % 2 == 1]


def _q(k: np.ndarray) -> np.ndarray:
    return np.atleast_2d(np.asarray(k, dtype=float) ** 2)


def _p0(ch: Channel) -> np.ndarray:
    hh = np.maximum(np.sum(ch.H * ch.H, axis=1), 1e-300)
    return np.full(ch.H.shape[1], 1e6 * float(np.median(ch.R / hh)))


# ---------------------------------------------------------------------------
# forward selection


@dataclass
class _Runs:
    """Innovations of the whole series and of each fold's fit."""

    all: Innovations
    folds: list[Innovations]
    fold_masks: list[np.ndarray]


def _runs(ch: Channel, z: np.ndarray, k: np.ndarray) -> _Runs:
    p0 = _p0(ch)
    q = _q(k)
    masks = _folds(len(ch))
    return _Runs(
        all=run_filter(ch.t, ch.H, ch.R, z, q, p0=p0),
        folds=[run_filter(ch.t, ch.H, ch.R, z, q, use=m, p0=p0) for m in masks],
        fold_masks=masks,
    )


def _lstsq(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    if a.shape[1] == 0:
        return np.zeros((0,) + b.shape[1:])
    return np.linalg.lstsq(a, b, rcond=1e-10)[0]


def _score_single(runs: _Runs, base: list[int], cand_cols: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, int]:
    """For single-column candidates: chi-square drop (P,), observability (P,), held-out
    gain (P,) in nats, the base residual chi-square and the base rank."""
    rows, w = runs.all.whitened()
    wy = w[:, 0]
    wb = w[:, base]
    qb = orthonormal_basis(wb)
    y_perp = wy - qb @ (qb.T @ wy)
    wc = w[:, cand_cols]
    c_perp = wc - qb @ (qb.T @ wc)
    cc = np.sum(c_perp * c_perp, axis=0)
    c_norm = np.sum(wc * wc, axis=0)
    observable = (cc > 1e-6 * np.maximum(c_norm, 1e-300)) & (cc > 0)
    chi2 = np.where(observable, (c_perp.T @ y_perp) ** 2 / np.where(cc > 0, cc, 1.0), 0.0)
    heldout = np.zeros(cand_cols.shape[0])
    for fit, mask in zip(runs.folds, runs.fold_masks, strict=True):
        f_rows, fw = fit.whitened()
        if f_rows.shape[0] == 0:
            continue
        fb = fw[:, base]
        g_y = _lstsq(fb, fw[:, 0])
        g_c = _lstsq(fb, fw[:, cand_cols])
        r_y = fw[:, 0] - (fb @ g_y if fb.shape[1] else 0.0)
        r_c = fw[:, cand_cols] - (fb @ g_c if fb.shape[1] else 0.0)
        den = np.sum(r_c * r_c, axis=0)
        beta = np.where(den > 0, (r_c.T @ r_y) / np.where(den > 0, den, 1.0), 0.0)
        ho = np.flatnonzero(runs.all.valid[0] & ~mask)
        if ho.shape[0] == 0:
            continue
        nu = runs.all.nu[0, ho]
        s = runs.all.S[0, ho]
        e0 = nu[:, 0] - (nu[:, base] @ g_y if base else 0.0)
        ec = nu[:, cand_cols] - (nu[:, base] @ g_c if base else 0.0)
        score0 = float(np.sum(e0 * e0 / s))
        resid = e0[:, None] - ec * beta[None, :]
        heldout += 0.5 * (score0 - np.sum(resid * resid / s[:, None], axis=0))
    return chi2, observable, heldout, float(y_perp @ y_perp), qb.shape[1]


def _score_multi(runs: _Runs, base: list[int], cols: list[int]
                 ) -> tuple[float, bool, float]:
    """Chi-square drop, observability and held-out gain of a multi-column candidate."""
    rows, w = runs.all.whitened()
    qb = orthonormal_basis(w[:, base])
    y_perp = w[:, 0] - qb @ (qb.T @ w[:, 0])
    wc = w[:, cols]
    c_perp = wc - qb @ (qb.T @ wc)
    qc = orthonormal_basis(c_perp, rtol=1e-6)
    col_ok = np.linalg.norm(c_perp, axis=0) > 1e-3 * np.maximum(np.linalg.norm(wc, axis=0),
                                                                 1e-300)
    observable = qc.shape[1] == len(cols) and bool(np.all(col_ok))
    proj = qc.T @ y_perp
    chi2 = float(proj @ proj)
    heldout = 0.0
    for fit, mask in zip(runs.folds, runs.fold_masks, strict=True):
        f_rows, fw = fit.whitened()
        ho = np.flatnonzero(runs.all.valid[0] & ~mask)
        if f_rows.shape[0] == 0 or ho.shape[0] == 0:
            continue
        nu = runs.all.nu[0, ho]
        s = runs.all.S[0, ho]
        g0 = _lstsq(fw[:, base], fw[:, 0])
        g1 = _lstsq(fw[:, base + cols], fw[:, 0])
        e0 = nu[:, 0] - (nu[:, base] @ g0 if base else 0.0)
        e1 = nu[:, 0] - nu[:, base + cols] @ g1
        heldout += 0.5 * float(np.sum(e0 * e0 / s) - np.sum(e1 * e1 / s))
    return chi2, observable, heldout


def _significance(chi2: float, resid_chi2: float, m: int, rank: int, dof: int,
                  trials: float) -> float:
    """z of a chi-square drop, scaled by the over-dispersion of what is left."""
    free = max(m - rank - dof, 1)
    phi = max(1.0, (resid_chi2 - chi2) / free)
    return chi2_significance(chi2 / phi, dof, trials)


_Score = tuple[int, float, float, float, bool]


def _deterministic_scores(ch: Channel, runs: _Runs, base: list[int], idx: list[list[int]],
                          active: list[bool], m: int) -> list[_Score]:
    """(candidate, chi-square drop, significance, held-out gain, observable) of every active
    deterministic candidate given the columns ``base``."""
    rows: list[_Score] = []
    single = [i for i, c in enumerate(ch.candidates) if active[i] and c.columns.shape[1] == 1]
    cols = np.array([idx[i][0] for i in single], dtype=int)
    chi2, obs, ho, resid, rank = _score_single(runs, base, cols)
    for j, i in enumerate(single):
        zz = (_significance(float(chi2[j]), resid, m, rank, 1, ch.candidates[i].trials)
              if obs[j] else 0.0)
        rows.append((i, float(chi2[j]), zz, float(ho[j]), bool(obs[j])))
    for i, c in enumerate(ch.candidates):
        if not active[i] or c.columns.shape[1] == 1:
            continue
        chi2_m, obs_m, ho_m = _score_multi(runs, base, idx[i])
        zz = (_significance(chi2_m, resid, m, rank, len(idx[i]), c.trials) if obs_m else 0.0)
        rows.append((i, chi2_m, zz, ho_m, obs_m))
    return rows


def _record(best: dict[tuple[str, str], dict], cand: Candidate, chi2: float, zz: float,
            ho: float, obs: bool) -> None:
    key = (cand.name, cand.sensor)
    if key not in best or zz > best[key]["significance"] or (
            zz == best[key]["significance"] and chi2 > best[key]["chi2"]):
        entry = {"name": cand.name, "triad": cand.triad, "sensor": cand.sensor,
                 "significance": zz, "heldout": ho, "chi2": chi2, "observable": obs}
        best[key] = entry


def _refine_step(ch: Channel, k: np.ndarray, base: list[int], z: np.ndarray,
                 cand: Candidate) -> tuple[Candidate, np.ndarray, float, float]:
    """Best boundary next to a step found on a strided scan: (candidate, its column,
    chi-square drop, held-out gain)."""
    b0, stride = int(cand.extra["boundary"]), int(cand.extra.get("stride", 1))
    j = list(ch.sensors).index(cand.sensor)
    n = len(ch)
    bounds = list(range(max(2, b0 - stride + 1), min(n - 1, b0 + stride)))
    idx = np.arange(n)
    new = np.stack([ch.H[:, j] * (idx >= b) for b in bounds], axis=1)
    zz = np.concatenate([z[:, [0] + base], new], axis=1)
    runs = _runs(ch, zz, k)
    cols = np.arange(1 + len(base), zz.shape[1])
    chi2, _obs, ho, _resid, _rank = _score_single(runs, list(range(1, 1 + len(base))), cols)
    best = int(np.argmax(chi2))
    out = Candidate(cand.name, cand.triad, cand.sensor, new[:, best:best + 1], cand.unit,
                    extra={"boundary": bounds[best], "stride": 1}, trials=cand.trials)
    return out, new[:, best], float(chi2[best]), float(ho[best])


# ---------------------------------------------------------------------------
# random walk (bias_drift)


def _reference_rows(ch: Channel, use: np.ndarray | None = None) -> np.ndarray:
    """Chunks that are not diffuse without any random walk (the fixed row set on which
    likelihoods of different K are compared)."""
    inn = run_filter(ch.t, ch.H, ch.R, ch.y[:, None], np.zeros((1, ch.H.shape[1])), use=use,
                     p0=_p0(ch))
    return inn.valid[0]


def _k_grid(ch: Channel, j: int) -> np.ndarray:
    """Trial K values (output units / sqrt(s)) for state sensor j."""
    h = np.abs(ch.H[:, j])
    seen = h > 0.2 * np.max(h) if np.max(h) > 0 else np.ones_like(h, dtype=bool)
    r_state = float(np.median(ch.R[seen] / h[seen] ** 2)) if np.any(seen) else 1.0
    span = max(float(ch.t[-1] - ch.t[0]), 1e-3) if len(ch) > 1 else 1.0
    dt = max(float(np.median(np.diff(ch.t))) if len(ch) > 1 else 1.0, 1e-3)
    lo = math.sqrt(0.003 * r_state / span)
    hi = math.sqrt(300.0 * r_state / dt)
    return np.concatenate([[0.0], np.geomspace(lo, hi, 25)])


def _profile_k(ch: Channel, z: np.ndarray, cols: list[int], k: np.ndarray, j: int,
               use: np.ndarray | None = None, mask: np.ndarray | None = None,
               extra: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Profile log-likelihood over K of state sensor j (others at ``k``)."""
    grid = _k_grid(ch, j)
    if extra is not None:
        grid = np.unique(np.concatenate([grid, [extra]]))
    q = np.repeat(_q(k), grid.shape[0], axis=0)
    q[:, j] = grid**2
    sub = z[:, [0] + cols]
    mask = _reference_rows(ch, use) if mask is None else mask & _reference_rows(ch, use)
    inn = run_filter(ch.t, ch.H, ch.R, sub, q, use=use, p0=_p0(ch))
    ll = profile_loglik(inn, list(range(1, sub.shape[1])), mask=mask)
    # refine around the maximum on a finer grid
    b = int(np.argmax(ll))
    lo = grid[max(b - 1, 0)]
    hi = grid[min(b + 1, grid.shape[0] - 1)]
    if hi > lo:
        fine = np.linspace(lo, hi, 9)
        qf = np.repeat(_q(k), fine.shape[0], axis=0)
        qf[:, j] = fine**2
        innf = run_filter(ch.t, ch.H, ch.R, sub, qf, use=use, p0=_p0(ch))
        llf = profile_loglik(innf, list(range(1, sub.shape[1])), mask=mask)
        grid = np.concatenate([grid, fine])
        ll = np.concatenate([ll, llf])
        order = np.argsort(grid)
        grid, ll = grid[order], ll[order]
    return grid, ll


def drift_test(ch: Channel, z: np.ndarray, cols: list[int], k: np.ndarray, j: int,
               heldout: bool = True) -> DriftResult:
    """Random walk of state sensor j beyond ``k[j]``: profile-likelihood estimate, its
    significance (likelihood ratio against ``k[j]``, boundary-corrected) and the held-out
    gain (K fitted on one fold of alternate chunks, predictive likelihood of the other)."""
    k_now = float(k[j])
    grid, ll = _profile_k(ch, z, cols, k, j, extra=k_now)
    best = int(np.argmax(ll))
    kj = float(grid[best])
    gain = float(ll[best]) - float(ll[int(np.argmin(np.abs(grid - k_now)))])
    inside = grid[ll >= ll[best] - 0.5]
    low, high = float(inside.min()), float(inside.max())
    if kj <= k_now or gain <= 0:
        z_val = 0.0
    else:
        z_val = z_from_log_p(min(log_chi2_sf(2.0 * gain, 1) + math.log(0.5), 0.0))
    ho_gain = 0.0
    if heldout and z_val > 0:
        ref_all = _reference_rows(ch)
        sub = z[:, [0] + cols]
        for mask in _folds(len(ch)):
            g_f, ll_f = _profile_k(ch, z, cols, k, j, use=mask, mask=mask, extra=k_now)
            k_f = float(g_f[int(np.argmax(ll_f))])
            q = np.repeat(_q(k), 2, axis=0)
            q[0, j], q[1, j] = k_now**2, k_f**2
            fit = run_filter(ch.t, ch.H, ch.R, sub, q, use=mask, p0=_p0(ch))
            full = run_filter(ch.t, ch.H, ch.R, sub, q, p0=_p0(ch))
            rows = np.flatnonzero(ref_all & ~mask)
            f_rows = np.flatnonzero(_reference_rows(ch, mask))
            scores = []
            for b in range(2):
                fw = fit.nu[b, f_rows] / np.sqrt(fit.S[b, f_rows])[:, None]
                g = _lstsq(fw[:, 1:], fw[:, 0])
                nu = full.nu[b, rows]
                s = full.S[b, rows]
                e = nu[:, 0] - (nu[:, 1:] @ g if len(cols) else 0.0)
                scores.append(-0.5 * float(np.sum(np.log(s) + e * e / s)))
            ho_gain += scores[1] - scores[0]
    return DriftResult(sensor=ch.sensors[j], value=kj, low=low, high=high,
                       certificate=float(ch.k_cert[j]), significance=z_val, heldout=ho_gain)


# ---------------------------------------------------------------------------
# a whole channel


def final_fit(ch: Channel, z: np.ndarray, cols: list[int], k: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray, float, list[np.ndarray]]:
    """GLS coefficients of ``cols`` on all chunks, their standard deviations (scaled by the
    over-dispersion), that dispersion, and the coefficients fitted on each fold."""
    runs = _runs(ch, z, k)
    _rows, w = runs.all.whitened()
    a = w[:, cols]
    beta = _lstsq(a, w[:, 0])
    resid = w[:, 0] - a @ beta if cols else w[:, 0]
    dof = max(w.shape[0] - len(cols), 1)
    disp = float(resid @ resid) / dof
    cov = np.linalg.pinv(a.T @ a) * max(disp, 1.0) if cols else np.zeros((0, 0))
    sigma = np.sqrt(np.maximum(np.diag(cov), 0.0))
    folds = []
    for fit in runs.folds:
        _r, fw = fit.whitened()
        folds.append(_lstsq(fw[:, cols], fw[:, 0]))
    return beta, sigma, disp, folds


def _deactivate(ch: Channel, active: list[bool], cand: Candidate) -> None:
    for j, other in enumerate(ch.candidates):
        if other.sensor != cand.sensor or other.name != cand.name:
            continue
        if cand.name != "bias_step" or abs(other.extra["boundary"] - cand.extra["boundary"]) <= 2:
            active[j] = False


def _backward(ch: Channel, z: np.ndarray, nuis: list[int], selected: list[Selected],
              k: np.ndarray, config: ModelCheckConfig) -> list[Selected]:
    """Drop selected effects that are no longer significant given all the others at ``k``."""
    while selected:
        runs = _runs(ch, z, k)
        m = int(runs.all.valid[0].sum())
        worst, worst_z = None, math.inf
        for s in selected:
            others = nuis + [c for o in selected if o is not s for c in o.cols]
            if len(s.cols) == 1:
                chi2, obs, ho, resid, rank = _score_single(runs, others, np.array(s.cols))
                zz = _significance(float(chi2[0]), resid, m, rank, 1, s.candidate.trials)
                ho_s = float(ho[0])
            else:
                chi2_m, _obs, ho_s = _score_multi(runs, others, s.cols)
                _c, _o, _h, resid, rank = _score_single(runs, others, np.zeros(0, dtype=int))
                zz = _significance(chi2_m, resid, m, rank, len(s.cols), s.candidate.trials)
            s.significance, s.heldout = zz, ho_s
            if zz < config.z_min or ho_s <= config.z_heldout:
                if zz < worst_z:
                    worst, worst_z = s, zz
        if worst is None:
            break
        selected = [s for s in selected if s is not worst]
    return selected


def analyse_channel(ch: Channel, config: ModelCheckConfig) -> ChannelResult:
    """Forward selection over the deterministic candidates and the random walk of every
    state sensor (the most significant first), a backward check, final values."""
    z, nuis, idx = _design(ch)
    k = np.array(ch.k_cert, dtype=float)
    if len(ch) < 6:
        return ChannelResult(channel=ch, selected=[], drift=[], k=k, tested=[],
                             dispersion=math.nan, design=z, nuisance_cols=nuis)
    selected: list[Selected] = []
    active = [True] * len(ch.candidates)
    drift_active = [bool(ch.drift_ok[j]) for j in range(k.shape[0])]
    drift_selected = [False] * k.shape[0]
    best_tests: dict[tuple[str, str], dict] = {}
    runs = _runs(ch, z, k)
    for _round in range(16):
        base = nuis + [c for s in selected for c in s.cols]
        m = int(runs.all.valid[0].sum())
        rows = _deterministic_scores(ch, runs, base, idx, active, m)
        for i, chi2_i, zz, ho_i, obs_i in rows:
            _record(best_tests, ch.candidates[i], chi2_i, zz, ho_i, obs_i)
        ok = [r for r in rows if r[4] and r[2] >= config.z_min and r[3] > config.z_heldout]
        det = max(ok, key=lambda r: (r[2], r[1])) if ok else None
        drifts = [(j, drift_test(ch, z, base, k, j, heldout=False))
                  for j in range(k.shape[0]) if drift_active[j]]
        drift_best = max(drifts, key=lambda d: d[1].significance) if drifts else None
        if drift_best is not None and drift_best[1].significance >= config.z_min and (
                det is None or drift_best[1].significance > det[2]):
            j = drift_best[0]
            res = drift_test(ch, z, base, k, j, heldout=True)
            if res.heldout > config.z_heldout:
                k[j] = res.value
                drift_selected[j] = True
            else:
                drift_active[j] = False
            runs = _runs(ch, z, k)
            continue
        if det is None:
            break
        i, chi2_i, zz, ho_i, _ = det
        cand = ch.candidates[i]
        new_cols = list(idx[i])
        if cand.name == "bias_step" and cand.extra.get("stride", 1) > 1:
            cand_r, col, chi2_r, ho_r = _refine_step(ch, k, base, z, cand)
            if chi2_r > chi2_i:
                cand, chi2_i, ho_i = cand_r, chi2_r, ho_r
                z = np.concatenate([z, col[:, None]], axis=1)
                new_cols = [z.shape[1] - 1]
        selected.append(Selected(candidate=cand, cols=new_cols, significance=zz,
                                 heldout=ho_i, chi2=chi2_i))
        _deactivate(ch, active, cand)
        runs = _runs(ch, z, k)
    selected = _backward(ch, z, nuis, selected, k, config)
    cols = nuis + [c for s in selected for c in s.cols]
    # final random-walk values: the estimate where drift was named, else the certificate's
    drift: list[DriftResult] = []
    k_cert = np.array(ch.k_cert, dtype=float)
    for j in range(k.shape[0]):
        if not ch.drift_ok[j]:
            continue
        k_test = k.copy()
        k_test[j] = k_cert[j]
        res = drift_test(ch, z, cols, k_test, j, heldout=drift_selected[j])
        if drift_selected[j]:
            k[j] = max(res.value, k_cert[j])
        drift.append(res)
    for j in range(k.shape[0]):
        if not drift_selected[j]:
            k[j] = k_cert[j]
    beta, sigma, disp, folds = final_fit(ch, z, cols, k)
    off = len(nuis)
    for s in selected:
        n = len(s.cols)
        s.value = beta[off:off + n]
        s.sigma = sigma[off:off + n]
        s.fold_values = [f[off:off + n] for f in folds]
        off += n
    for s in selected:
        _record(best_tests, s.candidate, s.chi2, s.significance, s.heldout, True)
    return ChannelResult(channel=ch, selected=selected, drift=drift, k=k,
                         tested=list(best_tests.values()), dispersion=disp, design=z,
                         nuisance_cols=nuis)


__all__ = [
    "ChannelResult",
    "DriftResult",
    "Selected",
    "analyse_channel",
    "drift_test",
    "final_fit",
]

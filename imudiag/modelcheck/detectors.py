"""Tests for the catalogue effects on a residual channel, with held-out confirmation.

For every channel (a gyro axis at rest, the accelerometer norm, the turns between
still runs) the candidate regressors of :mod:`.residuals` are tested by forward
selection under the random-walk GLS of :mod:`.kalman`:

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
random-walk intensity (``bias_drift``) competes in the same loop (profile
likelihood), so a wandering bias does not pass for a temperature effect or a
step, and is itself an effect when it exceeds the certificate's
``bias_random_walk`` significantly and predicts held-out chunks better. A
backward pass drops effects no longer significant in the final model.

Everything works on cross products of whitened innovations accumulated by the
filter (:func:`~.kalman.filter_products`): memory does not grow with the number
of chunks or of step positions scanned.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..stats import chi2_significance, log_chi2_sf, z_from_log_p
from .config import ModelCheckConfig
from .kalman import Products, filter_products, pinv_sym, run_filter
from .residuals import Candidate, Channel


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
    #: other sensors the data cannot tell from this one (same effect, correlated regressors)
    alternatives: list[str] = field(default_factory=list)


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
    gain: float = 0.0  #: log-likelihood gain over the K tested against, nats


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
# columns and filter runs


def candidate_columns(ch: Channel, cand: Candidate) -> np.ndarray:
    """The (C, k) regressors of a candidate (a step's are built from its boundary)."""
    if cand.columns is not None:
        return cand.columns
    idx = np.arange(len(ch))
    return (ch.H[:, int(cand.extra["axis"])] * (idx >= int(cand.extra["boundary"])))[:, None]


def _q(k: np.ndarray) -> np.ndarray:
    return np.atleast_2d(np.asarray(k, dtype=float) ** 2)


def _p0(ch: Channel) -> np.ndarray:
    hh = np.maximum(np.sum(ch.H * ch.H, axis=1), 1e-300)
    return np.full(ch.H.shape[1], 1e6 * float(np.median(ch.R / hh)))


def _reference_rows(ch: Channel, use: np.ndarray | None = None) -> np.ndarray:
    """Chunks that are not diffuse without any random walk (the fixed row set on which
    likelihoods of different K are compared)."""
    inn = run_filter(
        ch.t, ch.H, ch.R, ch.y[:, None], np.zeros((1, ch.H.shape[1])), use=use, p0=_p0(ch)
    )
    return inn.valid[0]


@dataclass
class _Ctx:
    """Per-channel constants: folds and the reference rows."""

    ch: Channel
    folds: list[np.ndarray]
    ref_all: np.ndarray
    ref_fold: list[np.ndarray]
    p0: np.ndarray

    @classmethod
    def of(cls, ch: Channel) -> _Ctx:
        folds = ch.folds()
        return cls(
            ch=ch,
            folds=folds,
            ref_all=_reference_rows(ch),
            ref_fold=[_reference_rows(ch, f) for f in folds],
            p0=_p0(ch),
        )


@dataclass
class _Runs:
    """Products of the whole series (groups: all, fold 0, fold 1 rows) and of each fold's
    own fit (group: its rows)."""

    all: Products
    fits: list[Products]


@dataclass
class _Cands:
    """Candidates laid out for a filter run: multi-column first (the block), then single
    non-step columns, then steps (generated by the filter)."""

    items: list[int]  #: candidate indices in that order
    spans: list[tuple[int, int]]  #: their column ranges in the candidate layout
    cand: np.ndarray | None
    step_axis: np.ndarray | None
    step_at: np.ndarray | None
    block_k: int


def _layout(ch: Channel, indices: list[int]) -> _Cands:
    columns = {
        i: c for i in indices if (c := ch.candidates[i].columns) is not None
    }  # regressor columns of each candidate; a bias step has none (built row by row)
    multi = [i for i in indices if i in columns and columns[i].shape[1] > 1]
    single = [i for i in indices if i in columns and columns[i].shape[1] == 1]
    steps = [i for i in indices if i not in columns]
    cols: list[np.ndarray] = []
    spans: list[tuple[int, int]] = []
    k = 0
    for i in multi + single:
        c = columns[i]
        cols.append(c)
        spans.append((k, k + c.shape[1]))
        k += c.shape[1]
    block_k = sum(columns[i].shape[1] for i in multi)
    for _i in steps:
        spans.append((k, k + 1))
        k += 1
    return _Cands(
        items=multi + single + steps,
        spans=spans,
        cand=np.concatenate(cols, axis=1) if cols else None,
        step_axis=(
            np.array([int(ch.candidates[i].extra["axis"]) for i in steps]) if steps else None
        ),
        step_at=(
            np.array([int(ch.candidates[i].extra["boundary"]) for i in steps]) if steps else None
        ),
        block_k=block_k,
    )


def _runs(ctx: _Ctx, head: np.ndarray, k: np.ndarray, lay: _Cands | None = None) -> _Runs:
    ch = ctx.ch
    kw: dict[str, Any] = {}
    if lay is not None:
        kw = {
            "cand": lay.cand,
            "step_axis": lay.step_axis,
            "step_at": lay.step_at,
            "block_k": lay.block_k,
        }
    groups = np.stack([ctx.ref_all, ctx.ref_all & ctx.folds[0], ctx.ref_all & ctx.folds[1]])
    q = _q(k)
    full = filter_products(ch.t, ch.H, ch.R, head, q, groups, p0=ctx.p0, **kw)
    fits = [
        filter_products(
            ch.t, ch.H, ch.R, head, q, ctx.ref_fold[f][None], use=ctx.folds[f], p0=ctx.p0, **kw
        )
        for f in (0, 1)
    ]
    return _Runs(all=full, fits=fits)


# ---------------------------------------------------------------------------
# scores from cross products


@dataclass
class _Base:
    """The head regression in one row group: y on the base columns."""

    m: np.ndarray  #: (h, h)
    a_inv: np.ndarray  #: pseudo-inverse of the base block
    gam: np.ndarray  #: base coefficients
    r_yy: float  #: residual chi-square
    rank: int


def _base(m: np.ndarray) -> _Base:
    a = m[1:, 1:]
    a_inv, rank = pinv_sym(a)
    gam = a_inv @ m[1:, 0]
    return _Base(m=m, a_inv=a_inv, gam=gam, r_yy=float(m[0, 0] - m[1:, 0] @ gam), rank=rank)


def _significance(
    chi2: float, resid_chi2: float, m: float, rank: int, dof: int, trials: float
) -> float:
    """z of a chi-square drop, scaled by the over-dispersion of what is left."""
    free = max(m - rank - dof, 1.0)
    phi = max(1.0, (resid_chi2 - chi2) / free)
    return chi2_significance(chi2 / phi, dof, trials)


def _single_scores(
    runs: _Runs, cols: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, _Base]:
    """For single candidate columns ``cols`` of the layout: chi-square drop, observability,
    held-out gain (nats), the partial residual r_jj, and the base fit (all rows)."""
    p = runs.all
    base = _base(p.head[0, 0])
    cx = p.cross[0, 0][cols]
    dg = p.diag[0, 0][cols]
    r_jy = cx[:, 0] - cx[:, 1:] @ base.gam
    r_jj = dg - np.sum((cx[:, 1:] @ base.a_inv) * cx[:, 1:], axis=1)
    observable = (r_jj > 1e-6 * np.maximum(dg, 1e-300)) & (r_jj > 0)
    chi2 = np.where(observable, r_jy**2 / np.where(observable, r_jj, 1.0), 0.0)
    heldout = np.zeros(cols.shape[0])
    for f in (0, 1):
        fit = runs.fits[f]
        fb = _base(fit.head[0, 0])
        fcx = fit.cross[0, 0][cols]
        fdg = fit.diag[0, 0][cols]
        g_f = fcx[:, 1:] @ fb.a_inv  # regressions of the candidates on the base, (c, |B|)
        f_jy = fcx[:, 0] - fcx[:, 1:] @ fb.gam
        f_jj = fdg - np.sum(g_f * fcx[:, 1:], axis=1)
        ok = f_jj > 1e-4 * np.maximum(fdg, 1e-300)  # the fold determines the candidate
        beta = np.where(ok, f_jy / np.where(ok, f_jj, 1.0), 0.0)
        o = 1 + (1 - f)  # the other fold's rows in the full run
        mo = p.head[0, o]
        cxo = p.cross[0, o][cols]
        dgo = p.diag[0, o][cols]
        theta0 = np.concatenate([[1.0], -fb.gam])
        v = mo @ theta0
        term1 = g_f @ v[1:] - cxo @ theta0
        quad = (
            np.sum((g_f @ mo[1:, 1:]) * g_f, axis=1) - 2.0 * np.sum(g_f * cxo[:, 1:], axis=1) + dgo
        )
        heldout += -0.5 * (2.0 * beta * term1 + beta**2 * quad)
    return chi2, observable, heldout, r_jj, base


def _full_matrix(p: Products, g: int, span: tuple[int, int], block: bool) -> np.ndarray:
    """The matrix over [head | candidate columns ``span``] in group g (block candidates)."""
    a, b = span
    mh = p.head[0, g]
    cx = p.cross[0, g][a:b]
    mjj = p.block[0, g][a:b, a:b] if block else np.diag(p.diag[0, g][a:b])
    return np.block([[mh, cx.T], [cx, mjj]])


def _multi_score(runs: _Runs, span: tuple[int, int]) -> tuple[float, bool, float, float, _Base]:
    """Chi-square drop, observability, held-out gain and estimate norm of a block
    candidate (several columns)."""
    p = runs.all
    base = _base(p.head[0, 0])
    m = _full_matrix(p, 0, span, True)
    h = base.m.shape[0]
    k = m.shape[0] - h
    c = m[h:, :h]
    r_jj = m[h:, h:] - c[:, 1:] @ base.a_inv @ c[:, 1:].T
    r_jy = c[:, 0] - c[:, 1:] @ base.gam
    r_inv, rank = pinv_sym(r_jj, rtol=1e-6)
    col_ok = np.diag(r_jj) > 1e-6 * np.maximum(np.diag(m[h:, h:]), 1e-300)
    observable = rank == k and bool(np.all(col_ok))
    chi2 = float(r_jy @ r_inv @ r_jy) if observable else 0.0
    beta = r_inv @ r_jy if observable else np.zeros(k)
    heldout = 0.0
    for f in (0, 1):
        mf = _full_matrix(runs.fits[f], 0, span, True)
        fb = _base(runs.fits[f].head[0, 0])
        full_inv, _r = pinv_sym(mf[1:, 1:], rtol=1e-8)
        r_f = mf[h:, h:] - mf[h:, 1:h] @ fb.a_inv @ mf[1:h, h:]
        if pinv_sym(r_f, rtol=1e-4)[1] < k:
            continue  # the fold cannot determine the candidate: no score from it
        coef = full_inv @ mf[1:, 0]
        mo = _full_matrix(p, 1 + (1 - f), span, True)
        theta0 = np.concatenate([[1.0], -fb.gam, np.zeros(k)])
        theta1 = np.concatenate([[1.0], -coef])
        heldout += 0.5 * float(theta0 @ mo @ theta0 - theta1 @ mo @ theta1)
    return chi2, observable, heldout, float(np.linalg.norm(beta)), base


# ---------------------------------------------------------------------------
# one selection round


_Score = tuple[int, float, float, float, bool]  # (candidate, chi2, z, heldout, passes)


def _scores(
    ch: Channel, runs: _Runs, lay: _Cands, active_rows: float, best: dict[tuple[str, str], dict]
) -> list[_Score]:
    """Scores of every candidate of the layout (recorded in ``best``)."""
    out: list[_Score] = []
    singles = [
        (pos, i) for pos, i in enumerate(lay.items) if lay.spans[pos][1] - lay.spans[pos][0] == 1
    ]
    resid, rank = None, 0
    if singles:
        cols = np.array([lay.spans[pos][0] for pos, _i in singles])
        chi2, obs, ho, _rjj, base = _single_scores(runs, cols)
        resid, rank = base.r_yy, base.rank
        for j, (_pos, i) in enumerate(singles):
            c = ch.candidates[i]
            zz = (
                _significance(float(chi2[j]), resid, active_rows, rank, 1, c.trials)
                if obs[j]
                else 0.0
            )
            out.append((i, float(chi2[j]), zz, float(ho[j]), bool(obs[j])))
    for pos, i in enumerate(lay.items):
        span = lay.spans[pos]
        if span[1] - span[0] == 1:
            continue
        c = ch.candidates[i]
        chi2_m, obs_m, ho_m, norm_m, base = _multi_score(runs, span)
        resid, rank = base.r_yy, base.rank
        zz = (
            _significance(chi2_m, resid, active_rows, rank, span[1] - span[0], c.trials)
            if obs_m
            else 0.0
        )
        # an estimate below what a known confounder can produce does not count
        out.append((i, chi2_m, zz, ho_m, obs_m and norm_m >= c.min_norm))
        if obs_m and norm_m < c.min_norm:
            c.extra["below_confounder"] = True
    for i, chi2_i, zz, ho_i, obs_i in out:
        _record(best, ch.candidates[i], chi2_i, zz, ho_i, obs_i)
    return out


def _record(
    best: dict[tuple[str, str], dict], cand: Candidate, chi2: float, zz: float, ho: float, obs: bool
) -> None:
    key = (cand.name, cand.sensor)
    if (
        key not in best
        or zz > best[key]["significance"]
        or (zz == best[key]["significance"] and chi2 > best[key]["chi2"])
    ):
        entry = {
            "name": cand.name,
            "triad": cand.triad,
            "sensor": cand.sensor,
            "significance": zz,
            "heldout": ho,
            "chi2": chi2,
            "observable": obs,
        }
        if cand.extra.get("below_confounder"):
            entry["observable"] = True
            entry["note"] = "smaller than what Earth rate can produce (heading unknown)"
        best[key] = entry


def _refine_step(
    ctx: _Ctx, head: np.ndarray, k: np.ndarray, cand: Candidate
) -> tuple[Candidate, float, float]:
    """Best boundary next to a step found on a strided scan: (candidate, chi-square drop,
    held-out gain)."""
    ch = ctx.ch
    b0, stride = int(cand.extra["boundary"]), int(cand.extra.get("stride", 1))
    bounds = list(range(max(2, b0 - stride + 1), min(len(ch) - 1, b0 + stride)))
    news = [
        Candidate(
            cand.name,
            cand.triad,
            cand.sensor,
            None,
            cand.unit,
            extra=dict(cand.extra, boundary=b, stride=1),
            trials=cand.trials,
        )
        for b in bounds
    ]
    tmp = Channel(**{**ch.__dict__, "candidates": news})
    lay = _layout(tmp, list(range(len(news))))
    runs = _runs(ctx, head, k, lay)
    cols = np.array([lay.spans[p][0] for p in range(len(news))])
    chi2, _obs, ho, _rjj, _base_fit = _single_scores(runs, cols)
    best = int(np.argmax(chi2))
    return news[lay.items[best]], float(chi2[best]), float(ho[best])


def _alternatives(
    ctx: _Ctx, head: np.ndarray, k: np.ndarray, i: int, chi2_i: float, rows: list[_Score]
) -> list[str]:
    """Sensors whose candidate of the same effect fits about as well (chi-square within 9)
    with strongly correlated regressors (|r| > 0.9 after the model so far): the data
    cannot say which of them it is."""
    ch = ctx.ch
    cand = ch.candidates[i]
    if candidate_columns(ch, cand).shape[1] != 1:
        return []
    others = [
        r[0]
        for r in rows
        if r[0] != i
        and r[4]
        and r[1] >= chi2_i - 9.0
        and ch.candidates[r[0]].name == cand.name
        and ch.candidates[r[0]].sensor != cand.sensor
        and candidate_columns(ch, ch.candidates[r[0]]).shape[1] == 1
    ]
    if not others:
        return []
    lay = _layout(ch, others)
    cols = np.array([lay.spans[p][0] for p in range(len(others))])
    r_before = _single_scores(_runs(ctx, head, k, lay), cols)[3]
    head2 = np.concatenate([head, candidate_columns(ch, cand)], axis=1)
    r_after = _single_scores(_runs(ctx, head2, k, lay), cols)[3]
    out: list[str] = []
    for pos, idx in enumerate(lay.items):
        rho2 = 1.0 - r_after[pos] / max(r_before[pos], 1e-300)
        sensor = ch.candidates[idx].sensor
        if rho2 > 0.81 and sensor not in out:
            out.append(sensor)
    return out


# ---------------------------------------------------------------------------
# random walk (bias_drift)


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


def _loglik(p: Products, g: int) -> np.ndarray:
    """Profile log-likelihood (B,) of y with the head regressors concentrated out."""
    out = np.empty(p.head.shape[0])
    for b in range(p.head.shape[0]):  # a few tens of grid points
        out[b] = -0.5 * (float(p.log_s[b, g]) + _base(p.head[b, g]).r_yy)
    return out


def profile_k(
    ctx: _Ctx,
    head: np.ndarray,
    k: np.ndarray,
    j: int,
    use: np.ndarray | None = None,
    rows: np.ndarray | None = None,
    extra: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Profile log-likelihood over K of state sensor j (others at ``k``), on ``rows``."""
    ch = ctx.ch
    grid = _k_grid(ch, j)
    if extra is not None:
        grid = np.unique(np.concatenate([grid, [extra]]))
    rows = ctx.ref_all if rows is None else rows

    def run(g: np.ndarray) -> np.ndarray:
        q = np.repeat(_q(k), g.shape[0], axis=0)
        q[:, j] = g**2
        return _loglik(
            filter_products(ch.t, ch.H, ch.R, head, q, rows[None], use=use, p0=ctx.p0), 0
        )

    ll = run(grid)
    b = int(np.argmax(ll))
    lo, hi = grid[max(b - 1, 0)], grid[min(b + 1, grid.shape[0] - 1)]
    if hi > lo:  # refine around the maximum
        fine = np.linspace(lo, hi, 9)
        grid = np.concatenate([grid, fine])
        ll = np.concatenate([ll, run(fine)])
        order = np.argsort(grid)
        grid, ll = grid[order], ll[order]
    return grid, ll


def k_on_rows(res: ChannelResult, j: int, use: np.ndarray) -> float:
    """Random-walk coefficient of state sensor j fitted on the chunks ``use`` only (with the
    channel's final model), output units / sqrt(s)."""
    ctx = _Ctx.of(res.channel)
    rows = _reference_rows(res.channel, use)
    grid, ll = profile_k(ctx, res.design, res.k, j, use=use, rows=rows)
    return float(grid[int(np.argmax(ll))])


def drift_test(
    ctx: _Ctx, head: np.ndarray, k: np.ndarray, j: int, heldout: bool = True
) -> DriftResult:
    """Random walk of state sensor j beyond ``k[j]``: profile-likelihood estimate, its
    significance (likelihood ratio against ``k[j]``, boundary-corrected) and the held-out
    gain (K fitted on one fold of alternate chunks, predictive likelihood of the other)."""
    ch = ctx.ch
    k_now = float(k[j])
    grid, ll = profile_k(ctx, head, k, j, extra=k_now)
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
        for f, mask in enumerate(ctx.folds):
            g_f, ll_f = profile_k(ctx, head, k, j, use=mask, rows=ctx.ref_fold[f], extra=k_now)
            k_f = float(g_f[int(np.argmax(ll_f))])
            q = np.repeat(_q(k), 2, axis=0)
            q[0, j], q[1, j] = k_now**2, k_f**2
            fit = filter_products(
                ch.t, ch.H, ch.R, head, q, ctx.ref_fold[f][None], use=mask, p0=ctx.p0
            )
            full = filter_products(
                ch.t, ch.H, ch.R, head, q, (ctx.ref_all & ~mask)[None], p0=ctx.p0
            )
            scores = []
            for b in range(2):
                gam = _base(fit.head[b, 0]).gam
                theta = np.concatenate([[1.0], -gam])
                scores.append(
                    -0.5 * (float(full.log_s[b, 0]) + float(theta @ full.head[b, 0] @ theta))
                )
            ho_gain += scores[1] - scores[0]
    return DriftResult(
        sensor=ch.sensors[j],
        value=kj,
        low=low,
        high=high,
        certificate=float(ch.k_cert[j]),
        significance=z_val,
        heldout=ho_gain,
        gain=max(gain, 0.0),
    )


# ---------------------------------------------------------------------------
# a whole channel


def final_fit(
    ctx: _Ctx, head: np.ndarray, k: np.ndarray
) -> tuple[np.ndarray, np.ndarray, float, list[np.ndarray]]:
    """GLS coefficients of the head regressors on all chunks, their standard deviations
    (scaled by the over-dispersion), that dispersion, and the coefficients of each fold."""
    runs = _runs(ctx, head, k)
    base = _base(runs.all.head[0, 0])
    dof = max(runs.all.rows[0] - base.rank, 1.0)
    disp = base.r_yy / dof
    sigma = np.sqrt(np.maximum(np.diag(base.a_inv), 0.0) * max(disp, 1.0))
    folds = [_base(f.head[0, 0]).gam for f in runs.fits]
    return base.gam, sigma, disp, folds


def _deactivate(ch: Channel, active: list[bool], cand: Candidate) -> None:
    for j, other in enumerate(ch.candidates):
        if other.sensor != cand.sensor or other.name != cand.name:
            continue
        if cand.name != "bias_step" or abs(other.extra["boundary"] - cand.extra["boundary"]) <= 2:
            active[j] = False


def _head(ch: Channel, selected: list[Selected]) -> np.ndarray:
    """[y | nuisance | selected effects' columns]."""
    parts = [ch.y[:, None], ch.nuisance] + [candidate_columns(ch, s.candidate) for s in selected]
    return np.concatenate(parts, axis=1)


def _backward(
    ctx: _Ctx, selected: list[Selected], k: np.ndarray, config: ModelCheckConfig
) -> list[Selected]:
    """Drop selected effects that are no longer significant given all the others at ``k``."""
    ch = ctx.ch
    while selected:
        worst, worst_z = None, math.inf
        for s in selected:
            others = [o for o in selected if o is not s]
            tmp = Channel(**{**ch.__dict__, "candidates": [s.candidate]})
            lay = _layout(tmp, [0])
            runs = _runs(ctx, _head(ch, others), k, lay)
            rows = _scores(tmp, runs, lay, float(runs.all.rows[0]), {})
            _i, chi2, zz, ho, _ok = rows[0]
            s.significance, s.heldout, s.chi2 = zz, ho, chi2
            if (zz < config.z_min or ho <= config.z_heldout) and zz < worst_z:
                worst, worst_z = s, zz
        if worst is None:
            break
        selected = [s for s in selected if s is not worst]
    return selected


def analyse_channel(ch: Channel, config: ModelCheckConfig) -> ChannelResult:
    """Forward selection over the deterministic candidates and the random walk of every
    state sensor, a backward check, final values."""
    k = np.array(ch.k_cert, dtype=float)
    nuis = list(range(1, 1 + ch.nuisance.shape[1]))
    if len(ch) < 6:
        return ChannelResult(
            channel=ch,
            selected=[],
            drift=[],
            k=k,
            tested=[],
            dispersion=math.nan,
            design=_head(ch, []),
            nuisance_cols=nuis,
        )
    ctx = _Ctx.of(ch)
    selected: list[Selected] = []
    active = [True] * len(ch.candidates)
    drift_active = [bool(ch.drift_ok[j]) for j in range(k.shape[0])]
    drift_selected = [False] * k.shape[0]
    best_tests: dict[tuple[str, str], dict] = {}
    for _round in range(16):
        head = _head(ch, selected)
        lay = _layout(ch, [i for i, a in enumerate(active) if a])
        runs = _runs(ctx, head, k, lay)
        rows = _scores(ch, runs, lay, float(runs.all.rows[0]), best_tests)
        ok = [r for r in rows if r[4] and r[2] >= config.z_min and r[3] > config.z_heldout]
        det = max(ok, key=lambda r: (r[2], r[1])) if ok else None
        drifts = [
            (j, drift_test(ctx, head, k, j, heldout=False))
            for j in range(k.shape[0])
            if drift_active[j]
        ]
        drift_best = max(drifts, key=lambda d: d[1].significance) if drifts else None
        # a random walk "explains" a smooth temperature effect or a step too: it must beat
        # the best deterministic effect by ``drift_margin`` nats of likelihood (a step pays
        # for the positions scanned); a wrongly chosen effect is dropped by the backward check
        det_nats = -math.inf
        if det is not None:
            det_nats = 0.5 * det[1] - math.log(max(ch.candidates[det[0]].trials, 1.0))
        if (
            drift_best is not None
            and drift_best[1].significance >= config.z_min
            and (drift_best[1].gain > det_nats + config.drift_margin)
        ):
            j = drift_best[0]
            res = drift_test(ctx, head, k, j, heldout=True)
            if res.heldout > config.z_heldout:
                k[j] = res.value
                drift_selected[j] = True
            else:
                drift_active[j] = False
            continue
        if det is None:
            break
        i, chi2_i, zz, ho_i, _ = det
        cand = ch.candidates[i]
        if cand.name == "bias_step" and cand.extra.get("stride", 1) > 1:
            cand_r, chi2_r, ho_r = _refine_step(ctx, head, k, cand)
            if chi2_r > chi2_i:
                cand, chi2_i, ho_i = cand_r, chi2_r, ho_r
        alt = _alternatives(ctx, head, k, i, chi2_i, rows)
        if cand.name == "bias_step":  # boundaries the data cannot tell from the best one
            near = [
                ch.candidates[r[0]].extra["boundary"]
                for r in rows
                if ch.candidates[r[0]].name == "bias_step"
                and ch.candidates[r[0]].sensor == cand.sensor
                and r[1] >= chi2_i - 9.0
            ]
            near.append(cand.extra["boundary"])
            cand = Candidate(
                cand.name,
                cand.triad,
                cand.sensor,
                None,
                cand.unit,
                extra=dict(cand.extra, boundary_range=(min(near), max(near))),
                trials=cand.trials,
            )
        selected.append(
            Selected(
                candidate=cand,
                cols=[],
                significance=zz,
                heldout=ho_i,
                chi2=chi2_i,
                alternatives=alt,
            )
        )
        _deactivate(ch, active, cand)
    selected = _backward(ctx, selected, k, config)
    # final random-walk values: the estimate where drift was named, else the certificate's
    drift: list[DriftResult] = []
    k_cert = np.array(ch.k_cert, dtype=float)
    head = _head(ch, selected)
    for j in range(k.shape[0]):
        if not ch.drift_ok[j]:
            continue
        k_test = k.copy()
        k_test[j] = k_cert[j]
        res = drift_test(ctx, head, k_test, j, heldout=drift_selected[j])
        if drift_selected[j]:
            k[j] = max(res.value, k_cert[j])
        drift.append(res)
    for j in range(k.shape[0]):
        if not drift_selected[j]:
            k[j] = k_cert[j]
    beta, sigma, disp, folds = final_fit(ctx, head, k)
    off = len(nuis)
    col = 1 + off
    for s in selected:
        n = candidate_columns(ch, s.candidate).shape[1]
        s.cols = list(range(col, col + n))
        s.value = beta[off : off + n]
        s.sigma = sigma[off : off + n]
        s.fold_values = [f[off : off + n] for f in folds]
        off += n
        col += n
    for s in selected:
        _record(best_tests, s.candidate, s.chi2, s.significance, s.heldout, True)
    return ChannelResult(
        channel=ch,
        selected=selected,
        drift=drift,
        k=k,
        tested=list(best_tests.values()),
        dispersion=disp,
        design=head,
        nuisance_cols=nuis,
    )


__all__ = [
    "ChannelResult",
    "DriftResult",
    "Selected",
    "analyse_channel",
    "candidate_columns",
    "drift_test",
    "final_fit",
    "k_on_rows",
    "profile_k",
]

"""The extended model: named effects added to the certificate, and the metrics that compare
it with the certificate's model on data not used for fitting.

Both models get the same nuisance treatment, so that the gain measures what the
named effects add and not a recalibration: the accelerometer's biases,
scale-factor errors and symmetric misalignment and every gyro axis's bias at
rest are re-estimated on the fitting half for *both* (the certificate's linear
model at its best on this session). Metrics (held out):

- ``residual_rms``: RMS of the quasi-static chunk residuals of the held-out
  half of the two-fold split over alternate chunks (input units: the gyro rate
  at rest, the accelerometer norm error);
- ``f0_false_alarm_rate``: share of held-out quasi-static samples with
  ``|F0| > limits.f0`` (accelerometers; gyros only where Earth rate is
  observable);
- ``allan_misfit``: RMS over sensors and cluster times of
  ``ln(adev_measured / adev_simulated) / sigma`` on the second half of the
  session (sigma from the independent terms of both), the noise model fitted
  on the first half: about 1 when the model's noise explains the data;
- ``spectrum_misfit``: the same log ratio over the PSD bins near named lines
  (second half), when there are lines.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field

import numpy as np

from ..certificate import Certificate, Noise, Temperature, TriadModel
from .detectors import ChannelResult
from .residuals import SENSORS, Channel, accel_effect_specs, refit_accel, with_effects
from .spectral import Line
from .streams import F0Check, Predictor, SegmentStats
from .summaries import Session

#: report key of an effect's held-out log-likelihood improvement, nats (above 0 is better)
HELDOUT_LOGLIK_KEY = "heldout_loglik_gain_nats"
#: what every entry of the report's ``gain`` block means
GAIN_DEFINITION = (
    "every gain is extended / baseline of the error measure it is named for (residual_rms, "
    "rotation_rms, f0_false_alarm_rate, allan_misfit), both on held-out data: below 1 the "
    "extended model is better, 1 no change; an effect's held-out log-likelihood improvement "
    f"is {HELDOUT_LOGLIK_KEY!r} (nats, above 0 is better), never called a gain"
)

_COL = {s: i for i, s in enumerate(SENSORS["gyro"] + SENSORS["accel"])}


@dataclass
class Effect:
    """A named effect with its fitted value (spec/reports.md units)."""

    name: str
    triad: str
    sensor: str
    value: float | list[float]
    unit: str
    significance: float
    sigma: float | list[float] | None = None
    heldout: float = 0.0
    extra: dict = field(default_factory=dict)  #: t, frequency, reference, ...

    def as_dict(self) -> dict:
        """The report entry."""
        d = {
            "name": self.name,
            "triad": self.triad,
            "sensor": self.sensor,
            "value": self.value,
            "unit": self.unit,
            "significance": round(float(self.significance), 3),
        }
        d.update(self.extra)
        if self.sigma is not None:
            d["sigma"] = self.sigma
        # a likelihood improvement (nats, above 0 is better), not a gain: see GAIN_DEFINITION
        d[HELDOUT_LOGLIK_KEY] = round(float(self.heldout), 3)
        return d


def _num(x: np.ndarray | float) -> float | list[float]:
    a = np.asarray(x, dtype=float).reshape(-1)
    return float(a[0]) if a.shape[0] == 1 else [float(v) for v in a]


def step_time(
    ch: Channel,
    boundary: int,
    size: float,
    half_y: np.ndarray,
    t_start: np.ndarray,
    t_end: np.ndarray,
    run: np.ndarray,
    j: int,
) -> tuple[float, float, float]:
    """Time (s) of a bias step of ``size`` found between chunks ``boundary - 1`` and
    ``boundary``, and the interval (s) the data allow (chi-square within 9: 3 sigma).

    ``half_y`` (C, 2): the channel residual of each chunk half. Where the sensor's
    trace ``H`` is (nearly) zero the step is invisible, so the search spans from the
    last chunk before the boundary that sees the sensor to the first one after it. For
    trial times the halves' expected levels are a constant per still run plus the part
    of the step each half has seen.
    """
    n = len(ch)
    h_all = np.abs(ch.H[:, j])
    seen = h_all > 0.1 * float(np.max(h_all)) if np.max(h_all) > 0 else np.ones(n, bool)
    i_lo = boundary - 1
    while i_lo > 0 and not seen[i_lo]:
        i_lo -= 1
    i_hi = boundary
    while i_hi < n - 1 and not seen[i_hi]:
        i_hi += 1
    ids = np.arange(max(i_lo - 2, 0), min(i_hi + 3, n))
    ids = ids[seen[ids]]
    mids = 0.5 * (t_start[ids] + t_end[ids])
    a = np.stack([t_start[ids], mids], axis=1).reshape(-1)
    b = np.stack([mids, t_end[ids]], axis=1).reshape(-1)
    y = half_y[ids].reshape(-1)
    h = np.repeat(ch.H[ids, j], 2)
    var = np.repeat(2.0 * ch.R[ids], 2)
    runs = np.repeat(run[ids], 2)
    grid = np.linspace(float(t_start[i_lo]), float(t_end[i_hi]), 801)
    frac = np.clip((b[None, :] - grid[:, None]) / np.maximum(b - a, 1e-12)[None, :], 0.0, 1.0)
    resid = (y[None, :] - size * h[None, :] * frac) / np.sqrt(var)[None, :]
    w = 1.0 / np.sqrt(var)
    cost = np.zeros(grid.shape[0])
    for r in np.unique(runs).tolist():  # a few runs
        sel = runs == r
        part = resid[:, sel]
        ws = w[sel]
        level = (part @ ws) / float(ws @ ws)  # the run's constant, weighted
        part = part - level[:, None] * ws[None, :]
        cost += np.sum(part * part, axis=1)
    best = cost <= cost.min() + 1e-9 * max(abs(float(cost.min())), 1.0)
    inside = grid[cost <= cost.min() + 9.0]
    return float(np.median(grid[best])), float(inside.min()), float(inside.max())


def collect_effects(
    results: list[ChannelResult],
    lines: list[Line],
    t_start: np.ndarray,
    t_end: np.ndarray,
    run: np.ndarray,
    half_y: dict[str, np.ndarray],
    output_unit: dict[str, str],
) -> list[Effect]:
    """The named effects of every channel and the spectral lines, as report entries."""
    out: list[Effect] = []
    for res in results:
        ch = res.channel
        for s in res.selected:
            c = s.candidate
            extra: dict = {}
            value = _num(s.value)
            if c.name == "bias_step":
                j = list(ch.sensors).index(c.sensor)
                ts, lo, hi = step_time(
                    ch,
                    int(c.extra["boundary"]),
                    float(s.value[0]),
                    half_y[ch.label],
                    t_start,
                    t_end,
                    run,
                    j,
                )
                b_lo, b_hi = c.extra.get("boundary_range", (c.extra["boundary"],) * 2)
                if b_hi - b_lo > 2:  # a flat stretch (the sensor barely sees the step there)
                    lo = min(lo, float(t_start[max(b_lo - 1, 0)]))
                    hi = max(hi, float(t_end[b_hi]))
                    ts = 0.5 * (lo + hi)
                extra["t"] = round(ts, 4)
                extra["t_range"] = [round(lo, 4), round(hi, 4)]
            if "reference" in c.extra:
                extra["reference"] = c.extra["reference"]
            if s.alternatives:
                extra["alternatives"] = list(s.alternatives)
            out.append(
                Effect(
                    c.name,
                    c.triad,
                    c.sensor,
                    value,
                    c.unit,
                    s.significance,
                    sigma=_num(s.sigma),
                    heldout=s.heldout,
                    extra=extra,
                )
            )
        for d in res.drift:
            if d.value > d.certificate and res.k[list(ch.sensors).index(d.sensor)] == d.value:
                unit = f"{output_unit[ch.triad]}/sqrt(s)"
                out.append(
                    Effect(
                        "bias_drift",
                        ch.triad,
                        d.sensor,
                        float(d.value),
                        unit,
                        d.significance,
                        sigma=0.5 * (d.high - d.low),
                        heldout=d.heldout,
                        extra={"certificate": d.certificate},
                    )
                )
    for ln in lines:
        triad = "gyro" if ln.sensor.startswith("g") else "accel"
        out.append(
            Effect(
                "periodic_disturbance",
                triad,
                ln.sensor,
                float(ln.amplitude),
                output_unit[triad],
                ln.significance,
                heldout=ln.heldout,
                extra={"frequency": round(float(ln.frequency), 4)},
            )
        )
    return out


# ---------------------------------------------------------------------------
# models


def add_blocks(triad: TriadModel, effects: list[Effect], reference: float) -> TriadModel:
    """A copy of ``triad`` with the temperature / nonlinearity / g-sensitivity effects added."""
    t = copy.deepcopy(triad)
    axes = SENSORS[t.name]
    for e in effects:
        if e.triad != t.name or e.sensor not in axes:
            continue
        j = axes.index(e.sensor)
        if e.name in ("temperature_bias", "temperature_scale"):
            if t.temperature is None:
                t.temperature = Temperature(reference=reference)
            if e.name == "temperature_bias":
                t.temperature.bias_coefficient = t.temperature.bias_coefficient.copy()
                t.temperature.bias_coefficient[j] += float(e.value)  # type: ignore[arg-type]
            else:
                t.temperature.scale_coefficient = t.temperature.scale_coefficient.copy()
                t.temperature.scale_coefficient[j] += float(e.value)  # type: ignore[arg-type]
        elif e.name == "scale_nonlinearity":
            q = np.zeros(3) if t.nonlinearity is None else t.nonlinearity.copy()
            q[j] += float(e.value)  # type: ignore[arg-type]
            t.nonlinearity = q
        elif e.name == "g_sensitivity":
            g = np.zeros((3, 3)) if t.g_sensitivity is None else t.g_sensitivity.copy()
            g[j] += np.asarray(e.value, dtype=float)
            t.g_sensitivity = g
    return t


def extended_certificate(
    certificate: Certificate,
    effects: list[Effect],
    density: np.ndarray | None,
    references: dict[str, float],
) -> Certificate:
    """The certificate with the fitted extended-model blocks (spec/certificate.md).

    bias_drift goes to ``noise.bias_random_walk``; a measured white-noise density is
    written where the certificate has none. Steps and periodic lines have no place in a
    certificate (a step is a bias change: the diagnosis reports it as a bias fault).
    """
    cert = copy.deepcopy(certificate)
    for k, name in enumerate(("gyro", "accel")):
        tri = add_blocks(cert.triad(name), effects, references[name])
        walk = [e for e in effects if e.triad == name and e.name == "bias_drift"]
        if walk or (density is not None and (tri.noise is None or tri.noise.density is None)):
            if tri.noise is None:
                tri.noise = Noise()
            if tri.noise.density is None and density is not None:
                tri.noise.density = np.asarray(density[3 * k : 3 * k + 3], dtype=float)
            if walk:
                base = (
                    tri.noise.bias_random_walk.copy()
                    if tri.noise.bias_random_walk is not None
                    else np.zeros(3)
                )
                for e in walk:
                    base[SENSORS[name].index(e.sensor)] = float(e.value)  # type: ignore[arg-type]
                tri.noise.bias_random_walk = base
        if name == "gyro":
            cert.gyro = tri
        else:
            cert.accel = tri
    return cert


# ---------------------------------------------------------------------------
# deterministic fold fits (residual RMS, F0 models)


@dataclass
class FoldFit:
    """Weighted least squares (no random walk) on one fold, evaluated on the other."""

    coef: np.ndarray
    heldout_resid: np.ndarray  #: residuals of the other fold, input units
    rows: np.ndarray  #: the held-out chunk indices


def fold_fits(res: ChannelResult, extended: bool) -> list[FoldFit]:
    """Per fold: fit ``[bias | nuisance | effects]`` on it, residuals of the other fold."""
    ch = res.channel
    z = res.design
    parts = [ch.H, ch.nuisance]
    if extended:
        cols = [c for s in res.selected for c in s.cols]
        parts.append(z[:, cols])
    x = np.concatenate(parts, axis=1)
    w = 1.0 / ch.R
    out = []
    for fit in ch.folds():
        ho = ~fit
        a = x[fit] * np.sqrt(w[fit])[:, None]
        b = ch.y[fit] * np.sqrt(w[fit])
        coef = np.linalg.lstsq(a, b, rcond=1e-10)[0] if x.shape[1] else np.zeros(0)
        resid = (ch.y[ho] - x[ho] @ coef) * ch.to_input[ho]
        out.append(FoldFit(coef=coef, heldout_resid=resid, rows=np.flatnonzero(ho)))
    return out


def residual_rms(
    results: list[ChannelResult], extended: bool, accel: list[AccelFold] | None = None
) -> dict[str, float | None]:
    """Held-out chunk residual RMS per triad, input units (None without chunks); the
    accelerometer's from its exact fold fits ``accel`` when given."""
    acc: dict[str, list[np.ndarray]] = {"gyro": [], "accel": []}
    for res in results:
        if len(res.channel) < 4 or res.channel.label == "rotation":
            continue
        if res.channel.triad == "accel" and accel is not None:
            acc["accel"] += [f.resid for f in accel]
            continue
        for f in fold_fits(res, extended):
            acc[res.channel.triad].append(f.heldout_resid)
    out: dict[str, float | None] = {}
    for triad, parts in acc.items():
        r = np.concatenate(parts) if parts else np.zeros(0)
        out[triad] = float(np.sqrt(np.mean(r * r))) if r.shape[0] else None
    return out


def rotation_rms(res: ChannelResult | None, extended: bool) -> float | None:
    """Held-out RMS of the direction residuals after a turn (rad), or None."""
    if res is None or len(res.channel) < 4:
        return None
    r = np.concatenate([f.heldout_resid for f in fold_fits(res, extended)])
    return float(np.sqrt(np.mean(r * r))) if r.shape[0] else None


@dataclass
class AccelFold:
    """The accelerometer model fitted (exactly, Gauss-Newton) on one fold."""

    model: TriadModel  #: with the effects' blocks
    steps: list[tuple[int, float, float]]  #: (column 3..5, t s, size) bias steps
    heldout: np.ndarray  #: chunk indices of the other fold
    resid: np.ndarray  #: norm residuals there, input units


def accel_folds(
    certificate: Certificate,
    session: Session,
    sigma2: np.ndarray,
    res: ChannelResult,
    reference: float,
    extended: bool,
) -> list[AccelFold]:
    """Per fold of the accelerometer channel: its own linear parameters (and the selected
    effects when ``extended``) fitted on the fold, and the exact residuals of the other."""
    c = session.chunks
    temp = c.temp if session.has_temp else None
    g_in = certificate.gravity / certificate.accel.unit_to_si
    specs = accel_effect_specs(res.selected) if extended else []
    idx = np.arange(len(c))
    out = []
    for fit in res.channel.folds():
        tri, values = refit_accel(certificate, session, sigma2, specs, reference, mask=fit)
        model = with_effects(tri, specs, values, reference)
        u = c.accel.copy()
        steps = []
        for (name, j, b), v in zip(specs, values, strict=True):
            if name == "bias_step":
                u[idx >= (b or 0), j] -= v
                steps.append((3 + j, float(c.t_start[b or 0]), float(v)))
        ho = np.flatnonzero(~fit)
        resid = (
            np.linalg.norm(model.inverse(u[ho], temp_c=None if temp is None else temp[ho]), axis=1)
            - g_in
        )
        out.append(AccelFold(model=model, steps=steps, heldout=ho, resid=resid))
    return out


def f0_checks(folds: dict[str, list[AccelFold]]) -> list[F0Check]:
    """F0 checks of the baseline and extended accelerometer models, each fitted on one fold
    and counted on the other (fold fitted on parity p is checked on parity 1 - p)."""
    out: list[F0Check] = []
    for name, fl in folds.items():
        for parity, f in enumerate(fl):
            out.append(F0Check(name=name, model=f.model, parity=1 - parity, steps=f.steps))
    return out


def f0_rate(checks: list[F0Check], name: str) -> float | None:
    """Share of checked samples failing, over the checks called ``name``."""
    sel = [c for c in checks if c.name == name]
    n = sum(c.checked for c in sel)
    return None if n == 0 else sum(c.failed for c in sel) / n


# ---------------------------------------------------------------------------
# predictors (per-sample model outputs at rest, for Allan / PSD residuals)


def predictor(
    gyro: TriadModel,
    accel: TriadModel,
    chunk_input: np.ndarray,
    steps: list[tuple[str, float, float]],
) -> Predictor:
    """Model outputs (n, 6) at rest along each chunk's specific force ``chunk_input`` (C, 3)."""

    def predict(t: np.ndarray, temp: np.ndarray | None, chunk: np.ndarray) -> np.ndarray:
        a = chunk_input[chunk]
        g = gyro.forward(
            np.zeros_like(a), temp_c=temp, accel_input=a if gyro.g_sensitivity is not None else None
        )
        u = np.concatenate([g, accel.forward(a, temp_c=temp)], axis=1)
        for sensor, ts, size in steps:
            u[:, _COL[sensor]] += size * (t >= ts)
        return u

    return predict


# ---------------------------------------------------------------------------
# Allan / spectrum misfit


def allan_misfit(
    measured: SegmentStats, simulated: list[SegmentStats], name: str, half: int = 1
) -> dict[str, float | None]:
    """RMS z of log Allan deviation, measured vs the mean of simulated replicas, per triad."""
    tau, adev_m, ind_m = measured.allan(name, (half,))
    sims = [s.allan(name, (half,)) for s in simulated]
    out: dict[str, float | None] = {}
    if not sims:
        return {"gyro": None, "accel": None}
    avar_s = np.mean(np.stack([s[1] ** 2 for s in sims]), axis=0)
    ind_s = np.sum(np.stack([s[2] for s in sims]), axis=0)
    ok = (ind_m >= 4) & (ind_s >= 4)
    for k, triad in enumerate(("gyro", "accel")):
        cols = slice(3 * k, 3 * k + 3)
        if not np.any(ok):
            out[triad] = None
            continue
        sig = np.sqrt(1.0 / (2.0 * ind_m[ok]) + 1.0 / (2.0 * ind_s[ok]))
        with np.errstate(divide="ignore", invalid="ignore"):
            z = np.log(adev_m[ok, cols] / np.sqrt(avar_s[ok, cols])) / sig[:, None]
        z = z[np.isfinite(z)]
        out[triad] = float(np.sqrt(np.mean(z * z))) if z.shape[0] else None
    del tau
    return out


def ratio(ext: float | None, base: float | None) -> float | None:
    """extended / baseline, None when undefined."""
    if ext is None or base is None or not math.isfinite(base) or base <= 0:
        return None if not (ext == 0 and base == 0) else 1.0
    return float(ext / base)


__all__ = [
    "GAIN_DEFINITION",
    "HELDOUT_LOGLIK_KEY",
    "Effect",
    "FoldFit",
    "AccelFold",
    "accel_folds",
    "add_blocks",
    "allan_misfit",
    "collect_effects",
    "extended_certificate",
    "f0_checks",
    "f0_rate",
    "fold_fits",
    "predictor",
    "ratio",
    "residual_rms",
    "rotation_rms",
    "step_time",
]

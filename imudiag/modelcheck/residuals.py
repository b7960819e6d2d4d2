"""Residuals of the quasi-static chunk means against a certificate's model.

The session's motion is reconstructed from the data where it is quasi-static:
the unit is still (zero rate; Earth rate is below a MEMS gyro's resolution and
its heading is unknown) and the specific force is gravity along the measured
direction. Against that, per chunk i:

- gyro axis j: ``y_ij = U_ij - forward(0, T_i, a_i)_j`` (output units): at rest
  the gyro output is its bias (plus g-sensitivity when the certificate has it);
- accelerometer: ``y_i = |inverse(U_i, T_i)| - g`` (input units): the attitude
  comes from the measured direction, so only the norm is a residual (the
  scalar method's F0, design note §1).

Every catalogue effect adds ``delta U_j`` (output units) to a sensor; its
trace on a residual is ``H_ij delta U_ij`` with ``H = 1`` for a gyro axis and
``H_ij = d|x| / dU_j`` for the accelerometer norm. Candidate regressors are
built so that their coefficients are the effect values in the units of
spec/reports.md.

The accelerometer's own linear parameters (biases, scale-factor errors, the
symmetric misalignment terms) are re-estimated as nuisance on the session
(``working`` model), so that a certificate that is a little off does not pass
for a missing effect; the model check is about the *structure* of the model.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field

import numpy as np

from ..certificate import MISALIGNMENT_N_ENTRY, Certificate, Temperature, TriadModel
from ..stats import chi2_ratio_quantile
from .config import ModelCheckConfig
from .summaries import SUB_BLOCKS, Session

SENSORS = {"gyro": ("gx", "gy", "gz"), "accel": ("ax", "ay", "az")}
#: symmetric misalignment pairs of the accelerometer nuisance
_PAIRS = ((0, 1), (0, 2), (1, 2))


@dataclass
class Candidate:
    """One catalogue effect on one sensor, as regressor columns of a channel."""

    name: str  #: catalogue name (spec/reports.md)
    triad: str
    sensor: str
    #: (C, k) regressors, coefficients are the effect value; None for a bias step, whose
    #: column ``H[:, axis] * (i >= boundary)`` is built where needed
    columns: np.ndarray | None
    unit: str
    extra: dict = field(default_factory=dict)  #: e.g. {"boundary": i} for steps
    trials: float = 1.0  #: positions scanned for the same hypothesis (Bonferroni)
    #: smallest norm of the value that can be told from a known confounder (g-sensitivity:
    #: the projection of Earth rate, whose direction needs the unknown heading)
    min_norm: float = 0.0


@dataclass
class Channel:
    """A residual series of chunk means with its noise and its regressors.

    y (C,) residuals; H (C, d) trace of a unit output change of each state
    sensor; R (C,) white-noise variance of y; ``to_input`` (C,) factor from y's
    units to the triad's input units (for residual RMS in physical units).
    """

    triad: str
    label: str  #: "gx" .. for a gyro axis, "accel" for the accelerometer norm
    sensors: tuple[str, ...]  #: sensors of the state dimensions
    t: np.ndarray
    y: np.ndarray
    H: np.ndarray
    R: np.ndarray
    to_input: np.ndarray
    nuisance: np.ndarray  #: (C, p) deterministic nuisance columns (besides the bias state)
    nuisance_names: list[str]
    candidates: list[Candidate] = field(default_factory=list)
    untestable: list[dict] = field(default_factory=list)
    k_cert: np.ndarray = field(default_factory=lambda: np.zeros(1))  #: (d,) output/sqrt(s)
    y_unit: str = ""
    drift_ok: np.ndarray = field(default_factory=lambda: np.ones(1, dtype=bool))  #: (d,)
    #: (C,) fold key: rows with the same key stay together in the two-fold split
    group: np.ndarray | None = None

    def folds(self) -> list[np.ndarray]:
        """The two folds (bool masks): alternate chunks (or alternate groups)."""
        key = np.arange(len(self)) if self.group is None else self.group
        return [key % 2 == 0, key % 2 == 1]

    def __len__(self) -> int:
        return int(self.y.shape[0])


def temperature_reference(triad: TriadModel, config: ModelCheckConfig) -> float:
    """degC at which the certificate's B, S, E hold (its block, else the configured default)."""
    if triad.temperature is not None:
        return float(triad.temperature.reference)
    return float(config.temperature_reference)


def white_variance(session: Session) -> np.ndarray:
    """Per-sample-equivalent white variance (6,) of chunk means, output units^2.

    Each chunk gives the variance of its sub-block means times the sub-block
    length (``SUB_BLOCKS - 1`` degrees of freedom; noise colour shorter than a
    sub-block included); the median over chunks, divided by the median of
    chi2(k)/k, is robust to the odd disturbed chunk.
    """
    c = session.chunks
    if len(c) == 0:
        return np.full(6, math.nan)
    dof = SUB_BLOCKS - 1
    est = np.median(c.sub_var, axis=0) / chi2_ratio_quantile(dof, 0.0)
    # a quantised, nearly constant output can give 0: floor at the quantisation noise
    q2 = session.quantum**2 / 12.0
    return np.maximum(est, np.maximum(q2, 1e-30))


def norm_and_gradient(
    triad: TriadModel, u: np.ndarray, temp: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Inputs x (C, 3), |x| (C,) and d|x|/dU (C, 3) per output unit (central differences)."""
    x = triad.inverse(u, temp_c=temp)
    norm = np.linalg.norm(x, axis=1)
    grad = np.empty_like(u)
    for j in range(3):
        step = 1e-3 * float(triad.scale_factor[j])
        du = np.zeros(3)
        du[j] = step
        hi = np.linalg.norm(triad.inverse(u + du, temp_c=temp), axis=1)
        lo = np.linalg.norm(triad.inverse(u - du, temp_c=temp), axis=1)
        grad[:, j] = (hi - lo) / (2.0 * step)
    return x, norm, grad


def _nx(triad: TriadModel, u: np.ndarray, temp: np.ndarray | None) -> np.ndarray:
    """(N x)_j = (U - B(T)) / S(T) per axis (input units; the nonlinearity's argument)."""
    x = triad.inverse(u, temp_c=temp)
    return x @ triad.n_matrix().T


def accel_nuisance_columns(
    triad: TriadModel, u: np.ndarray, temp: np.ndarray | None, grad: np.ndarray
) -> tuple[np.ndarray, list[str]]:
    """Columns (C, 6) of the accelerometer's scale errors E_j (output per input unit) and
    symmetric misalignment terms (rad) on the norm residual."""
    x = triad.inverse(u, temp_c=temp)
    nx = x @ triad.n_matrix().T
    s = triad.scale_factor
    cols = [grad[:, j] * nx[:, j] for j in range(3)]
    names = [f"scale_factor_error.{a}" for a in "xyz"]
    for j, k in _PAIRS:
        cols.append(grad[:, j] * s[j] * x[:, k] + grad[:, k] * s[k] * x[:, j])
        names.append(f"misalignment.{'xyz'[j]}{'xyz'[k]}+{'xyz'[k]}{'xyz'[j]}")
    return np.stack(cols, axis=1), names


def with_effects(
    tri: TriadModel,
    effects: list[tuple[str, int, int | None]],
    values: np.ndarray,
    reference: float,
) -> TriadModel:
    """``tri`` with temperature / nonlinearity effects of the given values added."""
    out = copy.deepcopy(tri)
    for (name, j, _b), v in zip(effects, values, strict=True):
        if name in ("temperature_bias", "temperature_scale"):
            if out.temperature is None:
                out.temperature = Temperature(reference=reference)
            key = "bias_coefficient" if name == "temperature_bias" else "scale_coefficient"
            arr = getattr(out.temperature, key).copy()
            arr[j] += v
            setattr(out.temperature, key, arr)
        elif name == "scale_nonlinearity":
            q = np.zeros(3) if out.nonlinearity is None else out.nonlinearity.copy()
            q[j] += v
            out.nonlinearity = q
    return out


def _effect_columns(
    tri: TriadModel,
    u: np.ndarray,
    temp: np.ndarray | None,
    grad: np.ndarray,
    effects: list[tuple[str, int, int | None]],
    reference: float,
) -> np.ndarray:
    """Columns (C, k) of the effects on the norm residual at the current model."""
    nx = tri.inverse(u, temp_c=temp) @ tri.n_matrix().T
    d_t = (temp - reference) if temp is not None else np.zeros(u.shape[0])
    idx = np.arange(u.shape[0])
    cols = []
    for name, j, b in effects:
        if name == "temperature_bias":
            cols.append(grad[:, j] * d_t)
        elif name == "temperature_scale":
            cols.append(grad[:, j] * tri.scale_factor[j] * nx[:, j] * d_t)
        elif name == "scale_nonlinearity":
            cols.append(grad[:, j] * nx[:, j] ** 2)
        else:  # bias_step at chunk boundary b
            cols.append(grad[:, j] * (idx >= (b or 0)))
    return np.stack(cols, axis=1) if cols else np.zeros((u.shape[0], 0))


def accel_effect_specs(selected: list) -> list[tuple[str, int, int | None]]:
    """(name, axis, step boundary) of the selected effects of an accelerometer channel."""
    return [
        (
            s.candidate.name,
            SENSORS["accel"].index(s.candidate.sensor),
            s.candidate.extra.get("boundary"),
        )
        for s in selected
    ]


def refit_accel(
    certificate: Certificate,
    session: Session,
    sigma2: np.ndarray,
    effects: list[tuple[str, int, int | None]] | None = None,
    reference: float = 25.0,
    iterations: int = 6,
    mask: np.ndarray | None = None,
) -> tuple[TriadModel, np.ndarray]:
    """The accelerometer model with biases, scale-factor errors and symmetric misalignment
    re-estimated on the session's chunks (Gauss-Newton on the exact norm residual, weak
    prior of 10 limits at the certificate: directions the attitudes do not determine stay
    put), jointly with the values of ``effects`` ((name, axis, step boundary) tuples) when
    given; only the chunks in ``mask`` when given. Returns the model *without* the effects,
    and the effects' values."""
    tri = copy.deepcopy(certificate.accel)
    effects = list(effects or [])
    values = np.zeros(len(effects))
    c = session.chunks
    if len(c) < 3:
        return tri, values
    temp = c.temp if session.has_temp else None
    g_in = certificate.gravity / tri.unit_to_si
    var_mean = sigma2[3:] / c.n[:, None]
    lim = np.concatenate([tri.limits.bias, tri.limits.scale_factor_error, tri.limits.misalignment])
    # solved in units of the prior's standard deviation (10 limits; effects: unit column
    # RMS), so that directions the attitudes do not determine are shared as the prior says
    prior = np.concatenate([np.ones(9), np.zeros(len(effects))])
    total = np.zeros(9 + len(effects))
    idx = np.arange(len(c))
    for _ in range(iterations):
        u = c.accel.copy()
        for (name, j, b), v in zip(effects, values, strict=True):
            if name == "bias_step":
                u[idx >= (b or 0), j] -= v
        model = with_effects(tri, effects, values, reference)
        _x, norm, grad = norm_and_gradient(model, u, temp)
        y = norm - g_in
        r = np.sum(grad**2 * var_mean, axis=1) + (1e-7 * g_in) ** 2
        cols, _names = accel_nuisance_columns(model, u, temp, grad)
        a = np.concatenate(
            [grad, cols, _effect_columns(model, u, temp, grad, effects, reference)], axis=1
        )
        w = 1.0 / r
        if mask is not None:
            w = np.where(mask, w, 0.0)
        eff_rms = np.sqrt(np.mean(a[:, 9:] ** 2, axis=0)) if effects else np.zeros(0)
        scale = np.concatenate([10.0 * lim, 1.0 / np.maximum(eff_rms, 1e-300)])
        a_s = a * scale[None, :]
        # the columns are the residual's response to a missing output (or effect): solve for
        # the missing part and move the model by it; only directions the data determine to
        # 1e-3 of the best are moved (near-collinear columns, e.g. bias against scale in one
        # attitude, would otherwise fit noise with huge opposite values)
        sw = np.sqrt(w)
        u_, sv, vt = np.linalg.svd(a_s * sw[:, None], full_matrices=False)
        keep = sv > 1e-3 * sv[0] if sv.shape[0] and sv[0] > 0 else np.zeros(0, dtype=bool)
        u_, sv, vt = u_[:, keep], sv[keep], vt[keep]
        z_now = total / scale
        # ridge in the kept subspace: (S^2 + P) dz = S U^T (w^1/2 y) - P z_now, P from the prior
        p_sub = vt @ (prior[:, None] * vt.T)
        lhs = np.diag(sv**2) + p_sub
        rhs = sv * (u_.T @ (y * sw)) - vt @ (prior * z_now)
        step = (vt.T @ np.linalg.solve(lhs, rhs)) * scale
        total = total + step
        tri.bias = tri.bias + step[:3]
        tri.scale_factor_error = tri.scale_factor_error + step[3:6]
        # a symmetric change delta of N_jk and N_kj, mapped to the D keys (certificate.md)
        for p, (j, k) in enumerate(_PAIRS):
            for key, (row, col, sign) in MISALIGNMENT_N_ENTRY.items():
                if (row, col) in ((j, k), (k, j)):
                    tri.misalignment[key] += sign * step[6 + p]
        values = values + step[9:]
        if np.all(np.abs(step[:9]) <= 1e-9 * np.maximum(lim, 1e-12)):
            break
    return tri, values


def chunk_accel_input(accel: TriadModel, session: Session) -> np.ndarray:
    """Specific force (C, 3) in accel input units at every chunk (working model inverse)."""
    c = session.chunks
    temp = c.temp if session.has_temp else None
    return accel.inverse(c.accel, temp_c=temp)


def run_up(accel: TriadModel, session: Session) -> dict[int, np.ndarray]:
    """Unit specific-force direction (body axes) of every still run."""
    x = chunk_accel_input(accel, session)
    out: dict[int, np.ndarray] = {}
    for r in np.unique(session.chunks.run).tolist():
        v = x[session.chunks.run == r].mean(axis=0)
        out[int(r)] = v / max(np.linalg.norm(v), 1e-30)
    return out


def distinct_attitudes(up: np.ndarray, separation_deg: float = 10.0) -> int:
    """Number of directions among ``up`` (M, 3) more than ``separation_deg`` apart (greedy)."""
    kept: list[np.ndarray] = []
    cos_lim = math.cos(math.radians(separation_deg))
    for v in up:
        if all(float(np.dot(v, k)) < cos_lim for k in kept):
            kept.append(v)
    return len(kept)


def _step_candidates(
    triad: str, sensor: str, axis: int, n: int, unit: str, config: ModelCheckConfig
) -> list[Candidate]:
    """Bias-step hypotheses at chunk boundaries (at least two chunks each side); their
    regressors ``H[:, axis] * (i >= boundary)`` are generated by the filter, not stored."""
    positions = np.arange(2, n - 1)
    if positions.shape[0] == 0:
        return []
    stride = max(1, int(math.ceil(positions.shape[0] / config.max_step_candidates)))
    trials = float(positions.shape[0])
    return [
        Candidate(
            "bias_step",
            triad,
            sensor,
            None,
            unit,
            extra={"boundary": int(i), "stride": stride, "axis": axis},
            trials=trials,
        )
        for i in positions[::stride].tolist()
    ]


def build_channels(
    certificate: Certificate,
    session: Session,
    config: ModelCheckConfig,
    accel: TriadModel,
    sigma2: np.ndarray,
) -> list[Channel]:
    """The gyro-axis channels and the accelerometer-norm channel of a session."""
    c = session.chunks
    if len(c) == 0:
        return []
    temp = c.temp if session.has_temp else None
    gyro = certificate.gyro
    a_in = chunk_accel_input(accel, session)
    t = c.t_mid
    n = c.n.astype(float)
    out: list[Channel] = []
    ups = np.array(list(run_up(accel, session).values()))
    n_att = distinct_attitudes(ups)
    t_span = (float(np.nanmax(c.temp) - np.nanmin(c.temp))) if session.has_temp else 0.0
    temp_ok = session.has_temp and t_span >= config.min_temperature_span
    temp_reason = (
        "no temperature column in the log"
        if not session.has_temp
        else f"temperature spans only {t_span:.2f} degC"
    )

    # -- gyro axes -----------------------------------------------------------------------
    g_out = gyro.output_unit
    acc_in_unit = accel.input_unit
    pred = gyro.forward(
        np.zeros((len(c), 3)),
        temp_c=temp,
        accel_input=a_in if gyro.g_sensitivity is not None else None,
    )
    earth_out = certificate.earth_rate / gyro.unit_to_si * gyro.scale_factor
    k_cert_g = (
        gyro.noise.bias_random_walk
        if gyro.noise is not None and gyro.noise.bias_random_walk is not None
        else np.zeros(3)
    )
    t_ref_g = temperature_reference(gyro, config)
    for j, sensor in enumerate(SENSORS["gyro"]):
        y = c.gyro[:, j] - pred[:, j]
        r = sigma2[j] / n + earth_out[j] ** 2 / 3.0
        ch = Channel(
            triad="gyro",
            label=sensor,
            sensors=(sensor,),
            t=t,
            y=y,
            H=np.ones((len(c), 1)),
            R=r,
            to_input=np.full(len(c), 1.0 / gyro.scale_factor[j]),
            nuisance=np.zeros((len(c), 0)),
            nuisance_names=[],
            k_cert=np.array([k_cert_g[j]]),
            y_unit=g_out,
        )
        if temp_ok:
            ch.candidates.append(
                Candidate(
                    "temperature_bias",
                    "gyro",
                    sensor,
                    (c.temp - t_ref_g)[:, None],
                    f"{g_out}/degC",
                    extra={"reference": t_ref_g},
                )
            )
        else:
            ch.untestable.append(
                {
                    "name": "temperature_bias",
                    "triad": "gyro",
                    "sensor": sensor,
                    "reason": temp_reason,
                }
            )
        if n_att >= 4:
            # Earth rate projects on a gyro axis by up to S * Omega as the attitude changes
            # (heading unknown): a g-sensitivity must move the bias by more than 3 times that
            g_in = certificate.gravity / accel.unit_to_si
            ch.candidates.append(
                Candidate(
                    "g_sensitivity",
                    "gyro",
                    sensor,
                    a_in.copy(),
                    f"{g_out}/({acc_in_unit})",
                    min_norm=3.0 * float(earth_out[j]) / g_in,
                )
            )
        else:
            ch.untestable.append(
                {
                    "name": "g_sensitivity",
                    "triad": "gyro",
                    "sensor": sensor,
                    "reason": f"{n_att} distinct attitude(s): needs 4 or more",
                }
            )
        ch.candidates += _step_candidates("gyro", sensor, 0, len(c), g_out, config)
        out.append(ch)

    # -- accelerometer norm -------------------------------------------------------------------
    a_out = accel.output_unit
    x, norm, grad = norm_and_gradient(accel, c.accel, temp)
    g_in = certificate.gravity / accel.unit_to_si
    y = norm - g_in
    r = np.sum(grad**2 * sigma2[3:] / n[:, None], axis=1) + (1e-7 * g_in) ** 2
    nuis, nuis_names = accel_nuisance_columns(accel, c.accel, temp, grad)
    k_cert_a = (
        accel.noise.bias_random_walk
        if accel.noise is not None and accel.noise.bias_random_walk is not None
        else np.zeros(3)
    )
    ch = Channel(
        triad="accel",
        label="accel",
        sensors=SENSORS["accel"],
        t=t,
        y=y,
        H=grad,
        R=r,
        to_input=np.ones(len(c)),
        nuisance=nuis,
        nuisance_names=nuis_names,
        k_cert=np.asarray(k_cert_a, dtype=float),
        y_unit=accel.input_unit,
    )
    nx = x @ accel.n_matrix().T
    t_ref_a = temperature_reference(accel, config)
    seen = np.sqrt(np.mean(grad**2, axis=0)) * accel.scale_factor  # ~ |direction component|
    ch.drift_ok = seen > 0.05
    for j, sensor in enumerate(SENSORS["accel"]):
        h = grad[:, j]
        if seen[j] <= 0.05:
            for name in (
                "temperature_bias",
                "temperature_scale",
                "scale_nonlinearity",
                "bias_step",
                "bias_drift",
            ):
                ch.untestable.append(
                    {
                        "name": name,
                        "triad": "accel",
                        "sensor": sensor,
                        "reason": "the sensor's axis never sees gravity",
                    }
                )
            continue
        if temp_ok:
            ch.candidates.append(
                Candidate(
                    "temperature_bias",
                    "accel",
                    sensor,
                    (h * (c.temp - t_ref_a))[:, None],
                    f"{a_out}/degC",
                    extra={"reference": t_ref_a},
                )
            )
            ch.candidates.append(
                Candidate(
                    "temperature_scale",
                    "accel",
                    sensor,
                    (h * accel.scale_factor[j] * nx[:, j] * (c.temp - t_ref_a))[:, None],
                    "1/degC",
                    extra={"reference": t_ref_a},
                )
            )
        else:
            for name in ("temperature_bias", "temperature_scale"):
                ch.untestable.append(
                    {"name": name, "triad": "accel", "sensor": sensor, "reason": temp_reason}
                )
        if n_att >= 4:
            ch.candidates.append(
                Candidate(
                    "scale_nonlinearity",
                    "accel",
                    sensor,
                    (h * nx[:, j] ** 2)[:, None],
                    f"{a_out}/({accel.input_unit})^2",
                )
            )
        else:
            ch.untestable.append(
                {
                    "name": "scale_nonlinearity",
                    "triad": "accel",
                    "sensor": sensor,
                    "reason": f"{n_att} distinct attitude(s): needs 4 or more",
                }
            )
        ch.candidates += _step_candidates("accel", sensor, j, len(c), a_out, config)
    out.append(ch)
    return out


__all__ = [
    "Candidate",
    "Channel",
    "SENSORS",
    "accel_effect_specs",
    "accel_nuisance_columns",
    "build_channels",
    "chunk_accel_input",
    "distinct_attitudes",
    "norm_and_gradient",
    "refit_accel",
    "run_up",
    "temperature_reference",
    "white_variance",
    "with_effects",
]

"""Gyro scale effects from the rotations between still runs.

At rest a gyro's input is zero, so its scale-type effects (``temperature_scale``,
``scale_nonlinearity``) only show when it turns. Between two still runs the
certificate-corrected gyro rates, integrated, must carry the first measured
gravity direction into the second (Tedaldi et al., ICRA 2014; design note §5).
For every such motion the direction residual (two components perpendicular to
the second direction, rad) and its derivatives with respect to small rate
corrections are computed:

- nuisance: relative scale-factor errors (3) and a general small linear
  correction M (6 off-diagonal terms) of the gyro against the accelerometers;
- candidates: ``temperature_scale`` (rate times T - T_ref, per axis) and
  ``scale_nonlinearity`` (rate squared / S, per axis),

so the coefficients are the effect values in report units. The rest bias during
the motion is interpolated between the neighbouring chunks (with the named
g-sensitivity following the measured specific force). The residuals then form a
:class:`~.residuals.Channel` without a random-walk state, tested like the others.
Motions are reduced to these numbers as soon as they close (bounded memory).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ..certificate import Certificate, TriadModel
from ..rotations import ordered_product, quat_matrix, rotvec_quat
from .config import ModelCheckConfig
from .residuals import Candidate, Channel
from .summaries import Chunks

#: direction residual floor (rad): integration and modelling resolution
DIRECTION_FLOOR = 1e-4
_N_NUIS = 9
#: turns of at least ``min_rotation_deg`` the tests need (9 nuisance parameters + 6 effects,
#: two direction components per turn, and two folds to fit and score)
MIN_TURNS = 12
_OFF = ((0, 1), (0, 2), (1, 0), (1, 2), (2, 0), (2, 1))


# ---------------------------------------------------------------------------
# one motion


@dataclass
class RotationPair:
    """A motion between two still runs reduced to its regression rows."""

    t: float  #: s, middle of the motion
    angle_deg: float  #: rotation angle
    y: np.ndarray  #: (2,) direction residual, rad
    jac: np.ndarray  #: (2, 15) derivatives: e(3), M(6), temperature_scale(3), nonlinearity(3)
    var: float  #: variance of each residual component, rad^2


@dataclass
class MotionWindow:
    """The gap between the last chunk of a still run and the first chunk of the next."""

    before: int  #: chunk index
    after: int
    t0: float
    t1: float
    rows: list[np.ndarray] = field(default_factory=list)  #: (t, gyro 3, accel 3, temp)


def motion_windows(chunks: Chunks, max_motion_s: float) -> list[MotionWindow]:
    """Windows between consecutive still runs, at most ``max_motion_s`` long."""
    out = []
    for i in range(len(chunks) - 1):  # one step per chunk
        if chunks.run[i] == chunks.run[i + 1]:
            continue
        t0, t1 = float(chunks.t_end[i]), float(chunks.t_start[i + 1])
        if 0 < t1 - t0 <= max_motion_s:
            out.append(MotionWindow(before=i, after=i + 1, t0=t0, t1=t1))
    return out


def _rates(gyro: TriadModel, u: np.ndarray, bias: np.ndarray) -> np.ndarray:
    """Certificate-corrected rates (m, 3) in input units from outputs and rest bias."""
    x = (u - bias) / gyro.scale_factor
    return x @ np.linalg.inv(gyro.n_matrix()).T


def _predict(omega_in: np.ndarray, to_si: float, dt: np.ndarray, up0: np.ndarray) -> np.ndarray:
    """End directions (P, 3) for rate sets (P, m, 3) in input units."""
    w = omega_in * to_si
    theta = 0.5 * (w[:, 1:] + w[:, :-1]) * dt[None, :, None]
    c = quat_matrix(ordered_product(rotvec_quat(theta)))  # body at the end -> body at the start
    return np.einsum("pji,j->pi", c, up0)


def reduce_motion(
    window: MotionWindow,
    certificate: Certificate,
    accel: TriadModel,
    chunks: Chunks,
    g_sens: np.ndarray | None,
    sigma2: np.ndarray,
    t_ref: float,
    max_step: float,
) -> RotationPair | None:
    """The regression rows of one motion, or None when it cannot be used."""
    if not window.rows:
        return None
    rows = np.concatenate(window.rows)
    # include the neighbouring chunks' edges: the motion starts and ends at rest
    if rows.shape[0] < 3 or np.any(np.diff(rows[:, 0]) > max_step):
        return None
    t = rows[:, 0]
    gyro = certificate.gyro
    b, a = window.before, window.after
    temp = rows[:, 7] if np.all(np.isfinite(rows[:, 7])) else None
    # rest bias: the means of the two still runs, interpolated; g-sensitivity follows the
    # specific force
    runs = []
    for i in (b, a):
        sel = chunks.run == chunks.run[i]
        n_run = chunks.n[sel]
        runs.append(
            (np.sum(chunks.gyro[sel] * n_run[:, None], axis=0) / n_run.sum(), int(n_run.sum()))
        )
    (bias_b, n_b), (bias_a, n_a) = runs
    w = np.clip((t - window.t0) / max(window.t1 - window.t0, 1e-9), 0.0, 1.0)[:, None]
    bias = (1.0 - w) * bias_b + w * bias_a
    if g_sens is not None:
        a_meas = accel.inverse(rows[:, 4:7], temp_c=temp)
        a_rest = (1.0 - w) * accel.inverse(chunks.accel[b : b + 1])[0] + w * accel.inverse(
            chunks.accel[a : a + 1]
        )[0]
        bias = bias + (a_meas - a_rest) @ g_sens.T
    omega = _rates(gyro, rows[:, 1:4], bias)  # input units
    up = []
    for i in (b, a):
        f = accel.inverse(chunks.accel[i : i + 1])[0]
        up.append(f / np.linalg.norm(f))
    up0, up1 = up
    dt = np.diff(t)
    dT = (temp - t_ref) if temp is not None else np.zeros(t.shape[0])
    s_in = gyro.scale_factor
    peak = max(float(np.max(np.abs(omega))), 1e-9)
    # rate corrections per parameter (15, m, 3): d(omega_true) / d(beta)
    basis = np.zeros((15,) + omega.shape)
    for j in range(3):
        basis[j, :, j] = -omega[:, j]
    for p, (j, k) in enumerate(_OFF):
        basis[3 + p, :, j] = -omega[:, k]
    for j in range(3):
        basis[9 + j, :, j] = -omega[:, j] * dT
        basis[12 + j, :, j] = -(omega[:, j] ** 2) / s_in[j]
    steps = np.array([1e-6] * 9 + [1e-6] * 3 + [1e-6 * s_in[j] / peak for j in range(3)])
    sets = np.concatenate([omega[None], omega[None] + steps[:, None, None] * basis])
    pred = _predict(sets, gyro.unit_to_si, dt, up0)
    d_pred = (pred[1:] - pred[0][None]) / steps[:, None]  # (15, 3)
    # two directions perpendicular to the measured end direction
    e1 = np.cross(up1, [1.0, 0.0, 0.0] if abs(up1[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up1, e1)
    e = np.stack([e1, e2])
    y = e @ (up1 - pred[0])
    jac = e @ d_pred.T
    duration = float(t[-1] - t[0])
    to_si = gyro.unit_to_si / float(np.mean(s_in))
    g_out = certificate.gravity / accel.unit_to_si * float(np.mean(accel.scale_factor))
    var = (
        float(np.mean(sigma2[3:])) * (1.0 / chunks.n[b] + 1.0 / chunks.n[a]) / g_out**2
        + float(np.mean(sigma2[:3])) * to_si**2 * float(np.mean(dt)) * duration
        + float(np.mean(sigma2[:3])) * to_si**2 * 0.5 * (1.0 / n_b + 1.0 / n_a) * duration**2
        + (certificate.earth_rate * duration) ** 2
        + DIRECTION_FLOOR**2
    )
    angle = math.degrees(math.acos(float(np.clip(np.dot(up0, up1), -1.0, 1.0))))
    return RotationPair(t=0.5 * (t[0] + t[-1]), angle_deg=angle, y=y, jac=jac, var=var)


class MotionCollector:
    """Collects the samples of every motion window during the second pass."""

    def __init__(
        self,
        windows: list[MotionWindow],
        reduce: Callable[[MotionWindow], RotationPair | None] | None = None,
    ) -> None:
        self.windows = windows
        self._t0 = np.array([w.t0 for w in windows])
        self._t1 = np.array([w.t1 for w in windows])
        self.done: list[MotionWindow] = []
        self.pairs: list[RotationPair] = []  #: reduced motions (with ``reduce``)
        self._reduce = reduce
        self._next = 0

    def _close(self, w: MotionWindow) -> None:
        if self._reduce is None:
            self.done.append(w)
            return
        pair = self._reduce(w)
        w.rows = []  # the samples are no longer needed
        if pair is not None:
            self.pairs.append(pair)

    def add(
        self, t: np.ndarray, gyro: np.ndarray, accel: np.ndarray, temp: np.ndarray | None
    ) -> None:
        """Feed all samples of a block (in time order)."""
        if not self.windows or t.shape[0] == 0:
            return
        k = np.searchsorted(self._t0, t, side="right") - 1
        ok = (k >= 0) & (t <= self._t1[np.maximum(k, 0)])
        if np.any(ok):
            idx = np.flatnonzero(ok)
            rows = np.empty((idx.shape[0], 8))
            rows[:, 0] = t[idx]
            rows[:, 1:4] = gyro[idx]
            rows[:, 4:7] = accel[idx]
            rows[:, 7] = np.nan if temp is None else temp[idx]
            kk = k[idx]
            cut = np.flatnonzero(np.diff(kk) != 0) + 1
            for s0, s1 in zip(
                np.concatenate([[0], cut]).tolist(),
                np.concatenate([cut, [idx.shape[0]]]).tolist(),
                strict=True,
            ):
                self.windows[int(kk[s0])].rows.append(rows[s0:s1])
        # windows that ended before this block's last sample are complete
        while self._next < len(self.windows) and self._t1[self._next] < t[-1]:
            self._close(self.windows[self._next])
            self._next += 1

    def finish(self) -> None:
        """Close the remaining windows."""
        while self._next < len(self.windows):
            self._close(self.windows[self._next])
            self._next += 1


def usable_pairs(pairs: list[RotationPair], max_misfit_rad: float) -> list[RotationPair]:
    """The turns a linear recalibration of the gyros (scale errors, small linear
    correction) brings within ``max_misfit_rad`` of the measured direction: beyond that
    the linearised model does not hold (saturation, gaps, errors far from the model)."""
    if len(pairs) < 6:
        return pairs
    y = np.concatenate([p.y for p in pairs])
    jac = np.concatenate([p.jac[:, :_N_NUIS] for p in pairs])
    w = 1.0 / np.sqrt(np.repeat([p.var for p in pairs], 2))
    keep = np.ones(len(pairs), dtype=bool)
    for it in range(4):  # refit on the turns that agree (after the first: the best half too)
        rows = np.repeat(keep, 2)
        beta = np.linalg.lstsq(jac[rows] * w[rows, None], y[rows] * w[rows], rcond=1e-10)[0]
        miss = np.linalg.norm((y - jac @ beta).reshape(-1, 2), axis=1)
        new = miss <= max_misfit_rad
        if it == 0:
            new |= miss <= np.sort(miss)[max(len(pairs) // 2, 6) - 1]
        if np.array_equal(new, keep):
            break
        keep = new
        if keep.sum() < 6:  # too few consistent turns to refit: those are the usable ones
            break
    return [p for p, k in zip(pairs, keep, strict=True) if k]


def rotation_channel(
    pairs: list[RotationPair],
    certificate: Certificate,
    config: ModelCheckConfig,
    has_temp: bool,
    temp_span: float,
    t_ref: float,
) -> Channel | None:
    """The direction residuals of all motions as a channel (no random-walk state)."""
    gyro = certificate.gyro
    pairs = usable_pairs(pairs, config.max_turn_misfit_rad)
    big = [p for p in pairs if p.angle_deg >= config.min_rotation_deg]
    if len(big) < MIN_TURNS:
        return None
    y = np.concatenate([p.y for p in pairs])
    jac = np.concatenate([p.jac for p in pairs])
    r = np.repeat([p.var for p in pairs], 2)
    t = np.repeat([p.t for p in pairs], 2)
    group = np.repeat(np.arange(len(pairs)), 2)
    out_unit, in_unit = gyro.output_unit, gyro.input_unit
    ch = Channel(
        triad="gyro",
        label="rotation",
        sensors=(),
        t=t,
        y=y,
        H=np.zeros((y.shape[0], 0)),
        R=r,
        to_input=np.ones(y.shape[0]),
        nuisance=jac[:, :_N_NUIS],
        nuisance_names=[f"scale.{a}" for a in "xyz"] + [f"M.{j}{k}" for j, k in _OFF],
        k_cert=np.zeros(0),
        y_unit="rad",
        drift_ok=np.zeros(0, dtype=bool),
        group=group,
    )
    temp_ok = has_temp and temp_span >= config.min_temperature_span
    for j, sensor in enumerate(("gx", "gy", "gz")):
        if temp_ok:
            ch.candidates.append(
                Candidate(
                    "temperature_scale",
                    "gyro",
                    sensor,
                    jac[:, 9 + j : 10 + j],
                    "1/degC",
                    extra={"reference": t_ref},
                )
            )
        ch.candidates.append(
            Candidate(
                "scale_nonlinearity",
                "gyro",
                sensor,
                jac[:, 12 + j : 13 + j],
                f"{out_unit}/({in_unit})^2",
            )
        )
    if not temp_ok:
        reason = (
            "no temperature column in the log"
            if not has_temp
            else f"temperature spans only {temp_span:.2f} degC"
        )
        ch.untestable += [
            {"name": "temperature_scale", "triad": "gyro", "sensor": s, "reason": reason}
            for s in ("gx", "gy", "gz")
        ]
    return ch


__all__ = [
    "MotionCollector",
    "MotionWindow",
    "RotationPair",
    "motion_windows",
    "reduce_motion",
    "rotation_channel",
    "usable_pairs",
]

"""True motion of the IMU: body angular rate, specific force and attitude over time.

Frames: the local level frame is NED (x north, y east, z down), fixed to the
Earth at the start position (transport rate neglected: below 1e-5 rad/s at
vehicle speeds). ``attitude`` maps body to NED. Gravity points down, so at rest
the specific force is ``f_b = C^T (0, 0, -g)``: it points *up* with ``|f| = g``
(a body z axis pointing down reads ``-g``). The body rate includes Earth rate,
``omega = omega_nb + C^T Omega (cos lat, 0, -sin lat)``.

Every motion is analytic in time: each turn is a rotation about a fixed body
axis with a raised-cosine rate profile, angle ``theta * (tau - sin(2 pi tau) / 2 pi)``,
so ``omega`` is the exact derivative of ``attitude`` (no numerical integration),
and a motion can be evaluated at any times (the ``sim://`` source does so in chunks).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..earth import OMEGA_E, earth_rate_ned
from .rotations import (
    attitude_with_up,
    axis_angle_matrix,
    rotation_vector,
    rpy_matrix,
)

STANDARD_GRAVITY = 9.80665  #: m/s^2
EARTH_RATE = OMEGA_E  #: rad/s (the WGS-84 value of imudiag.earth)


@dataclass
class Trajectory:
    """True motion sampled at ``rate_hz``.

    t (N,) s; omega (N, 3) rad/s body angular rate incl. Earth rate;
    specific_force (N, 3) m/s^2 in body axes; attitude (N, 3, 3) body-to-NED;
    static (N,) bool, true while the unit is still; latitude_deg deg; gravity m/s^2.
    """

    t: np.ndarray
    omega: np.ndarray
    specific_force: np.ndarray
    attitude: np.ndarray
    static: np.ndarray
    rate_hz: float
    latitude_deg: float = 45.0
    gravity: float = STANDARD_GRAVITY
    earth_rate: float = EARTH_RATE  #: rad/s

    def __len__(self) -> int:
        return int(self.t.shape[0])

    @property
    def duration_s(self) -> float:
        """Length of the session, s (N / rate)."""
        return len(self) / self.rate_hz

    def slice(self, start: int, stop: int) -> Trajectory:
        """Samples ``start:stop`` (views)."""
        return Trajectory(
            t=self.t[start:stop],
            omega=self.omega[start:stop],
            specific_force=self.specific_force[start:stop],
            attitude=self.attitude[start:stop],
            static=self.static[start:stop],
            rate_hz=self.rate_hz,
            latitude_deg=self.latitude_deg,
            gravity=self.gravity,
            earth_rate=self.earth_rate,
        )

    def static_intervals(self) -> list[tuple[int, int]]:
        """(start, stop) sample index ranges where ``static`` is true."""
        s = np.concatenate([[False], self.static.astype(bool), [False]])
        edges = np.flatnonzero(np.diff(s.astype(np.int8)))
        return [(int(a), int(b)) for a, b in zip(edges[0::2], edges[1::2], strict=True)]


# ---------------------------------------------------------------------------
# motions: analytic in time


class Motion(ABC):
    """A motion evaluated at arbitrary times; ``duration_s`` may be ``math.inf``."""

    duration_s: float = math.inf
    latitude_deg: float = 45.0
    gravity: float = STANDARD_GRAVITY
    earth_rate: float = EARTH_RATE

    @abstractmethod
    def kinematics(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(attitude (N,3,3), omega_nb body rad/s (N,3), acceleration NED m/s^2 (N,3), static)."""

    def navigation_frame(
        self, t: np.ndarray, acc_n: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray | float]:
        """The navigation frame the motion moves in, at times ``t`` (s): its rate against
        inertial space w_in (NED, rad/s, (3,) or (N, 3)), the Coriolis and transport term
        added to the acceleration (NED, m/s^2, broadcastable to (N, 3)) and gravity down
        (m/s^2, scalar or (N,)). Here the level frame fixed to the Earth at
        ``latitude_deg``: Earth rate, no Coriolis term, constant ``gravity``."""
        return earth_rate_ned(self.latitude_deg, self.earth_rate), np.zeros(3), self.gravity

    def evaluate(self, t: np.ndarray, rate_hz: float) -> Trajectory:
        """The trajectory at times ``t`` (s): the one kinematics model of the simulator,
        ``omega = omega_nb + C^T w_in`` and ``f_b = C^T (a_n + coriolis - (0, 0, g))``
        with the terms of :meth:`navigation_frame`."""
        t = np.asarray(t, dtype=float)
        c, w_nb, acc_n, static = self.kinematics(t)
        w_in, coriolis, gravity = self.navigation_frame(t, acc_n)
        ct = np.swapaxes(c, -1, -2)
        omega = w_nb + np.einsum("nij,nj->ni", ct, np.broadcast_to(w_in, w_nb.shape))
        f_n = acc_n + coriolis
        f_n[:, 2] -= gravity
        f_b = np.einsum("nij,nj->ni", ct, f_n)
        return Trajectory(
            t=t,
            omega=omega,
            specific_force=f_b,
            attitude=c,
            static=static,
            rate_hz=float(rate_hz),
            latitude_deg=self.latitude_deg,
            gravity=self.gravity,
            earth_rate=self.earth_rate,
        )

    def n_samples(self, rate_hz: float) -> int | None:
        """Samples in the whole motion at ``rate_hz``, or None when endless."""
        if math.isinf(self.duration_s):
            return None
        return int(round(self.duration_s * rate_hz))

    def sample(self, rate_hz: float, start: int = 0, n: int | None = None) -> Trajectory:
        """Samples ``start .. start+n`` at t = index / rate_hz (default: the whole motion)."""
        if n is None:
            total = self.n_samples(rate_hz)
            if total is None:
                raise ValueError("an endless motion needs an explicit sample count")
            n = total - start
        t = (start + np.arange(max(n, 0), dtype=np.int64)) / float(rate_hz)
        return self.evaluate(t, rate_hz)


def smooth_step(tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Raised-cosine step: s = tau - sin(2 pi tau)/(2 pi) in [0, 1], ds/dtau = 1 - cos(2 pi tau)."""
    tau = np.clip(tau, 0.0, 1.0)
    two_pi_tau = 2.0 * math.pi * tau
    return tau - np.sin(two_pi_tau) / (2.0 * math.pi), 1.0 - np.cos(two_pi_tau)


class PoseSchedule(Motion):
    """Dwells in fixed attitudes and raised-cosine turns about fixed body axes between them.

    ``attitudes`` (M, 3, 3) body-to-NED; the unit dwells ``dwell_s[i]`` in
    attitude i, then turns to attitude i+1 in ``turn_s`` seconds. With
    ``cyclic`` the schedule returns to the first attitude and repeats forever.
    """

    def __init__(
        self,
        attitudes: np.ndarray,
        dwell_s: Sequence[float] | np.ndarray,
        turn_s: float,
        cyclic: bool = False,
        latitude_deg: float = 45.0,
        gravity: float = STANDARD_GRAVITY,
        earth_rate: float = EARTH_RATE,
    ) -> None:
        att = np.asarray(attitudes, dtype=float).reshape(-1, 3, 3)
        dwell = np.asarray(dwell_s, dtype=float)
        if dwell.shape[0] != att.shape[0]:
            raise ValueError(f"{att.shape[0]} attitudes but {dwell.shape[0]} dwell times")
        if np.any(dwell < 0) or turn_s <= 0:
            raise ValueError("dwell times must be >= 0 s and the turn time > 0 s")
        self.latitude_deg = float(latitude_deg)
        self.gravity = float(gravity)
        self.earth_rate = float(earth_rate)
        m = att.shape[0]
        n_turns = m if cyclic else m - 1
        t0, dur, start, axis, angle, static = [], [], [], [], [], []
        clock = 0.0
        for i in range(m):
            t0.append(clock)
            dur.append(dwell[i])
            start.append(att[i])
            axis.append(np.array([1.0, 0.0, 0.0]))
            angle.append(0.0)
            static.append(True)
            clock += dwell[i]
            if i < n_turns:
                rel = att[i].T @ att[(i + 1) % m]  # body-frame rotation of the turn
                rv = rotation_vector(rel)
                ang = float(np.linalg.norm(rv))
                t0.append(clock)
                dur.append(float(turn_s))
                start.append(att[i])
                axis.append(rv / ang if ang > 0 else np.array([1.0, 0.0, 0.0]))
                angle.append(ang)
                static.append(False)
                clock += turn_s
        self.seg_t0 = np.array(t0)
        self.seg_dur = np.array(dur)
        self.seg_start = np.array(start)
        self.seg_axis = np.array(axis)
        self.seg_angle = np.array(angle)
        self.seg_static = np.array(static)
        self.cyclic = cyclic
        self.period_s = clock
        self.duration_s = math.inf if cyclic else clock

    def kinematics(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        t = np.asarray(t, dtype=float)
        tl = np.mod(t, self.period_s) if self.cyclic else t
        i = np.clip(np.searchsorted(self.seg_t0, tl, side="right") - 1, 0, len(self.seg_t0) - 1)
        dur = self.seg_dur[i]
        safe = np.where(dur > 0, dur, 1.0)
        s, ds = smooth_step((tl - self.seg_t0[i]) / safe)
        angle = self.seg_angle[i] * s
        axis = self.seg_axis[i]
        c = self.seg_start[i] @ axis_angle_matrix(axis, angle)
        omega_nb = axis * (self.seg_angle[i] * ds / safe)[:, None]
        return c, omega_nb, np.zeros((t.shape[0], 3)), self.seg_static[i].copy()


class Turntable(Motion):
    """Rotation about a fixed body axis at a constant rate, after an optional raised-cosine ramp."""

    def __init__(
        self,
        rate_rad_s: float,
        axis_body: np.ndarray,
        start_attitude: np.ndarray,
        duration_s: float = math.inf,
        ramp_s: float = 0.0,
        latitude_deg: float = 45.0,
        gravity: float = STANDARD_GRAVITY,
        earth_rate: float = EARTH_RATE,
    ) -> None:
        a = np.asarray(axis_body, dtype=float)
        self.axis = a / np.linalg.norm(a)
        self.rate = float(rate_rad_s)
        self.start = np.asarray(start_attitude, dtype=float)
        self.ramp_s = float(ramp_s)
        self.duration_s = float(duration_s)
        self.latitude_deg = float(latitude_deg)
        self.gravity = float(gravity)
        self.earth_rate = float(earth_rate)

    def kinematics(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        t = np.asarray(t, dtype=float)
        if self.ramp_s > 0:
            # rate r (1 - cos(pi t / T)) / 2 during the ramp, then r
            tr = np.minimum(t, self.ramp_s)
            x = math.pi * tr / self.ramp_s
            angle = self.rate * (tr - self.ramp_s / math.pi * np.sin(x)) / 2.0
            angle = angle + self.rate * np.maximum(t - self.ramp_s, 0.0)
            rate = np.where(t < self.ramp_s, self.rate * (1.0 - np.cos(x)) / 2.0, self.rate)
        else:
            angle = self.rate * t
            rate = np.full(t.shape, self.rate)
        c = self.start @ axis_angle_matrix(self.axis, angle)
        omega_nb = self.axis * rate[:, None]
        static = np.full(t.shape, self.rate == 0.0)
        return c, omega_nb, np.zeros((t.shape[0], 3)), static


class VehicleRun(Motion):
    """Level vehicle: still, a take-off run (smooth acceleration), a sharp turn, a straight run.

    Speed and heading change by raised-cosine steps; body x points along the
    velocity, so body f = (dv/dt, v dpsi/dt, -g) and body rate = (0, 0, dpsi/dt).
    """

    def __init__(
        self,
        still_s: float = 10.0,
        accel_s: float = 8.0,
        speed_m_s: float = 20.0,
        cruise_s: float = 4.0,
        turn_s: float = 4.0,
        turn_deg: float = 90.0,
        final_s: float = 6.0,
        heading_deg: float = 0.0,
        latitude_deg: float = 45.0,
        gravity: float = STANDARD_GRAVITY,
        earth_rate: float = EARTH_RATE,
    ) -> None:
        self.still_s = float(still_s)
        self.accel_s = float(accel_s)
        self.speed = float(speed_m_s)
        self.turn_t0 = self.still_s + self.accel_s + float(cruise_s)
        self.turn_s = float(turn_s)
        self.turn = math.radians(turn_deg)
        self.heading0 = math.radians(heading_deg)
        self.duration_s = self.turn_t0 + self.turn_s + float(final_s)
        self.latitude_deg = float(latitude_deg)
        self.gravity = float(gravity)
        self.earth_rate = float(earth_rate)

    def kinematics(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        t = np.asarray(t, dtype=float)
        sv, dsv = smooth_step((t - self.still_s) / self.accel_s)
        v = self.speed * sv
        dv = self.speed * dsv / self.accel_s
        sp, dsp = smooth_step((t - self.turn_t0) / self.turn_s)
        psi = self.heading0 + self.turn * sp
        dpsi = self.turn * dsp / self.turn_s
        cp, spsi = np.cos(psi), np.sin(psi)
        c = np.zeros((t.shape[0], 3, 3))
        c[:, 0, 0], c[:, 0, 1], c[:, 1, 0], c[:, 1, 1], c[:, 2, 2] = cp, -spsi, spsi, cp, 1.0
        acc = np.stack([dv * cp - v * dpsi * spsi, dv * spsi + v * dpsi * cp, np.zeros_like(t)], 1)
        omega_nb = np.zeros((t.shape[0], 3))
        omega_nb[:, 2] = dpsi
        return c, omega_nb, acc, t < self.still_s


# ---------------------------------------------------------------------------
# attitude sets

#: Up directions (body) of the six faces and the eight cube diagonals.
FACE_DIRECTIONS = np.array(
    [[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], dtype=float
)
DIAGONAL_DIRECTIONS = np.array(
    [[sx, sy, sz] for sx in (1, -1) for sy in (1, -1) for sz in (1, -1)], dtype=float
) / math.sqrt(3.0)


def spread_up_directions(n: int, seed: int = 0) -> np.ndarray:
    """``n`` well-spread body up directions (n, 3): the six faces first (both signs of
    every axis, from n >= 6), then the cube diagonals, then random directions; visited
    in a seeded order."""
    if n < 1:
        raise ValueError("n_attitudes must be >= 1")
    rng = np.random.default_rng(seed)
    faces = FACE_DIRECTIONS[rng.permutation(6)]
    diags = DIAGONAL_DIRECTIONS[rng.permutation(8)]
    dirs = np.vstack([faces, diags])
    if n > dirs.shape[0]:
        extra = rng.standard_normal((n - dirs.shape[0], 3))
        dirs = np.vstack([dirs, extra / np.linalg.norm(extra, axis=1, keepdims=True)])
    chosen = dirs[:n]
    return chosen[rng.permutation(n)]


def _attitudes_from_up(up: np.ndarray, seed: int) -> np.ndarray:
    rng = np.random.default_rng(np.random.SeedSequence([seed, 1]))
    yaws = np.asarray(rng.uniform(-math.pi, math.pi, up.shape[0]))
    return np.array([attitude_with_up(u, y) for u, y in zip(up, yaws.tolist(), strict=True)])


def _axis_vector(axis: str | Sequence[float]) -> np.ndarray:
    if isinstance(axis, str):
        sign = -1.0 if axis.startswith("-") else 1.0
        name = axis.lstrip("+-").lower()
        if name not in ("x", "y", "z"):
            raise ValueError(f"axis must be x, y, z (optionally signed) or a vector, got {axis!r}")
        v = np.zeros(3)
        v["xyz".index(name)] = sign
        return v
    v = np.asarray(axis, dtype=float)
    if v.shape != (3,) or not np.all(np.isfinite(v)) or np.linalg.norm(v) == 0:
        raise ValueError(f"axis must be a non-zero 3-vector, got {axis!r}")
    return v / np.linalg.norm(v)


# ---------------------------------------------------------------------------
# builders (the contract API)


def still_motion(
    duration_s: float = math.inf,
    attitude_rpy_deg: Sequence[float] = (0.0, 0.0, 0.0),
    latitude_deg: float = 45.0,
    gravity: float = STANDARD_GRAVITY,
) -> PoseSchedule:
    """A still unit in one attitude (roll, pitch, yaw in deg)."""
    c = rpy_matrix(*attitude_rpy_deg)
    dur = duration_s if math.isfinite(duration_s) else 1e30
    m = PoseSchedule(c[None], [dur], 1.0, latitude_deg=latitude_deg, gravity=gravity)
    m.duration_s = float(duration_s)
    return m


def still(
    duration_s: float,
    rate_hz: float = 200.0,
    attitude_rpy_deg: Sequence[float] = (0.0, 0.0, 0.0),
    latitude_deg: float = 45.0,
    gravity: float = STANDARD_GRAVITY,
) -> Trajectory:
    """A still unit in one attitude (roll, pitch, yaw in deg) for ``duration_s`` s."""
    return still_motion(duration_s, attitude_rpy_deg, latitude_deg, gravity).sample(rate_hz)


def multi_position_motion(
    n_attitudes: int = 12,
    dwell_s: float = 3.0,
    turn_s: float = 1.5,
    seed: int = 0,
    first_dwell_s: float | None = None,
    latitude_deg: float = 45.0,
    gravity: float = STANDARD_GRAVITY,
    up_directions: np.ndarray | None = None,
    cyclic: bool = False,
) -> PoseSchedule:
    """The motion of :func:`multi_position` (``cyclic``: return to the start and repeat)."""
    up = (
        spread_up_directions(n_attitudes, seed)
        if up_directions is None
        else np.asarray(up_directions, dtype=float).reshape(-1, 3)
    )
    att = _attitudes_from_up(up, seed)
    dwell = np.full(att.shape[0], float(dwell_s))
    if first_dwell_s is not None:
        dwell[0] = float(first_dwell_s)
    return PoseSchedule(
        att, dwell, turn_s, cyclic=cyclic, latitude_deg=latitude_deg, gravity=gravity
    )


def multi_position(
    n_attitudes: int = 12,
    dwell_s: float = 3.0,
    turn_s: float = 1.5,
    rate_hz: float = 200.0,
    seed: int = 0,
    first_dwell_s: float | None = None,
    latitude_deg: float = 45.0,
    gravity: float = STANDARD_GRAVITY,
    up_directions: np.ndarray | None = None,
) -> Trajectory:
    """A multi-position session: ``n_attitudes`` well-spread attitudes held ``dwell_s`` s
    (the first ``first_dwell_s`` s), raised-cosine turns of ``turn_s`` s between.

    The up directions are the six faces (both signs of every axis), then the cube
    diagonals, then random ones, each with a random yaw (seeded), unless given
    as ``up_directions`` (n, 3) in body axes. Duration:
    first_dwell + (n - 1) (turn + dwell) s.
    """
    motion = multi_position_motion(
        n_attitudes, dwell_s, turn_s, seed, first_dwell_s, latitude_deg, gravity, up_directions
    )
    return motion.sample(rate_hz)


def turntable_motion(
    rate_deg_s: float,
    axis: str | Sequence[float] = "z",
    duration_s: float = math.inf,
    attitude_rpy_deg: Sequence[float] | None = None,
    ramp_s: float = 0.0,
    latitude_deg: float = 45.0,
    gravity: float = STANDARD_GRAVITY,
) -> Turntable:
    """The motion of :func:`turntable`."""
    a = _axis_vector(axis)
    start = attitude_with_up(a) if attitude_rpy_deg is None else rpy_matrix(*attitude_rpy_deg)
    return Turntable(math.radians(rate_deg_s), a, start, duration_s, ramp_s, latitude_deg, gravity)


def turntable(
    rate_deg_s: float,
    axis: str | Sequence[float] = "z",
    duration_s: float = 60.0,
    rate_hz: float = 200.0,
    attitude_rpy_deg: Sequence[float] | None = None,
    ramp_s: float = 0.0,
    latitude_deg: float = 45.0,
    gravity: float = STANDARD_GRAVITY,
) -> Trajectory:
    """A turntable turning the unit about body ``axis`` ("x", "-y", ... or a vector) at
    ``rate_deg_s`` deg/s (relative to the Earth), after a raised-cosine spin-up of
    ``ramp_s`` s. By default the axis points straight up (the table axis is vertical);
    ``attitude_rpy_deg`` sets the starting attitude instead."""
    return turntable_motion(
        rate_deg_s, axis, duration_s, attitude_rpy_deg, ramp_s, latitude_deg, gravity
    ).sample(rate_hz)


def vehicle_run(
    still_s: float = 10.0,
    accel_s: float = 8.0,
    speed_m_s: float = 20.0,
    cruise_s: float = 4.0,
    turn_s: float = 4.0,
    turn_deg: float = 90.0,
    final_s: float = 6.0,
    rate_hz: float = 200.0,
    heading_deg: float = 0.0,
    latitude_deg: float = 45.0,
    gravity: float = STANDARD_GRAVITY,
) -> Trajectory:
    """A take-off run: still ``still_s`` s, accelerate to ``speed_m_s`` m/s in ``accel_s`` s
    (peak 2 v / T m/s^2), run ``cruise_s`` s, a sharp ``turn_deg`` turn in ``turn_s`` s
    (peak rate 2 turn / T, peak lateral acceleration v times that), run ``final_s`` s.
    Defaults: peak 5 m/s^2 forward, 45 deg/s and 15.7 m/s^2 lateral in the turn."""
    return VehicleRun(
        still_s,
        accel_s,
        speed_m_s,
        cruise_s,
        turn_s,
        turn_deg,
        final_s,
        heading_deg,
        latitude_deg,
        gravity,
    ).sample(rate_hz)


def static_cycle_motion(
    n_attitudes: int = 4,
    dwell_s: float = 20.0,
    turn_s: float = 4.0,
    seed: int = 0,
    latitude_deg: float = 45.0,
    gravity: float = STANDARD_GRAVITY,
) -> PoseSchedule:
    """Endless: a few attitudes (the first level, z down) held ``dwell_s`` s with slow
    turns between, repeating. The default scenario of the ``sim://`` source."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, 2]))
    up = [np.array([0.0, 0.0, -1.0])]
    for _ in range(max(n_attitudes - 1, 0)):
        # tilted up to 60 deg from level in a random direction
        tilt = math.radians(rng.uniform(15.0, 60.0))
        az = rng.uniform(-math.pi, math.pi)
        up.append(
            np.array(
                [math.sin(tilt) * math.cos(az), math.sin(tilt) * math.sin(az), -math.cos(tilt)]
            )
        )
    att = _attitudes_from_up(np.array(up), seed)
    att[0] = np.eye(3)
    dwell = np.full(len(up), float(dwell_s))
    return PoseSchedule(
        att, dwell, turn_s, cyclic=n_attitudes > 1, latitude_deg=latitude_deg, gravity=gravity
    )


def relative_rotation(traj: Trajectory, i: int, j: int) -> np.ndarray:
    """Body rotation from sample i to sample j as the gyros see it (incl. Earth rate):
    ``C_j = R_earth(-(t_j - t_i)) C_i Phi`` solved for Phi (3, 3)."""
    w_ie = earth_rate_ned(traj.latitude_deg, traj.earth_rate)
    dt = traj.t[j] - traj.t[i]
    w = np.linalg.norm(w_ie)
    r_e = axis_angle_matrix(w_ie / w, w * dt) if w > 0 else np.eye(3)
    return traj.attitude[i].T @ r_e @ traj.attitude[j]

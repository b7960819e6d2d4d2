"""Car drives with a consistent GNSS stream: urban, highway and hilly scenarios.

The vehicle's body x axis points along its velocity (no side slip), body z
down; the attitude is yaw psi (heading) and pitch theta (road grade), roll 0.
``DriveMotion.slip_rad_per_m_s2`` (default 0) adds a side slip: the body's
heading is the velocity's course plus beta = k a_lat (a_lat = v psi', m/s^2),
so the yaw rate is psi' + beta' (what the no-slip test of
:mod:`imudiag.aiding.course_rate` must reject).
Speed v(t), heading psi(t) and grade theta(t) are sums of raised-cosine
steps, so velocity, acceleration and body rate are exact derivatives:

    v_n   = v (cos th cos psi, cos th sin psi, -sin th)
    omega_nb (body) = (-psi' sin th, th', psi' cos th)

and, on the rotating WGS-84 Earth (the navigation equation the GNSS side of
:mod:`imudiag.aiding` inverts),

    f_n = dv_n/dt - (0, 0, gamma(lat, h)) + (2 Omega_ie + omega_en) x v_n
    omega_ib (body) = omega_nb + C^T (Omega_ie + omega_en).

Position (lat, lon, h) is integrated on a 10 Hz grid from the start point
and interpolated (it only enters gravity, the Earth terms and the GNSS fixes).

:func:`gnss_reports` samples the antenna velocity (IMU velocity plus
C (omega_nb x l) for a lever arm l) at the GNSS rate and writes gpsd TPV
reports with white velocity noise, a latency (time tags late by it), outages
(no-fix reports) and multipath outliers.
"""

from __future__ import annotations

import functools
import json
import math
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from ..earth import coriolis_term, earth_rate_ned, normal_gravity, radii, transport_rate_ned
from .trajectories import Motion, smooth_step

DRIVE_SCENARIOS = ("urban", "highway", "hilly", "aircraft")
#: Unix time of the simulated drives' t = 0 (2026-01-01T00:00:00Z).
EPOCH_UNIX = 1767225600.0
#: m/s^3, largest jerk of a leg (comfortable driving stays below about 2)
MAX_JERK = 2.0


@dataclass
class _Steps:
    """x(t) = x0 + sum of raised-cosine steps (start s, duration s, change)."""

    x0: float = 0.0
    steps: list[tuple[float, float, float]] = field(default_factory=list)
    _table_n: int = field(default=-1, repr=False, compare=False)
    _table: tuple[np.ndarray, np.ndarray] = field(
        default=(np.zeros(0), np.zeros(0)), repr=False, compare=False
    )

    def add(self, t0: float, dur: float, delta: float) -> None:
        self.steps.append((float(t0), float(dur), float(delta)))

    def value_at_end(self) -> float:
        return self.x0 + sum(d for _, _, d in self.steps)

    def eval(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Value, first and second derivative at times t.

        The definition is the sum over every step of ``delta * s(tau)`` (and its derivatives),
        tau = (t - t0) / dur: a step over at a time (tau >= 1) adds exactly ``delta`` there and
        nothing to the derivatives, one not begun (tau <= 0) adds nothing. So on sorted times
        (every simulator read) each step is evaluated only on the times it spans, the times
        between steps take the running sum of the deltas, in the steps' order, and the result
        is bit for bit the definition's (tests/test_sim_trajectories.py); times out of order,
        or steps that overlap, take the definition's loop."""
        t = np.asarray(t, dtype=float)
        if len(self.steps) != self._table_n:  # (start, duration) of every step, as arrays
            table = np.array(self.steps, dtype=float).reshape(-1, 3)
            self._table = (table[:, 0].copy(), table[:, 1].copy())
            self._table_n = len(self.steps)
        fast = _sorted_spans(*self._table, t)
        if fast is None:
            return self._eval_every_step(t)
        x = np.empty(t.shape)
        dx = np.zeros(t.shape)
        ddx = np.zeros(t.shape)
        c = self.x0
        pos = 0
        for (t0, dur, delta), (a, b) in zip(self.steps, fast, strict=True):
            if a > pos:
                x[pos:a] = c
            if b > a:
                tau = (t[a:b] - t0) / dur
                s, ds = smooth_step(tau)
                x[a:b] = c + delta * s
                # 0.0 + ...: the definition's sum from zeros (no -0.0 where it has +0.0)
                dx[a:b] = 0.0 + delta * ds / dur
                ddx[a:b] = 0.0 + delta * 2 * math.pi * np.sin(2 * math.pi * tau) / dur**2
            c += delta
            pos = b
        x[pos:] = c
        return x, dx, ddx

    def _eval_every_step(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`eval` by its definition: every step on every time."""
        x = np.full(t.shape, self.x0)
        dx = np.zeros(t.shape)
        ddx = np.zeros(t.shape)
        for t0, dur, delta in self.steps:
            tau = (t - t0) / dur
            s, ds = smooth_step(tau)
            x += delta * s
            dx += delta * ds / dur
            inside = (tau > 0) & (tau < 1)
            ddx += np.where(inside, delta * 2 * math.pi * np.sin(2 * math.pi * tau) / dur**2, 0)
        return x, dx, ddx


def _sorted_spans(t0: np.ndarray, dur: np.ndarray, t: np.ndarray) -> list[tuple[int, int]] | None:
    """For sorted 1-D times ``t``: per step (start ``t0``, duration ``dur``, s) the index
    range [a, b) where 0 < tau < 1, found with the same float expression ``(t - t0) / dur``
    as the definition (monotone in t); None when ``t`` is not sorted, a duration is not
    positive, or two steps' ranges overlap (then :meth:`_Steps.eval` takes the definition's
    loop)."""
    if t.ndim != 1 or (t.size > 1 and not bool(np.all(t[1:] >= t[:-1]))):
        return None
    if not bool(np.all(dur > 0)):
        return None
    if t.size == 0:
        return [(0, 0)] * t0.shape[0]
    a = _first(t, t0, dur, np.searchsorted(t, t0, side="right"), 0.0, False)
    b = np.maximum(a, _first(t, t0, dur, np.searchsorted(t, t0 + dur, side="left"), 1.0, True))
    if bool(np.any(a[1:] < b[:-1])):  # two steps overlap
        return None
    return list(zip(a.tolist(), b.tolist(), strict=True))


def _first(
    t: np.ndarray, t0: np.ndarray, dur: np.ndarray, guess: np.ndarray, edge: float, closed: bool
) -> np.ndarray:
    """Per step, the first index i of sorted, non-empty ``t`` with tau = (t[i] - t0) / dur
    beyond ``edge`` (``>=`` if ``closed``, else ``>``; once true it stays true along t),
    from the ``searchsorted`` guess, corrected where rounding puts it off."""
    n = t.shape[0]

    def beyond(i: np.ndarray) -> np.ndarray:
        tau = (t[i] - t0) / dur
        return tau >= edge if closed else tau > edge

    i = guess
    while True:
        # forward while i < n and tau(i) is not beyond; back while tau(i - 1) is beyond
        fwd = (i < n) & ~beyond(np.minimum(i, n - 1))
        back = (i > 0) & beyond(np.maximum(i - 1, 0))
        if not (fwd.any() or back.any()):
            return i
        i = i + fwd - back


class DriveMotion(Motion):
    """A car drive built leg by leg (see :func:`drive_motion` for the scenarios)."""

    def __init__(
        self,
        lat_deg: float = 45.0,
        lon_deg: float = 7.0,
        alt_m: float = 300.0,
        heading_deg: float = 0.0,
    ) -> None:
        self.speed = _Steps()
        self.heading = _Steps(math.radians(heading_deg))
        self.grade = _Steps()
        self.t = 0.0
        self.lat0, self.lon0, self.alt0 = float(lat_deg), float(lon_deg), float(alt_m)
        self.latitude_deg = float(lat_deg)
        self.gravity = float(normal_gravity(lat_deg, alt_m))
        self.stops: list[tuple[float, float]] = []
        self.coordinated = False  #: bank into turns (aircraft): f stays in the body x-z plane
        #: rad per m/s^2: body heading = course + this x lateral acceleration (0: no slip)
        self.slip_rad_per_m_s2 = 0.0
        self._pos: tuple[np.ndarray, np.ndarray] | None = None

    # building -----------------------------------------------------------------
    @property
    def v_now(self) -> float:
        return self.speed.value_at_end()

    def stop(self, dur: float) -> DriveMotion:
        """Stand still ``dur`` s (the speed must already be 0)."""
        self.stops.append((self.t, self.t + dur))
        self.t += dur
        return self

    def speed_to(self, v: float, peak_acc: float) -> DriveMotion:
        """Change speed to ``v`` m/s with a peak acceleration ``peak_acc`` m/s^2 (raised cosine:
        duration 2 |dv| / peak)."""
        dv = v - self.v_now
        if dv:
            dur = max(2.0 * abs(dv) / peak_acc, math.sqrt(2 * math.pi * abs(dv) / MAX_JERK))
            self.speed.add(self.t, dur, dv)
            self.t += dur
        return self

    def cruise(self, dur: float) -> DriveMotion:
        self.t += dur
        return self

    def turn(self, angle_deg: float, peak_rate_deg_s: float) -> DriveMotion:
        """Turn by ``angle_deg`` (positive right) at a peak yaw rate (duration 2 angle / peak)."""
        a = math.radians(abs(angle_deg))
        dur = max(
            2.0 * abs(angle_deg) / peak_rate_deg_s,
            math.sqrt(2 * math.pi * a * max(self.v_now, 1.0) / MAX_JERK),
        )
        self.heading.add(self.t, dur, math.radians(angle_deg))
        self.t += dur
        return self

    def grade_to(self, percent: float, dur: float) -> DriveMotion:
        """Change the road grade to ``percent`` % (positive uphill) over ``dur`` s."""
        th = math.atan(percent / 100.0)
        a = abs(th - self.grade.value_at_end())
        dur = max(dur, math.sqrt(2 * math.pi * a * max(self.v_now, 1.0) / MAX_JERK))
        self.grade.add(self.t, dur, th - self.grade.value_at_end())
        self.t += dur
        return self

    def finish(self) -> DriveMotion:
        self.duration_s = self.t
        self._pos = None
        return self

    # kinematics ---------------------------------------------------------------
    def _profiles(self, t: np.ndarray) -> dict[str, np.ndarray]:
        v, dv, _ = self.speed.eval(t)
        psi, dpsi, ddpsi = self.heading.eval(t)
        th, dth, _ = self.grade.eval(t)
        if self.coordinated:
            # bank phi = atan(v psi' / g): the lateral acceleration is carried by the lift
            q = v * dpsi / self.gravity
            dq = (dv * dpsi + v * ddpsi) / self.gravity
            phi, dphi = np.arctan(q), dq / (1.0 + q * q)
        else:
            phi, dphi = np.zeros_like(t), np.zeros_like(t)
        k = self.slip_rad_per_m_s2
        return {
            "psi_b": psi + k * v * dpsi,
            "dpsi_b": dpsi + k * (dv * dpsi + v * ddpsi),
            "v": v,
            "dv": dv,
            "psi": psi,
            "dpsi": dpsi,
            "th": th,
            "dth": dth,
            "phi": phi,
            "dphi": dphi,
        }

    def velocity_ned(self, t: np.ndarray) -> np.ndarray:
        p = self._profiles(np.asarray(t, dtype=float))
        return _vel(p)

    def position(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(lat deg, lon deg, h m) at times t, integrated on a 10 Hz grid."""
        if self._pos is None:
            grid = np.arange(0.0, self.duration_s + 0.2, 0.1)
            vel = self.velocity_ned(grid)
            d = np.vstack([np.zeros((1, 3)), np.cumsum(0.5 * (vel[1:] + vel[:-1]) * 0.1, 0)])
            self._pos = (grid, d)
        grid, d = self._pos
        dn, de, dd = (np.interp(t, grid, d[:, c]) for c in range(3))
        rm, rn = radii(self.lat0)
        lat = self.lat0 + np.degrees(dn / (rm + self.alt0))
        lon = self.lon0 + np.degrees(de / ((rn + self.alt0) * math.cos(math.radians(self.lat0))))
        return lat, lon, self.alt0 - dd

    def kinematics(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        p = self._profiles(t)
        c = _attitude(p["psi_b"], p["th"], p["phi"])
        w_nb = _body_rate(p)
        v, dv, psi, dpsi, th, dth = (p[k] for k in ("v", "dv", "psi", "dpsi", "th", "dth"))
        cth, sth, cps, sps = np.cos(th), np.sin(th), np.cos(psi), np.sin(psi)
        d_dir = np.stack(
            [-sth * dth * cps - cth * sps * dpsi, -sth * dth * sps + cth * cps * dpsi, -cth * dth],
            1,
        )
        acc = dv[:, None] * _dir(psi, th) + v[:, None] * d_dir
        return c, w_nb, acc, v == 0.0

    def navigation_frame(
        self, t: np.ndarray, acc_n: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray | float]:
        """The rotating WGS-84 Earth along the drive (module doc): w_in = Omega_ie + omega_en,
        the Coriolis and transport term (2 Omega_ie + omega_en) x v_n, normal gravity."""
        lat, _, h = self.position(t)
        vel = self.velocity_ned(t)
        w_in = earth_rate_ned(lat) + transport_rate_ned(lat, h, vel)
        return w_in, coriolis_term(lat, h, vel), normal_gravity(lat, h)


def _dir(psi: np.ndarray, th: np.ndarray) -> np.ndarray:
    return np.stack([np.cos(th) * np.cos(psi), np.cos(th) * np.sin(psi), -np.sin(th)], 1)


def _vel(p: dict[str, np.ndarray]) -> np.ndarray:
    return p["v"][:, None] * _dir(p["psi"], p["th"])


def _attitude(psi: np.ndarray, th: np.ndarray, phi: np.ndarray | None = None) -> np.ndarray:
    """Body-to-NED C = Rz(psi) Ry(th) Rx(phi), (N, 3, 3)."""
    cps, sps, cth, sth = np.cos(psi), np.sin(psi), np.cos(th), np.sin(th)
    c = np.zeros((psi.shape[0], 3, 3))
    c[:, 0, 0], c[:, 0, 1], c[:, 0, 2] = cps * cth, -sps, cps * sth
    c[:, 1, 0], c[:, 1, 1], c[:, 1, 2] = sps * cth, cps, sps * sth
    c[:, 2, 0], c[:, 2, 1], c[:, 2, 2] = -sth, 0.0, cth
    if phi is not None and np.any(phi):
        cph, sph = np.cos(phi), np.sin(phi)
        rx = np.zeros_like(c)
        rx[:, 0, 0] = 1.0
        rx[:, 1, 1], rx[:, 1, 2], rx[:, 2, 1], rx[:, 2, 2] = cph, -sph, sph, cph
        c = c @ rx
    return c


def _body_rate(p: dict[str, np.ndarray]) -> np.ndarray:
    """omega_nb in body axes (N, 3), rad/s, of the ZYX Euler angles' rates (the body's
    heading rate, course rate plus the slip angle's rate)."""
    th, phi = p["th"], p["phi"]
    dpsi, dth, dphi = p["dpsi_b"], p["dth"], p["dphi"]
    return np.stack(
        [
            dphi - dpsi * np.sin(th),
            dth * np.cos(phi) + dpsi * np.cos(th) * np.sin(phi),
            -dth * np.sin(phi) + dpsi * np.cos(th) * np.cos(phi),
        ],
        1,
    )


def drive_motion(scenario: str, duration_s: float = 600.0, seed: int = 0) -> DriveMotion:
    """A drive of about ``duration_s`` s (whole legs) under ``seed``.

    urban: stops of 8-20 s, accelerations to 8-14 m/s at 1.5-2.5 m/s^2, braking at
    2-3.5 m/s^2, 90 deg turns at 10-20 deg/s, short cruises. highway: on-ramp to
    28-33 m/s, long cruises, lane changes, gentle curves, speed changes. hilly:
    grades of -8..+8 %, curves at 6-12 deg/s, stops at the bottom of hills.
    """
    if scenario not in DRIVE_SCENARIOS:
        raise ValueError(
            f"unknown drive {scenario!r}; expected one of {', '.join(DRIVE_SCENARIOS)}"
        )
    rng = np.random.default_rng(seed)
    m = DriveMotion(heading_deg=float(rng.uniform(0, 360)))
    m.stop(10.0)
    u = rng.uniform
    if scenario == "aircraft":
        return _flight(m, duration_s, rng)
    while m.t < duration_s - 30.0:
        if scenario == "urban":
            m.speed_to(u(8, 14), u(1.5, 2.5)).cruise(u(5, 25))
            if rng.random() < 0.6:
                m.speed_to(u(5, 7), u(2.0, 3.0)).turn(float(rng.choice([-90, 90])), u(10, 20))
                m.speed_to(u(9, 13), u(1.5, 2.5)).cruise(u(3, 15))
            m.speed_to(0.0, u(2.0, 3.5)).stop(u(8, 20))
        elif scenario == "highway":
            if m.v_now < 1:
                m.speed_to(u(28, 33), u(1.5, 2.5))
            m.cruise(u(20, 60))
            r = rng.random()
            if r < 0.3:
                m.turn(u(-3, 3), u(1, 2)).turn(u(-3, 3), u(1, 2))
            elif r < 0.7:
                m.turn(u(-40, 40), u(1, 3))
            else:
                m.speed_to(u(22, 34), u(0.8, 1.5))
        else:  # hilly
            if m.v_now < 1:
                m.speed_to(u(12, 20), u(1.5, 2.5))
            m.grade_to(u(-8, 8), u(4, 8)).cruise(u(5, 20))
            if rng.random() < 0.6:
                m.turn(u(-60, 60), u(6, 12))
            if rng.random() < 0.2:
                m.grade_to(0.0, u(4, 8)).speed_to(0.0, u(2, 3)).stop(u(8, 15))
    # end: level, stopped
    if abs(m.grade.value_at_end()) > 1e-9:
        m.grade_to(0.0, 6.0)
    m.speed_to(0.0, 2.5).stop(10.0)
    return m.finish()


def _flight(m: DriveMotion, duration_s: float, rng: np.random.Generator) -> DriveMotion:
    """A light aircraft (or UAV): take-off run, climb, coordinated turns at 3-12 deg/s
    (bank up to ~50 deg, |f| up to ~1.5 g), pull-ups and push-overs (0.7-1.3 g),
    descent, landing roll."""
    u = rng.uniform
    m.coordinated = True
    m.speed_to(35.0, 2.5).grade_to(10.0, 4.0).speed_to(50.0, 1.0).cruise(20.0)
    m.grade_to(0.0, 6.0)
    while m.t < duration_s - 90.0:
        r = rng.random()
        if r < 0.4:
            # standard-rate to steep turns: 3-12 deg/s at 40-65 m/s, bank up to ~50 deg
            m.turn(float(rng.choice([-1, 1])) * u(90, 270), u(3, 12)).cruise(u(5, 15))
        elif r < 0.7:
            g = u(8, 15)
            m.grade_to(g, u(2.5, 4)).cruise(u(2, 6)).grade_to(-g, u(4, 6)).cruise(u(2, 5))
            m.grade_to(0.0, u(2.5, 4)).cruise(u(5, 15))
        else:
            m.speed_to(u(40, 65), u(0.5, 1.5)).cruise(u(5, 15))
    m.grade_to(-5.0, 6.0).cruise(30.0).grade_to(0.0, 6.0).speed_to(0.0, 2.0).stop(10.0)
    return m.finish()


# ---------------------------------------------------------------------------
# GNSS stream


@dataclass
class GnssSimConfig:
    """The simulated receiver (u-blox class, Doppler velocity)."""

    rate_hz: float = 5.0
    sigma_h_m_s: float = 0.03  #: m/s per horizontal axis, 1 sigma
    sigma_v_m_s: float = 0.05  #: m/s vertical, 1 sigma
    latency_s: float = 0.12  #: time tags late by this much, s
    lever_arm_m: tuple[float, float, float] = (0.0, 0.0, 0.0)  #: IMU -> antenna, body, m
    outages: tuple[tuple[float, float], ...] = ()  #: (start s, duration s): no fix
    outlier_rate: float = 0.005  #: fraction of epochs with a multipath velocity error
    outlier_m_s: tuple[float, float] = (0.5, 2.0)  #: size range of those errors, m/s
    device: str = "/dev/ttyACM0"


def iso_time(unix_s: float) -> str:
    """gpsd's ISO 8601 time with milliseconds, rounded (not truncated)."""
    ms = int(round(unix_s * 1000.0))
    return f"{_iso_second(ms // 1000)}.{ms % 1000:03d}Z"


@functools.lru_cache(maxsize=1024)
def _iso_second(unix_s: int) -> str:
    """The whole second ``unix_s`` as gpsd writes it (a drive's fixes share each second)."""
    return datetime.fromtimestamp(unix_s, UTC).strftime("%Y-%m-%dT%H:%M:%S")


def gnss_reports(
    motion: DriveMotion, cfg: GnssSimConfig | None = None, seed: int = 0
) -> list[dict]:
    """gpsd TPV reports of the drive (module doc), in time order."""
    cfg = cfg or GnssSimConfig()
    rng = np.random.default_rng(seed + 7919)
    tt = np.arange(0.0, motion.duration_s, 1.0 / cfg.rate_hz)
    p = motion._profiles(tt)
    vel = _vel(p)
    lev = np.asarray(cfg.lever_arm_m, dtype=float)
    if np.any(lev):
        c = _attitude(p["psi_b"], p["th"], p["phi"])
        w_nb = _body_rate(p)
        vel = vel + np.einsum("nij,nj->ni", c, np.cross(w_nb, lev))
    sig = np.array([cfg.sigma_h_m_s, cfg.sigma_h_m_s, cfg.sigma_v_m_s])
    vel = vel + rng.normal(0.0, 1.0, vel.shape) * sig
    out = rng.random(len(tt)) < cfg.outlier_rate
    if np.any(out):
        mag = rng.uniform(*cfg.outlier_m_s, int(np.sum(out)))
        d = rng.normal(0, 1, (int(np.sum(out)), 3))
        d[:, 2] *= 0.5
        vel[out] += d / np.linalg.norm(d, axis=1)[:, None] * mag[:, None]
    lat, lon, h = motion.position(tt)
    reports = []
    for i, t in enumerate(tt):
        iso = iso_time(EPOCH_UNIX + t + cfg.latency_s)
        if any(a <= t < a + d for a, d in cfg.outages):
            reports.append({"class": "TPV", "device": cfg.device, "mode": 1, "time": iso})
            continue
        vn, ve, vd = (round(float(x), 4) for x in vel[i])
        speed = math.hypot(vn, ve)
        reports.append(
            {
                "class": "TPV",
                "device": cfg.device,
                "mode": 3,
                "status": 1,
                "time": iso,
                "lat": round(float(lat[i]), 9),
                "lon": round(float(lon[i]), 9),
                "altHAE": round(float(h[i]), 3),
                "velN": vn,
                "velE": ve,
                "velD": vd,
                "speed": round(speed, 4),
                "track": round(math.degrees(math.atan2(ve, vn)) % 360, 3),
                "climb": -vd,
                "eps": round(2 * cfg.sigma_h_m_s, 4),
                "epc": round(2 * cfg.sigma_v_m_s, 4),
            }
        )
    return reports


def write_gpspipe_log(path: str | Path, reports: list[dict], device: str = "/dev/ttyACM0") -> None:
    """Write reports as ``gpspipe -w`` records them: VERSION, DEVICES, WATCH, then TPV lines."""
    head = [
        {"class": "VERSION", "release": "3.22", "rev": "3.22", "proto_major": 3, "proto_minor": 14},
        {"class": "DEVICES", "devices": [{"class": "DEVICE", "path": device, "driver": "u-blox"}]},
        {"class": "WATCH", "enable": True, "json": True},
    ]
    p = Path(path)
    tmp = p.with_name(p.name + ".part")
    with open(tmp, "w", encoding="utf-8") as fh:
        for obj in head + reports:
            fh.write(json.dumps(obj) + "\n")
    tmp.replace(p)


__all__ = [
    "DRIVE_SCENARIOS",
    "EPOCH_UNIX",
    "DriveMotion",
    "GnssSimConfig",
    "drive_motion",
    "gnss_reports",
    "iso_time",
    "simulate_drive",
    "write_gpspipe_log",
]


def simulate_drive(
    scenario: str,
    duration_s: float,
    certificate: object,
    seed: int = 0,
    rate_hz: float = 100.0,
    gnss: GnssSimConfig | None = None,
    faults: tuple = (),
    effects: object | None = None,
    slip_rad_per_m_s2: float = 0.0,
) -> tuple[object, list[dict], DriveMotion]:
    """(SimResult with t in UTC Unix s from :data:`EPOCH_UNIX`, TPV reports, motion);
    ``slip_rad_per_m_s2``: the side slip of :class:`DriveMotion` (0: none)."""
    from .simulator import simulate

    motion = drive_motion(scenario, duration_s, seed)
    motion.slip_rad_per_m_s2 = float(slip_rad_per_m_s2)
    res = simulate(certificate, motion.sample(rate_hz), seed=seed, faults=faults, effects=effects)  # type: ignore[arg-type]
    res.samples.t = res.samples.t + EPOCH_UNIX
    return res, gnss_reports(motion, gnss, seed), motion

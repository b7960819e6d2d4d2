"""Vibration of a vehicle's installation, added to a trajectory's true motion: broadband
random vibration plus engine harmonics, and shocks (a pothole) that clip the sensor.

Vibration is motion, not sensor noise: it is added to the trajectory's specific force
(m/s^2) and angular rate (rad/s) before the sensor model, so the simulated board measures
it as it would measure a car's engine and road. :func:`add_vibration` returns the new
trajectory and the vibration added (what a check should report).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from .trajectories import Trajectory


@dataclass
class Vibration:
    """A vibration profile. The RMS level of each window of ``level_step_s`` seconds is
    drawn between ``accel_rms`` (low, high) m/s^2 per axis, the angular level is
    ``gyro_per_accel`` rad/s per m/s^2 of it; ``harmonic_share`` of the power is in engine
    harmonics at ``harmonics_hz`` (amplitudes equal, phases random), the rest broadband in
    ``band_hz``. Only where ``while_moving`` the trajectory is not static (an engine that
    stops at a standstill), else throughout. ``shocks``: (t s, duration s, axis 0-2,
    m/s^2) pulses added to the specific force."""

    accel_rms: tuple[float, float] = (0.5, 5.0)
    gyro_per_accel: float = 0.05
    harmonics_hz: tuple[float, ...] = (25.0, 37.5)
    harmonic_share: float = 0.5
    band_hz: tuple[float, float] = (6.0, 45.0)
    level_step_s: float = 10.0
    while_moving: bool = True
    shocks: list[tuple[float, float, int, float]] = field(default_factory=list)


def _band_noise(
    rng: np.random.Generator, n: int, rate: float, band: tuple[float, float]
) -> np.ndarray:
    """(n, 3) unit-RMS Gaussian noise confined to ``band`` (Hz) by an FFT mask."""
    x = rng.standard_normal((n, 3))
    spec = np.fft.rfft(x, axis=0)
    f = np.fft.rfftfreq(n, 1.0 / rate)
    spec[(f < band[0]) | (f > min(band[1], rate / 2.0))] = 0.0
    y = np.fft.irfft(spec, n=n, axis=0)
    rms = np.sqrt(np.mean(y * y, axis=0))
    return y / np.where(rms > 0, rms, 1.0)


def add_vibration(traj: Trajectory, vib: Vibration, seed: int = 0) -> tuple[Trajectory, np.ndarray]:
    """``traj`` with ``vib`` added; and the vibration added (N, 6): angular rate (rad/s)
    then specific force (m/s^2), shocks included."""
    rng = np.random.default_rng(seed)
    n = len(traj)
    rate = float(traj.rate_hz)
    t = traj.t - traj.t[0]
    share = float(vib.harmonic_share)
    unit = np.zeros((n, 6))
    for part in range(2):  # gyro, accel: independent of each other
        broad = _band_noise(rng, n, rate, vib.band_hz)
        harm = np.zeros((n, 3))
        for f in vib.harmonics_hz:
            phase = rng.uniform(0, 2 * np.pi, 3)
            harm += np.sqrt(2.0) * np.sin(2 * np.pi * f * t[:, None] + phase)
        if vib.harmonics_hz:
            harm /= np.sqrt(len(vib.harmonics_hz))
        unit[:, 3 * part : 3 * part + 3] = np.sqrt(1 - share) * broad + np.sqrt(share) * harm
    # the level: one draw per window of level_step_s, per axis
    k = np.floor(t / vib.level_step_s).astype(np.int64)
    lo, hi = vib.accel_rms
    levels = rng.uniform(lo, hi, (int(k.max()) + 1 if n else 0, 3))
    level = levels[k] if n else np.zeros((0, 3))
    on = ~traj.static if vib.while_moving else np.ones(n, dtype=bool)
    added = np.zeros((n, 6))
    added[:, :3] = unit[:, :3] * level * vib.gyro_per_accel
    added[:, 3:] = unit[:, 3:] * level
    added[~on] = 0.0
    for t0, dur, axis, value in vib.shocks:
        m = (t >= t0) & (t < t0 + dur)
        added[m, 3 + int(axis)] += float(value)
    out = replace(
        traj,
        omega=traj.omega + added[:, :3],
        specific_force=traj.specific_force + added[:, 3:],
    )
    return out, added


__all__ = ["Vibration", "add_vibration"]

"""Hidden-effect sessions for the model-check tests (shared by tests and the benchmark).

Under a seed, one effect of the catalogue (or none) is drawn with a random sensor and
magnitude and hidden in a simulated session of the bundled ADXRS300/ADXL202 board: a
cyclic multi-position session (14 attitudes: the six faces and the eight cube diagonals;
16 s dwells, 2 s turns) at 100 Hz with a warm-up and a temperature swing, 300 s; a gyro
scale effect (seen only while the unit turns) gets the same session with 5 s dwells and
1.5 s turns (45 turns instead of 16).
Magnitudes are drawn from ranges the session can resolve (about 6 to 30 standard
deviations of the estimate); the test then checks that the model check names that effect
and sensor with a value inside the stated tolerance.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from imudiag.certificate import Certificate
from imudiag.sim import BiasStep, Effects, PeriodicDisturbance, TemperatureProfile, simulate
from imudiag.sim.trajectories import multi_position_motion

RATE_HZ = 100.0
TURNS_MOTION_SEED = 5
DURATION_S = 300.0

#: effects a still / multi-position session can show, with the sensors they apply to
HIDDEN = (
    "none",
    "bias_drift",
    "temperature_bias",
    "temperature_scale",
    "g_sensitivity",
    "scale_nonlinearity",
    "bias_step",
    "periodic_disturbance",
)
GYROS = ("gx", "gy", "gz")
ACCELS = ("ax", "ay", "az")

#: relative tolerance on the value (and absolute ones where stated)
TOLERANCE = {
    "temperature_bias": 0.2,
    "temperature_scale": 0.2,  # gyros: 0.35 (from 45 turns)
    "scale_nonlinearity": 0.2,  # gyros: 0.3
    "g_sensitivity": 0.2,  # of the row's largest component, on every component
    "bias_step": 0.15,
    "periodic_disturbance": 0.15,  # amplitude; frequency within one PSD bin
    "bias_drift": 0.45,  # a random-walk coefficient from a few minutes of data
}


GYRO_TOLERANCE = {"temperature_scale": 0.35, "scale_nonlinearity": 0.3}


@dataclass
class Hidden:
    """The truth of one hidden-effect session."""

    name: str
    sensor: str | None
    value: float | list[float] | None
    extra: dict = field(default_factory=dict)

    @property
    def turns(self) -> bool:
        """A gyro scale effect: the session needs many turns."""
        return self.sensor in GYROS and self.name in GYRO_TOLERANCE

    @property
    def tolerance(self) -> float:
        """Relative tolerance on the value."""
        if self.turns:
            return GYRO_TOLERANCE[self.name]
        return TOLERANCE[self.name]


def draw(seed: int) -> tuple[Hidden, Effects]:
    """The hidden effect and the simulator effects for ``seed`` (the effect cycles with the
    seed so every one is covered; sensor, magnitude and sign are random)."""
    rng = np.random.default_rng(1000 + seed)
    name = HIDDEN[seed % len(HIDDEN)]
    sign = float(rng.choice([-1.0, 1.0]))
    temp = TemperatureProfile(
        start_c=float(rng.uniform(20.0, 24.0)),
        warmup_c=float(rng.uniform(10.0, 14.0)),
        warmup_tau_s=float(rng.uniform(120.0, 180.0)),
        swing_c=float(rng.uniform(2.0, 3.0)),
        swing_period_s=float(rng.uniform(90.0, 130.0)),
    )
    kw: dict = {"temperature": temp}
    hidden = Hidden(name, None, None)
    if name == "bias_drift":
        s = str(rng.choice(GYROS + ACCELS))
        k = float(rng.uniform(0.9, 2.0) if s in GYROS else rng.uniform(0.3, 0.6))
        kw["bias_drift"] = {s: k}
        hidden = Hidden(name, s, k)
    elif name == "temperature_bias":
        s = str(rng.choice(GYROS + ACCELS))
        c = sign * float(rng.uniform(1.0, 3.0) if s in GYROS else rng.uniform(0.9, 1.6))
        kw["temperature_bias"] = {s: c}
        hidden = Hidden(name, s, c)
    elif name == "temperature_scale":
        s = str(rng.choice(GYROS + ACCELS))
        c = sign * float(rng.uniform(1.3e-3, 2e-3) if s in GYROS else rng.uniform(1.5e-4, 4e-4))
        kw["temperature_scale"] = {s: c}
        hidden = Hidden(name, s, c)
    elif name == "g_sensitivity":
        s = str(rng.choice(GYROS))
        row = rng.uniform(-1.5, 1.5, 3)
        row[int(rng.integers(3))] = sign * float(rng.uniform(0.8, 1.5))
        g = np.zeros((3, 3))
        g[GYROS.index(s)] = row
        kw["g_sensitivity"] = g
        hidden = Hidden(name, s, [float(v) for v in row])
    elif name == "scale_nonlinearity":
        s = str(rng.choice(GYROS + ACCELS))
        q = sign * float(rng.uniform(4e-3, 6e-3) if s in GYROS else rng.uniform(0.02, 0.06))
        kw["scale_nonlinearity"] = {s: q}
        hidden = Hidden(name, s, q)
    elif name == "bias_step":
        s = str(rng.choice(GYROS + ACCELS))
        size = sign * float(rng.uniform(12.0, 25.0) if s in GYROS else rng.uniform(3.0, 8.0))
        t = float(rng.uniform(60.0, 240.0))
        kw["bias_step"] = [BiasStep(s, t, size)]
        hidden = Hidden(name, s, size, {"t": t})
    elif name == "periodic_disturbance":
        s = str(rng.choice(GYROS + ACCELS))
        amp = float(rng.uniform(12.0, 30.0) if s in GYROS else rng.uniform(1.8, 4.0))
        f = float(rng.uniform(2.0, 45.0))
        kw["periodic_disturbance"] = [PeriodicDisturbance(s, amp, f, float(rng.uniform(0, 6)))]
        hidden = Hidden(name, s, amp, {"frequency": f})
    return hidden, Effects.board(**kw)


def session(
    certificate: Certificate,
    seed: int,
    effects: Effects,
    duration_s: float = DURATION_S,
    rate_hz: float = RATE_HZ,
    turns: bool = False,
):
    """Simulate the cyclic multi-position session with ``effects`` (``turns``: short dwells,
    many turns); returns the SimResult."""
    dwell, turn = (5.0, 1.5) if turns else (16.0, 2.0)
    # a gyro-scale session needs turns about every axis in both senses: a fixed schedule
    # that has them (the turn axes depend on the motion seed), the noise still seeded
    motion = multi_position_motion(
        14, dwell, turn, seed=TURNS_MOTION_SEED if turns else seed, cyclic=True
    )
    traj = motion.sample(rate_hz, n=int(duration_s * rate_hz))
    return simulate(certificate, traj, seed=seed, effects=effects)


def value_ok(hidden: Hidden, effect: dict, psd_resolution_hz: float) -> tuple[bool, str]:
    """Whether a reported effect's value matches the hidden one (and why not)."""
    tol = hidden.tolerance
    v = effect["value"]
    if hidden.name == "g_sensitivity":
        true = np.asarray(hidden.value, dtype=float)
        err = np.max(np.abs(np.asarray(v, dtype=float) - true))
        ok = err <= tol * np.max(np.abs(true))
        return bool(ok), f"g_sensitivity {v} vs {hidden.value}"
    true = float(hidden.value)  # type: ignore[arg-type]
    ok = abs(float(v) - true) <= tol * abs(true)
    msg = f"{hidden.name} {v} vs {true}"
    if hidden.name == "bias_step":
        lo, hi = effect["t_range"]
        ok = ok and (lo - 1.0 <= hidden.extra["t"] <= hi + 1.0)
        msg += f", t {effect['t']} {effect['t_range']} vs {hidden.extra['t']}"
    if hidden.name == "periodic_disturbance":
        ok = ok and abs(effect["frequency"] - hidden.extra["frequency"]) <= psd_resolution_hz
        msg += f", f {effect['frequency']} vs {hidden.extra['frequency']}"
    return ok, msg

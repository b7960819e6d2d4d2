"""Switchable sensor effects beyond the certificate's linear model (physical units).

Names follow the effect catalogue of spec/reports.md. Every effect is off by
default except white noise from the certificate's noise density. Per-sensor
effects are dicts keyed by sensor name (``gx gy gz ax ay az``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

SENSORS = ("gx", "gy", "gz", "ax", "ay", "az")


def sensor_index(name: str) -> int:
    """Column 0..5 of sensor ``gx gy gz ax ay az``; ValueError names a bad sensor."""
    try:
        return SENSORS.index(name)
    except ValueError:
        raise ValueError(f"unknown sensor {name!r}; expected one of {' '.join(SENSORS)}") from None


@dataclass(frozen=True)
class BiasStep:
    """A bias step of ``size`` output units on ``sensor`` at ``t_s`` seconds."""

    sensor: str
    t_s: float
    size: float


@dataclass(frozen=True)
class PeriodicDisturbance:
    """``amplitude * sin(2 pi frequency_hz t + phase_rad)`` output units on ``sensor``."""

    sensor: str
    amplitude: float
    frequency_hz: float
    phase_rad: float = 0.0


@dataclass(frozen=True)
class TemperatureProfile:
    """Board temperature, degC: start + warmup (1 - exp(-t / warmup_tau_s)) + ramp t
    + swing sin(2 pi t / swing_period_s)."""

    start_c: float = 25.0
    warmup_c: float = 0.0  #: degC gained during warm-up
    warmup_tau_s: float = 300.0  #: s
    ramp_c_per_s: float = 0.0  #: degC/s
    swing_c: float = 0.0  #: degC amplitude
    swing_period_s: float = 600.0  #: s

    def __call__(self, t: np.ndarray) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        temp = self.start_c + self.ramp_c_per_s * t
        if self.warmup_c:
            temp = temp + self.warmup_c * (1.0 - np.exp(-t / self.warmup_tau_s))
        if self.swing_c:
            temp = temp + self.swing_c * np.sin(2.0 * math.pi * t / self.swing_period_s)
        return temp


@dataclass
class Effects:
    """Everything the simulated sensor does beyond ``U = B + diag(S) N x``.

    Units: output units (counts for the default board) unless stated; input
    units are the certificate's (deg/s, m/s^2 for the default board).
    """

    #: white noise with the certificate's density, sigma = density sqrt(rate / 2) per sample
    white_noise: bool = True
    noise_scale: float = 1.0  #: multiplier of that sigma
    #: bias random walk, output units / sqrt(s), per sensor
    bias_drift: dict[str, float] = field(default_factory=dict)
    #: first-order Gauss-Markov bias instability, per sensor: (sigma output units, tau s)
    bias_instability: dict[str, tuple[float, float]] = field(default_factory=dict)
    #: flicker floor (IEEE bias instability B, output units: Allan deviation 0.664 B flat
    #: over ``flicker_band``), per sensor; a sum of Gauss-Markov processes
    flicker: dict[str, float] = field(default_factory=dict)
    #: cluster times (low, high), s, over which the flicker floor is flat
    flicker_band: tuple[float, float] = (0.1, 1.0e4)
    #: rate ramp R, output units / s (a bias growing as R t), per sensor
    rate_ramp: dict[str, float] = field(default_factory=dict)
    #: quantisation of an integrating output, per sensor: step q (output units per sample,
    #: 1 = one count) of the accumulated output, each sample the increment with the remainder
    #: carried (a delta-angle counter). IEEE 952 term Q = q / (rate sqrt(12)) u s, Allan
    #: variance 3 Q^2 / tau^2. (``quantize`` rounds each sample on its own: white noise.)
    quantization: dict[str, float] = field(default_factory=dict)
    #: board temperature over time (degC); None: constant ``temperature_reference``
    temperature: TemperatureProfile | Callable[[np.ndarray], np.ndarray] | None = None
    temperature_reference: float = 25.0  #: degC at which the certificate's B, S, E hold
    #: bias change, output units per degC, per sensor
    temperature_bias: dict[str, float] = field(default_factory=dict)
    #: relative scale-factor change per degC, per sensor
    temperature_scale: dict[str, float] = field(default_factory=dict)
    #: gyro g-sensitivity (3, 3): gyro output units per accel input unit, rows gx gy gz
    g_sensitivity: np.ndarray | None = None
    #: scale nonlinearity, output units per (input unit)^2 (on N x), per sensor
    scale_nonlinearity: dict[str, float] = field(default_factory=dict)
    bias_step: list[BiasStep] = field(default_factory=list)
    periodic_disturbance: list[PeriodicDisturbance] = field(default_factory=list)
    #: round outputs to whole counts
    quantize: bool = False
    #: output range (low, high) in output units, one pair for all or a dict per triad;
    #: outside it the output is clipped and flag bit0 (gyro) / bit1 (accel) set
    saturation: tuple[float, float] | dict[str, tuple[float, float]] | None = None
    #: probability per sample of an ADC error: flag bit2, one channel garbage in the range
    adc_error_rate: float = 0.0
    #: probability per frame that it is lost (gap in seq and t)
    drop_rate: float = 0.0
    #: standard deviation of time-stamp jitter, s (truncated at 0.45 sample periods)
    jitter_s: float = 0.0

    def __post_init__(self) -> None:
        self.bias_step = [s if isinstance(s, BiasStep) else BiasStep(*s) for s in self.bias_step]
        self.periodic_disturbance = [
            p if isinstance(p, PeriodicDisturbance) else PeriodicDisturbance(*p)
            for p in self.periodic_disturbance
        ]
        for name in (
            "bias_drift",
            "bias_instability",
            "flicker",
            "rate_ramp",
            "quantization",
            "temperature_bias",
            "temperature_scale",
            "scale_nonlinearity",
        ):
            for sensor in getattr(self, name):
                sensor_index(sensor)
        for sensor, q in self.quantization.items():
            if not q > 0:
                raise ValueError(f"quantization[{sensor}]: need a step > 0, got {q}")
        for s in self.bias_step:
            sensor_index(s.sensor)
        for p in self.periodic_disturbance:
            sensor_index(p.sensor)
        if self.g_sensitivity is not None:
            g = np.asarray(self.g_sensitivity, dtype=float)
            if g.shape == (3,):
                g = np.diag(g)
            if g.shape != (3, 3):
                raise ValueError("g_sensitivity must be a 3x3 matrix (or 3 diagonal values)")
            self.g_sensitivity = g
        for name in ("adc_error_rate", "drop_rate"):
            v = getattr(self, name)
            if not 0.0 <= v < 1.0:
                raise ValueError(f"{name} must be in [0, 1), got {v}")
        if self.jitter_s < 0:
            raise ValueError(f"jitter_s must be >= 0 s, got {self.jitter_s}")

    # -- helpers ------------------------------------------------------------

    @staticmethod
    def per_sensor(values: Mapping[str, float]) -> np.ndarray:
        """A (6,) array from a {sensor: value} dict (zeros elsewhere)."""
        out = np.zeros(6)
        for k, v in values.items():
            out[sensor_index(k)] = float(v)
        return out

    def saturation_range(self, triad: str) -> tuple[float, float] | None:
        """(low, high) output range of ``triad`` or None."""
        if self.saturation is None:
            return None
        if isinstance(self.saturation, Mapping):
            r = self.saturation.get(triad)
            return None if r is None else (float(r[0]), float(r[1]))
        lo, hi = self.saturation
        return float(lo), float(hi)

    @classmethod
    def board(cls, **overrides: Any) -> Effects:
        """The simulated 16-bit USB board: white noise, whole counts, ADC range 0..65535."""
        kw: dict[str, Any] = {"quantize": True, "saturation": (0.0, 65535.0)}
        kw.update(overrides)
        return cls(**kw)

    @classmethod
    def none(cls) -> Effects:
        """No noise and no effects at all: the certificate's model exactly."""
        return cls(white_noise=False)

    @classmethod
    def all_on(cls, **overrides: Any) -> Effects:
        """Every effect on at a moderate, data-sheet-like size (for benchmarks and tests)."""
        kw: dict[str, Any] = {
            "bias_drift": {s: 0.05 for s in SENSORS},
            "bias_instability": {s: (2.0, 100.0) for s in SENSORS},
            "temperature": TemperatureProfile(
                start_c=22.0, warmup_c=12.0, warmup_tau_s=600.0, ramp_c_per_s=0.001
            ),
            "temperature_bias": {
                "gx": 1.5,
                "gy": -1.0,
                "gz": 0.8,
                "ax": 0.6,
                "ay": -0.4,
                "az": 0.5,
            },
            "temperature_scale": {s: 2e-4 for s in SENSORS},
            "g_sensitivity": np.diag([1.34, 1.34, 1.34]),
            "scale_nonlinearity": {
                "gx": 1e-4,
                "gy": 1e-4,
                "gz": 1e-4,
                "ax": 0.02,
                "ay": 0.02,
                "az": 0.02,
            },
            "bias_step": [BiasStep("gz", 600.0, 15.0)],
            "periodic_disturbance": [PeriodicDisturbance("ay", 3.0, 50.0)],
            "quantize": True,
            "saturation": (0.0, 65535.0),
            "adc_error_rate": 1e-5,
            "drop_rate": 1e-4,
            "jitter_s": 2e-5,
        }
        kw.update(overrides)
        return cls(**kw)

"""Named scenarios and the text forms of effects and faults (``sim://`` URLs, ``imudiag simulate``).

Scenarios (parameters as ``key=value``; times s, angles deg, rates deg/s):

``static`` (the default; endless)
    The board still in ``n`` (4) attitudes, the first level, held ``dwell`` (20) s each,
    slow ``turn`` (4) s turns between, repeating.
``still`` (endless)
    One attitude, ``roll`` ``pitch`` ``yaw`` (0 0 0) deg: for noise statistics.
``multiposition`` (finite: first_dwell + (n-1)(turn+dwell) s; endless with ``loop=1``)
    ``n`` (12) well-spread attitudes, ``dwell`` (3) s, ``turn`` (1.5) s, ``first_dwell`` (dwell).
``turntable`` (endless)
    Rotation at ``turn_rate`` (30) deg/s about body ``axis`` (z) held vertical, after a
    ``ramp`` (2) s spin-up.
``vehicle`` (finite, 32 s with the defaults)
    ``still`` (10) s, take-off run to ``speed`` (20) m/s in ``accel`` (8) s, ``cruise`` (4) s,
    a sharp ``turn_deg`` (90) deg turn in ``turn`` (4) s, ``final`` (6) s.
``urban``, ``highway``, ``hilly``, ``aircraft`` (finite, about ``length`` (600) s)
    Drives of :mod:`.drive`; ``slip`` (0) rad per m/s^2: the body heads that much per
    m/s^2 of lateral acceleration off the course (a side slip, for the no-slip test).

Effects (``--effect`` / ``effect=``; units of spec/reports.md, output units = counts
for the bundled board):

=====================================  ================================================
``board``                              whole counts, range 0..65535 (the default)
``none``                               no noise, no quantisation: the bare model
``all``                                every effect on (:meth:`Effects.all_on`)
``noise:SCALE``                        white-noise multiplier (0 = off)
``bias_drift:S:K``                     random walk, output units/sqrt(s)
``bias_instability:S:SIGMA:TAU``       Gauss-Markov, output units and s
``flicker:S:B[:TAU_LOW:TAU_HIGH]``     flicker floor B (output units), flat over that tau band
``rate_ramp:S:R``                      rate ramp, output units/s
``quantization:S:STEP``                integrating output quantised in STEP output units
                                       (remainder carried): Q = STEP / (rate sqrt(12))
``temperature:START:WARMUP:TAU[:RAMP]`` profile: degC, degC, s, degC/s
``temperature_bias:S:C``               output units/degC
``temperature_scale:S:C``              relative/degC
``g_sensitivity:GS:KX:KY:KZ``          row of gyro GS, output units per accel input unit
``scale_nonlinearity:S:Q``             output units per (input unit)^2
``bias_step:S:T:SIZE``                 at T s, output units
``periodic_disturbance:S:AMP:FREQ``    output units, Hz
``quantize`` / ``saturation:LOW:HIGH`` whole counts / output range
``adc_error:P`` ``drop:P`` ``jitter:S`` probability per sample / per frame, jitter s
=====================================  ================================================

Faults: ``kind:sensor:t_s[:value]`` (see :mod:`imudiag.sim.faults`), e.g. ``bias:ax:30:150``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Iterable, Mapping

import numpy as np

from .. import validate
from .effects import BiasStep, Effects, PeriodicDisturbance, TemperatureProfile, sensor_index
from .faults import Fault, parse_fault
from .trajectories import (
    Motion,
    VehicleRun,
    multi_position_motion,
    static_cycle_motion,
    still_motion,
    turntable_motion,
)

SCENARIOS = (
    "static",
    "still",
    "multiposition",
    "turntable",
    "vehicle",
    "urban",
    "highway",
    "hilly",
    "aircraft",
)
#: Drives with a consistent GNSS stream (imudiag.sim.drive); their time is UTC Unix seconds.
DRIVES = ("urban", "highway", "hilly", "aircraft")
_PARAMS: dict[str, tuple[str, ...]] = {
    "static": ("n", "dwell", "turn", "latitude"),
    "still": ("roll", "pitch", "yaw", "latitude"),
    "multiposition": ("n", "dwell", "turn", "first_dwell", "loop", "latitude"),
    "turntable": ("turn_rate", "axis", "ramp", "latitude"),
    "vehicle": ("still", "accel", "speed", "cruise", "turn", "turn_deg", "final", "latitude"),
    **{d: ("length", "slip") for d in DRIVES},
}


#: Bounds of the numeric scenario parameters: (lowest, highest, lowest allowed itself, unit);
#: times and lengths are never negative, a latitude lies within +-90 deg. Others (angles,
#: turn rates, slip) take any finite number.
_BOUNDS: dict[str, tuple[float, float, bool, str]] = {
    "latitude": (-90.0, 90.0, True, "deg"),
    "dwell": (0.0, math.inf, True, "s"),
    "first_dwell": (0.0, math.inf, True, "s"),
    "turn": (0.0, math.inf, False, "s"),
    "ramp": (0.0, math.inf, True, "s"),
    "length": (0.0, math.inf, False, "s"),
    "still": (0.0, math.inf, True, "s"),
    "accel": (0.0, math.inf, False, "s"),
    "speed": (0.0, math.inf, True, "m/s"),
    "cruise": (0.0, math.inf, True, "s"),
    "final": (0.0, math.inf, True, "s"),
}
#: Parameters that are whole numbers: (lowest, highest).
_INTEGERS: dict[str, tuple[int, int]] = {"n": (1, 10**6), "loop": (0, 1)}


def _check_bounds(sc: str, key: str, v: float) -> float:
    """``v`` when the value of parameter ``key`` is within its bounds (BadInput if not)."""
    where = f"scenario {sc}: {key}"
    if key in _INTEGERS:
        lo_i, hi_i = _INTEGERS[key]
        return validate.integer(int(v) if v == int(v) else v, where, lo_i, hi_i)
    if key in _BOUNDS:
        lo, hi, closed, unit = _BOUNDS[key]
        return validate.number(v, where, lo, hi, lo_open=not closed, unit=unit)
    return v


def scenario_names() -> tuple[str, ...]:
    """Every scenario name (``default`` is an alias of ``static``)."""
    return SCENARIOS


def scenario_params(name: str) -> tuple[str, ...]:
    """The parameter keys scenario ``name`` accepts."""
    return _PARAMS[canonical_scenario(name)]


def canonical_scenario(name: str) -> str:
    """The scenario called ``name`` (empty or ``default``: ``static``); ValueError if unknown."""
    name = (name or "static").strip().lower()
    if name in ("", "default"):
        return "static"
    if name not in SCENARIOS:
        raise ValueError(
            f"unknown scenario {name!r}; expected one of {', '.join(SCENARIOS)} (or default)"
        )
    return name


def scenario_motion(name: str, seed: int = 0, params: Mapping[str, str] | None = None) -> Motion:
    """The motion of scenario ``name`` with ``params`` (text values; unknown keys are an error)."""
    sc = canonical_scenario(name)
    params = dict(params or {})
    for key in params:
        if key not in _PARAMS[sc]:
            raise ValueError(
                f"scenario {sc}: unknown parameter {key!r}; expected {', '.join(_PARAMS[sc])}"
            )

    def num(key: str, default: float) -> float:
        if key not in params:
            return default
        try:
            v = float(params[key])
        except ValueError:
            raise ValueError(
                f"scenario {sc}: {key} must be a number, got {params[key]!r}"
            ) from None
        if not math.isfinite(v):
            raise ValueError(f"scenario {sc}: {key} must be finite, got {params[key]!r}")
        _check_bounds(sc, key, v)
        return v

    if sc in DRIVES:
        from .drive import drive_motion

        drive = drive_motion(sc, num("length", 600.0), seed)
        drive.slip_rad_per_m_s2 = num("slip", 0.0)
        return drive
    lat = num("latitude", 45.0)
    if sc == "static":
        return static_cycle_motion(
            int(num("n", 4)), num("dwell", 20.0), num("turn", 4.0), seed, latitude_deg=lat
        )
    if sc == "still":
        return still_motion(
            attitude_rpy_deg=(num("roll", 0.0), num("pitch", 0.0), num("yaw", 0.0)),
            latitude_deg=lat,
        )
    if sc == "multiposition":
        first = num("first_dwell", -1.0)
        return multi_position_motion(
            int(num("n", 12)),
            num("dwell", 3.0),
            num("turn", 1.5),
            seed,
            first_dwell_s=None if first < 0 else first,
            latitude_deg=lat,
            cyclic=bool(num("loop", 0.0)),
        )
    if sc == "turntable":
        return turntable_motion(
            num("turn_rate", 30.0),
            params.get("axis", "z"),
            ramp_s=num("ramp", 2.0),
            latitude_deg=lat,
        )
    return VehicleRun(
        num("still", 10.0),
        num("accel", 8.0),
        num("speed", 20.0),
        num("cruise", 4.0),
        num("turn", 4.0),
        num("turn_deg", 90.0),
        num("final", 6.0),
        latitude_deg=lat,
    )


# ---------------------------------------------------------------------------
# effects text


def _floats(parts: list[str], n: int, spec: str) -> list[float]:
    if len(parts) != n:
        raise ValueError(f"effect {spec!r}: expected {n} numbers after the name")
    try:
        vals = [float(p) for p in parts]
    except ValueError:
        raise ValueError(f"effect {spec!r}: not a number") from None
    if not all(math.isfinite(v) for v in vals):
        raise ValueError(f"effect {spec!r}: values must be finite")
    return vals


def _sensor(name: str, spec: str) -> str:
    try:
        sensor_index(name)
    except ValueError as exc:
        raise ValueError(f"effect {spec!r}: {exc}") from None
    return name


def apply_effect(effects: Effects, spec: str) -> Effects:
    """``effects`` with one text effect (module docstring) applied; ValueError names it."""
    parts = spec.strip().split(":")
    name, rest = parts[0].strip().lower(), parts[1:]
    e = dataclasses.replace(
        effects,
        bias_drift=dict(effects.bias_drift),
        bias_instability=dict(effects.bias_instability),
        flicker=dict(effects.flicker),
        rate_ramp=dict(effects.rate_ramp),
        quantization=dict(effects.quantization),
        temperature_bias=dict(effects.temperature_bias),
        temperature_scale=dict(effects.temperature_scale),
        scale_nonlinearity=dict(effects.scale_nonlinearity),
        bias_step=list(effects.bias_step),
        periodic_disturbance=list(effects.periodic_disturbance),
    )
    per_sensor: dict[str, Callable[[str, list[float]], None]] = {
        "bias_drift": lambda s, v: e.bias_drift.__setitem__(s, v[0]),
        "temperature_bias": lambda s, v: e.temperature_bias.__setitem__(s, v[0]),
        "temperature_scale": lambda s, v: e.temperature_scale.__setitem__(s, v[0]),
        "scale_nonlinearity": lambda s, v: e.scale_nonlinearity.__setitem__(s, v[0]),
    }
    if name == "board" and not rest:
        return Effects.board()
    if name == "none" and not rest:
        return Effects.none()
    if name == "all" and not rest:
        return Effects.all_on()
    if name == "quantize" and not rest:
        e.quantize = True
    elif name in per_sensor:
        if not rest:
            raise ValueError(f"effect {spec!r}: expected {name}:SENSOR:VALUE")
        per_sensor[name](_sensor(rest[0], spec), _floats(rest[1:], 1, spec))
    elif name == "flicker":
        if not rest or len(rest) not in (2, 4):
            raise ValueError(f"effect {spec!r}: expected flicker:SENSOR:B[:TAU_LOW:TAU_HIGH]")
        vals = _floats(rest[1:], len(rest) - 1, spec)
        if vals[0] < 0:
            raise ValueError(f"effect {spec!r}: need B >= 0")
        if len(vals) == 3:
            if not 0 < vals[1] < vals[2]:
                raise ValueError(f"effect {spec!r}: need 0 < TAU_LOW < TAU_HIGH s")
            e.flicker_band = (vals[1], vals[2])
        e.flicker[_sensor(rest[0], spec)] = vals[0]
    elif name == "rate_ramp":
        if len(rest) != 2:
            raise ValueError(f"effect {spec!r}: expected rate_ramp:SENSOR:R")
        e.rate_ramp[_sensor(rest[0], spec)] = _floats(rest[1:], 1, spec)[0]
    elif name == "quantization":
        if len(rest) != 2:
            raise ValueError(f"effect {spec!r}: expected quantization:SENSOR:STEP")
        step = _floats(rest[1:], 1, spec)[0]
        if not step > 0:
            raise ValueError(f"effect {spec!r}: need STEP > 0 (output units)")
        e.quantization[_sensor(rest[0], spec)] = step
    elif name == "bias_instability":
        if not rest:
            raise ValueError(f"effect {spec!r}: expected bias_instability:SENSOR:SIGMA:TAU")
        sigma, tau = _floats(rest[1:], 2, spec)
        if sigma < 0 or tau <= 0:
            raise ValueError(f"effect {spec!r}: need SIGMA >= 0 and TAU > 0 s")
        e.bias_instability[_sensor(rest[0], spec)] = (sigma, tau)
    elif name == "temperature":
        vals = _floats(rest, 4 if len(rest) == 4 else 3, spec)
        if vals[2] <= 0:
            raise ValueError(f"effect {spec!r}: the warm-up time constant must be > 0 s")
        e.temperature = TemperatureProfile(
            start_c=vals[0],
            warmup_c=vals[1],
            warmup_tau_s=vals[2],
            ramp_c_per_s=vals[3] if len(vals) == 4 else 0.0,
        )
    elif name == "g_sensitivity":
        if not rest or rest[0] not in ("gx", "gy", "gz"):
            raise ValueError(f"effect {spec!r}: expected g_sensitivity:gx|gy|gz:KX:KY:KZ")
        row = _floats(rest[1:], 3, spec)
        g = np.zeros((3, 3)) if e.g_sensitivity is None else np.array(e.g_sensitivity, float)
        g[sensor_index(rest[0])] = row
        e.g_sensitivity = g
    elif name == "bias_step":
        if not rest:
            raise ValueError(f"effect {spec!r}: expected bias_step:SENSOR:T:SIZE")
        t_s, size = _floats(rest[1:], 2, spec)
        e.bias_step.append(BiasStep(_sensor(rest[0], spec), t_s, size))
    elif name == "periodic_disturbance":
        if not rest:
            raise ValueError(f"effect {spec!r}: expected periodic_disturbance:SENSOR:AMP:FREQ")
        vals = _floats(rest[1:], 3 if len(rest) == 4 else 2, spec)
        e.periodic_disturbance.append(PeriodicDisturbance(_sensor(rest[0], spec), *vals))
    elif name == "saturation":
        lo, hi = _floats(rest, 2, spec)
        if not lo < hi:
            raise ValueError(f"effect {spec!r}: need LOW < HIGH")
        e.saturation = (lo, hi)
    elif name in ("adc_error", "drop"):
        (p,) = _floats(rest, 1, spec)
        if not 0.0 <= p < 1.0:
            raise ValueError(f"effect {spec!r}: probability must be in [0, 1)")
        setattr(e, "adc_error_rate" if name == "adc_error" else "drop_rate", p)
    elif name == "jitter":
        (j,) = _floats(rest, 1, spec)
        if j < 0:
            raise ValueError(f"effect {spec!r}: jitter must be >= 0 s")
        e.jitter_s = j
    elif name == "noise":
        (k,) = _floats(rest, 1, spec)
        if k < 0:
            raise ValueError(f"effect {spec!r}: noise scale must be >= 0")
        e.white_noise = k > 0
        e.noise_scale = k if k > 0 else 1.0
    else:
        raise ValueError(f"unknown effect {spec!r}; see `imudiag simulate --help`")
    return e


def parse_effects(specs: Iterable[str], base: Effects | None = None) -> Effects:
    """Apply text effects in order to ``base`` (default: the board preset)."""
    e = base if base is not None else Effects.board()
    for spec in specs:
        e = apply_effect(e, spec)
    return e


def parse_faults(specs: Iterable[str]) -> list[Fault]:
    """Faults from ``kind:sensor:t_s[:value]`` texts."""
    return [parse_fault(s) for s in specs]


def split_list(values: Iterable[str]) -> list[str]:
    """Flatten comma-separated lists (``fault=a,b&fault=c`` -> [a, b, c])."""
    out: list[str] = []
    for v in values:
        out.extend(p.strip() for p in v.split(",") if p.strip())
    return out


def describe(effects: Effects) -> list[str]:
    """Names of the effects that are on (for log metadata)."""
    on = ["white_noise"] if effects.white_noise else []
    for name in (
        "bias_drift",
        "bias_instability",
        "flicker",
        "rate_ramp",
        "quantization",
        "temperature_bias",
        "temperature_scale",
        "scale_nonlinearity",
        "bias_step",
        "periodic_disturbance",
    ):
        if getattr(effects, name):
            on.append(name)
    for name in ("temperature", "g_sensitivity", "saturation"):
        if getattr(effects, name) is not None:
            on.append(name)
    if effects.quantize:
        on.append("quantize")
    for name in ("adc_error_rate", "drop_rate", "jitter_s"):
        if getattr(effects, name) > 0:
            on.append(name)
    return on

"""Calibration certificate, format ``imudiag-certificate/1`` (spec/certificate.md).

Per triad the sensor model is ``U = B + diag(S) N x + w`` with

    N = [[1 + e_x,  D_xz,   -D_xy ],
         [-D_yz,    1 + e_y, D_yx ],
         [ D_zy,   -D_zx,   1 + e_z]]      e_j = E_j / S_j

``x`` in the triad's ``input_unit`` (rad/s or deg/s for gyros, m/s^2 or g for
accelerometers), ``U`` in its ``output_unit``. The optional extended blocks
(temperature, nonlinearity, g-sensitivity) are applied on top when present.

Every rule of the spec is enforced on load: an unknown key, a wrong format, a
missing key, a wrong length, a non-finite number or a non-positive scale
factor raises :class:`CertificateError` naming the key path.
"""

from __future__ import annotations

import copy
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from . import validate, yamlio
from .argtypes import rate_problem
from .errors import CertificateError as _CertificateErrorBase
from .rowwise import BIG_ROWS, rows_op
from .units import STANDARD_GRAVITY_M_S2, TO_SI

FORMAT = "imudiag-certificate/1"

#: Conversion factor from each input unit spec/certificate.md allows to SI (rad/s, m/s^2);
#: the factors are imudiag.units' (the one table of exact conversions).
INPUT_UNITS_TO_SI: dict[str, dict[str, float]] = {
    "gyro": {u: TO_SI["gyro"][u] for u in ("rad/s", "deg/s")},
    "accel": {u: TO_SI["accel"][u] for u in ("m/s^2", "g")},
}
TRIADS = ("gyro", "accel")
AXES = ("x", "y", "z")
SENSOR_NAMES = {"gyro": ("gx", "gy", "gz"), "accel": ("ax", "ay", "az")}
#: Misalignment-difference pairs for d1, d2, d3 (spec/reports.md).
MISALIGNMENT_PAIRS = {
    "gyro": ("gx/gy", "gx/gz", "gy/gz"),
    "accel": ("ax/ay", "ax/az", "ay/az"),
}
MISALIGNMENT_KEYS = ("xz", "xy", "yz", "yx", "zy", "zx")
#: The misalignment sign table (certificate.md), its one definition: the row, column and
#: sign of each D_jk in N = [[1 + e_x, D_xz, -D_xy], [-D_yz, 1 + e_y, D_yx],
#: [D_zy, -D_zx, 1 + e_z]]. Every consumer (the model, the simulator, the model check,
#: the calibration's certificate fields) reads it here (tests/test_conventions.py).
MISALIGNMENT_N_ENTRY: dict[str, tuple[int, int, float]] = {
    "xz": (0, 1, 1.0),
    "xy": (0, 2, -1.0),
    "yz": (1, 0, -1.0),
    "yx": (1, 2, 1.0),
    "zy": (2, 0, 1.0),
    "zx": (2, 1, -1.0),
}
#: The observable differences d1, d2, d3 = D_plus - D_minus, one per pair of
#: :data:`MISALIGNMENT_PAIRS` (x/y, x/z, y/z): (plus key, minus key).
MISALIGNMENT_DIFFERENCES: tuple[tuple[str, str], ...] = (("xz", "yz"), ("zy", "xy"), ("yx", "zx"))


def misalignment_of_n(n: np.ndarray) -> dict[str, float]:
    """The misalignment keys D_jk (rad) that a 3x3 N (dimensionless) holds, read through
    :data:`MISALIGNMENT_N_ENTRY` (the inverse of :meth:`TriadModel.n_matrix` off the
    diagonal)."""
    return {
        key: float(sign * n[row, col]) for key, (row, col, sign) in MISALIGNMENT_N_ENTRY.items()
    }


class CertificateError(_CertificateErrorBase):
    """A certificate that breaks a rule; ``key`` is the offending key path."""

    def __init__(self, key: str, reason: str, source: str | None = None) -> None:
        self.key = key
        self.reason = reason
        self.source = source
        where = f"{source}: " if source else ""
        super().__init__(f"{where}{key}: {reason}")


# ---------------------------------------------------------------------------
# validation helpers


def _finite(value: Any, key: str) -> float:
    return validate.number(value, lambda reason: CertificateError(key, reason))


def _vector(value: Any, key: str, length: int = 3) -> np.ndarray:
    if not isinstance(value, (list, tuple)):
        raise CertificateError(key, f"expected a list of {length} numbers, got {value!r}")
    if len(value) != length:
        raise CertificateError(key, f"expected {length} values, got {len(value)}")
    return np.array([_finite(v, f"{key}[{i}]") for i, v in enumerate(value)], dtype=float)


def _mapping(value: Any, key: str) -> Mapping[str, Any]:
    if not isinstance(value, Mapping):
        raise CertificateError(key, f"expected a mapping, got {type(value).__name__}")
    return value


def _check_keys(
    node: Mapping[str, Any], key: str, required: tuple[str, ...], optional: tuple[str, ...] = ()
) -> None:
    prefix = f"{key}." if key else ""
    for name in node:
        if name not in required and name not in optional:
            raise CertificateError(f"{prefix}{name}", "unknown key")
    for name in required:
        if name not in node:
            raise CertificateError(f"{prefix}{name}", "missing required key")


def _positive(value: float, key: str) -> float:
    if value <= 0.0:
        raise CertificateError(key, f"must be > 0, got {float(value)!r}")
    return value


# ---------------------------------------------------------------------------
# typed objects


@dataclass
class Limits:
    """Tolerances of the paper's predicates (lambda_0 .. lambda_9)."""

    f0: float  #: on 1/2(|u|^2 - 1), dimensionless
    bias: np.ndarray  #: output units, per axis
    scale_factor_error: np.ndarray  #: output per input unit, per axis
    misalignment: np.ndarray  #: rad, on d1, d2, d3


@dataclass
class Uncertainty:
    """Standard deviations of the certified values themselves (a certificate written by a
    calibration: the fit's std), in the units of the values; NaN where not stated."""

    bias: np.ndarray  #: output units, per axis
    scale_factor_error: np.ndarray  #: output per input unit, per axis
    misalignment: np.ndarray  #: rad, on the differences d1, d2, d3 (as the limits)

    def vector(self) -> np.ndarray:
        """(9,) in the order of the diagnosed parameters (bias, scale factor error,
        misalignment differences); NaN where not stated."""
        return np.concatenate([self.bias, self.scale_factor_error, self.misalignment])


#: The keys of ``<triad>.uncertainty``, in the order of :meth:`Uncertainty.vector`.
UNCERTAINTY_KEYS = ("bias", "scale_factor_error", "misalignment")


#: FLICKER_FACTOR * B is the flat Allan deviation of a bias instability B: sqrt(2 ln 2 / pi)
FLICKER_FACTOR = math.sqrt(2.0 * math.log(2.0) / math.pi)

#: The noise fields of a certificate (``<triad>.noise``), each a per-axis vector, with
#: their units ("u" = the triad's output unit) and the IEEE Std 952 / 1554 term they hold.
NOISE_FIELDS: dict[str, tuple[str, str]] = {
    "density": (
        "u/sqrt(Hz)",
        "white noise, one-sided density (angle / velocity random "
        "walk N = density / sqrt(2), u sqrt(s); per-sample sigma = density "
        "sqrt(rate / 2))",
    ),
    "bias_random_walk": ("u/sqrt(s)", "rate random walk K: Allan variance K^2 tau / 3"),
    "quantization": (
        "u s",
        "quantisation noise Q: Allan variance 3 Q^2 / tau^2 (an integrating output, "
        "e.g. a delta-angle counter, quantised in steps q at rate f has "
        "Q = q / (f sqrt(12)); a rate output rounded sample by sample is white noise)",
    ),
    "bias_instability": ("u", "bias instability (flicker floor) B: Allan deviation 0.664 B, flat"),
    "rate_ramp": ("u/s", "rate ramp R: Allan variance R^2 tau^2 / 2"),
    "gauss_markov_sigma": (
        "u",
        "first-order Gauss-Markov bias, steady-state standard deviation (needs gauss_markov_time)",
    ),
    "gauss_markov_time": (
        "s",
        "correlation time of the Gauss-Markov bias, > 0 (needs gauss_markov_sigma)",
    ),
}


@dataclass
class Noise:
    """Noise terms per axis, output units u (:data:`NOISE_FIELDS`: units and meaning)."""

    density: np.ndarray | None = None  #: u / sqrt(Hz), one-sided white-noise density
    bias_random_walk: np.ndarray | None = None  #: u / sqrt(s), rate random walk K
    quantization: np.ndarray | None = None  #: u s, quantisation Q
    bias_instability: np.ndarray | None = None  #: u, flicker floor B
    rate_ramp: np.ndarray | None = None  #: u / s, rate ramp R
    gauss_markov_sigma: np.ndarray | None = None  #: u, Gauss-Markov bias sigma
    gauss_markov_time: np.ndarray | None = None  #: s, Gauss-Markov correlation time

    def allan_deviation(self, tau: np.ndarray | float) -> np.ndarray:
        """Closed-form Allan deviation (u) predicted from the noise terms, shape (3, len(tau)).

        sigma^2(tau) = 3 Q^2/tau^2 + N^2/tau + (0.664 B)^2 + K^2 tau/3 + R^2 tau^2/2
        + s^2 (T/tau)^2 (2 tau/T - 3 + 4 e^(-tau/T) - e^(-2 tau/T)) (IEEE Std 952 Annex C;
        N = density / sqrt(2); the terms are independent). ``tau`` in s.
        """
        t = np.atleast_1d(np.asarray(tau, dtype=float))[None, :]

        def col(v: np.ndarray | None) -> np.ndarray:
            return np.zeros((3, 1)) if v is None else np.asarray(v, float).reshape(3, 1)

        var = col(self.density) ** 2 / 2.0 / t
        var = var + col(self.bias_random_walk) ** 2 * t / 3.0
        var = var + 3.0 * col(self.quantization) ** 2 / t**2
        var = var + (FLICKER_FACTOR * col(self.bias_instability)) ** 2
        var = var + col(self.rate_ramp) ** 2 * t**2 / 2.0
        if self.gauss_markov_sigma is not None and self.gauss_markov_time is not None:
            tc = np.maximum(col(self.gauss_markov_time), 1e-300)
            var = var + col(self.gauss_markov_sigma) ** 2 * markov_allan_shape(t / tc)
        return np.sqrt(var)


def markov_allan_shape(x: np.ndarray) -> np.ndarray:
    """Allan variance of a unit first-order Gauss-Markov process at tau = x T:
    (2x - 3 + 4 e^-x - e^-2x) / x^2, with its series below x = 1e-3."""
    x = np.asarray(x, dtype=float)
    small = x < 1e-3
    xs = np.where(small, x, 1.0)
    xl = np.where(small, 1.0, x)
    series = 2.0 * xs / 3.0 - xs**2 / 2.0
    exact = (2.0 * xl - 3.0 + 4.0 * np.exp(-xl) - np.exp(-2.0 * xl)) / xl**2
    return np.where(small, series, exact)


@dataclass
class Temperature:
    """Temperature dependence of bias and scale factor."""

    reference: float = 25.0  #: degC at which B, S, E hold
    bias_coefficient: np.ndarray = field(default_factory=lambda: np.zeros(3))  #: output/degC
    scale_coefficient: np.ndarray = field(default_factory=lambda: np.zeros(3))  #: 1/degC


def _into(a: np.ndarray, b: np.ndarray | float) -> np.ndarray | None:
    """``a`` as the output of an elementwise operation on ``a`` and ``b``, when the result
    has ``a``'s shape (``b`` broadcasts into it); else None (a new array)."""
    sb = np.shape(b)
    if sb == () or sb == a.shape or sb == a.shape[-1:]:  # the common cases, checked cheaply
        return a
    return a if np.broadcast_shapes(a.shape, sb) == a.shape else None


@dataclass
class TriadModel:
    """One triad's certificate entry and its sensor model (vectorised over N samples)."""

    name: str  #: "gyro" or "accel"
    input_unit: str
    output_unit: str
    scale_factor: np.ndarray  #: S, output per input unit
    scale_factor_error: np.ndarray  #: E, output per input unit
    bias: np.ndarray  #: B, output units
    misalignment: dict[str, float]  #: D_jk, rad
    limits: Limits
    noise: Noise | None = None
    temperature: Temperature | None = None
    nonlinearity: np.ndarray | None = None  #: output per (input unit)^2
    g_sensitivity: np.ndarray | None = None  #: 3x3, gyro output per accel input unit
    #: std of the certified bias, scale factor error and misalignment differences (a
    #: calibration's own uncertainty); None: not stated (taken as exact)
    uncertainty: Uncertainty | None = None

    # -- derived quantities -------------------------------------------------

    @property
    def unit_to_si(self) -> float:
        """Factor from this triad's input unit to SI (rad/s or m/s^2)."""
        return INPUT_UNITS_TO_SI[self.name][self.input_unit]

    @property
    def relative_scale_error(self) -> np.ndarray:
        """e_j = E_j / S_j, dimensionless."""
        return self.scale_factor_error / self.scale_factor

    @property
    def misalignment_differences(self) -> np.ndarray:
        """Observable differences d1 = D_xz - D_yz, d2 = D_zy - D_xy, d3 = D_yx - D_zx, rad."""
        d = self.misalignment
        return np.array([d[plus] - d[minus] for plus, minus in MISALIGNMENT_DIFFERENCES])

    def n_matrix(self) -> np.ndarray:
        """The 3x3 matrix N of the spec (dimensionless)."""
        n = np.diag(1.0 + self.relative_scale_error)
        for key, (row, col, sign) in MISALIGNMENT_N_ENTRY.items():
            n[row, col] = sign * self.misalignment[key]
        return n

    def _bias_at(self, temp_c: np.ndarray | float | None) -> np.ndarray:
        """Bias in output units, (3,) or (N, 3) when a temperature series is given."""
        if self.temperature is None or temp_c is None:
            return self.bias
        dt = np.asarray(temp_c, dtype=float)[..., None] - self.temperature.reference
        return self.bias + self.temperature.bias_coefficient * dt

    def _scale_at(self, temp_c: np.ndarray | float | None) -> np.ndarray:
        if self.temperature is None or temp_c is None:
            return self.scale_factor
        dt = np.asarray(temp_c, dtype=float)[..., None] - self.temperature.reference
        return self.scale_factor * (1.0 + self.temperature.scale_coefficient * dt)

    # -- the model ----------------------------------------------------------

    def forward(
        self,
        x: np.ndarray,
        temp_c: np.ndarray | float | None = None,
        accel_input: np.ndarray | None = None,
    ) -> np.ndarray:
        """Noise-free outputs U (output units) from true inputs ``x`` (N, 3) in input units.

        ``temp_c`` (degC) applies the temperature block, ``accel_input`` (N, 3,
        accelerometer input units) the gyro g-sensitivity, when present.
        """
        x = np.asarray(x, dtype=float)
        nx = x @ self.n_matrix().T
        u = self._bias_at(temp_c) + self._scale_at(temp_c) * nx
        if self.nonlinearity is not None:
            u = u + self.nonlinearity * nx**2
        if self.g_sensitivity is not None and accel_input is not None:
            u = u + np.asarray(accel_input, dtype=float) @ self.g_sensitivity.T
        return u

    def inverse(
        self,
        u: np.ndarray,
        temp_c: np.ndarray | float | None = None,
        accel_input: np.ndarray | None = None,
        n_inv_t: np.ndarray | None = None,
    ) -> np.ndarray:
        """Inputs x (N, 3) in input units from outputs ``u`` (N, 3) in output units.

        The exact inverse of :meth:`forward`. With a nonlinearity block each
        axis solves ``q y^2 + S y = r`` in closed form, taking the root that
        tends to r/S as q -> 0 (NaN beyond the quadratic's turning point).
        ``n_inv_t``: :meth:`n_inverse_t` computed once by a caller that inverts
        many blocks with the same certificate (the monitor, the still detector).
        """
        u = np.asarray(u, dtype=float)
        n_inv_t = self.n_inverse_t() if n_inv_t is None else n_inv_t
        if u.ndim == 2 and u.shape[0] >= BIG_ROWS:
            return self._corrected_in_place(u, temp_c, accel_input) @ n_inv_t
        r = u - self._bias_at(temp_c)
        if self.g_sensitivity is not None and accel_input is not None:
            r = r - np.asarray(accel_input, dtype=float) @ self.g_sensitivity.T
        scale = self._scale_at(temp_c)
        if self.nonlinearity is None:
            nx = r / scale
        else:
            with np.errstate(invalid="ignore"):
                root = np.sqrt(scale**2 + 4.0 * self.nonlinearity * r)
            nx = 2.0 * r / (scale + root)
        return nx @ n_inv_t

    def _corrected_in_place(
        self, u: np.ndarray, temp_c: np.ndarray | float | None, accel_input: np.ndarray | None
    ) -> np.ndarray:
        """N x (N, 3) of :meth:`inverse` for many rows ``u`` (N, 3): the same operations in
        the same order, bit for bit, on one new array of its own instead of a new one per
        step (on blocks of 10^5 samples their page faults cost more than the arithmetic),
        a (3,) row against the rows by :func:`~imudiag.rowwise.rows_op`."""
        r = rows_op(np.subtract, u, self._bias_at(temp_c))
        if self.g_sensitivity is not None and accel_input is not None:
            g = np.asarray(accel_input, dtype=float) @ self.g_sensitivity.T
            r = np.subtract(r, g, out=_into(r, g))
        scale = self._scale_at(temp_c)
        if self.nonlinearity is None:
            return rows_op(np.divide, r, scale, out=_into(r, scale))
        with np.errstate(invalid="ignore"):
            # 4 q r as r (4 q), scale^2 + root as root + scale^2: products and sums of two
            # numbers do not depend on their order
            root = rows_op(np.multiply, r, 4.0 * self.nonlinearity)
            root = rows_op(np.add, root, np.square(scale), out=_into(root, scale))
            np.sqrt(root, out=root)
        root = rows_op(np.add, root, scale, out=_into(root, scale))
        nx = np.multiply(2.0, r, out=r)
        return np.divide(nx, root, out=_into(nx, root))

    def n_inverse_t(self) -> np.ndarray:
        """The transpose of N^-1 (dimensionless, 3x3): ``x = (N^-1 y^T)^T = y @ n_inverse_t()``."""
        return np.linalg.inv(self.n_matrix()).T

    def forward_si(self, x_si: np.ndarray, **kw: Any) -> np.ndarray:
        """As :meth:`forward` with ``x_si`` in rad/s or m/s^2."""
        return self.forward(np.asarray(x_si, dtype=float) / self.unit_to_si, **kw)

    def inverse_si(self, u: np.ndarray, **kw: Any) -> np.ndarray:
        """As :meth:`inverse`, returning rad/s or m/s^2."""
        x = self.inverse(u, **kw)
        x *= self.unit_to_si  # (a new array of inverse's own)
        return x

    def noise_sigma(self, sample_rate_hz: float) -> np.ndarray | None:
        """Per-sample white-noise standard deviation, output units, or None if unknown.

        sigma = density * sqrt(sample_rate / 2) (noise band up to Nyquist).
        """
        if self.noise is None or self.noise.density is None:
            return None
        return self.noise.density * math.sqrt(sample_rate_hz / 2.0)

    def allan_deviation(self, tau: np.ndarray | float) -> np.ndarray | None:
        """Allan deviation (output units, shape (3, len(tau))) predicted from the noise
        fields at cluster times ``tau`` (s) (:meth:`Noise.allan_deviation`); None without
        a noise block."""
        return None if self.noise is None else self.noise.allan_deviation(tau)


@dataclass
class VibrationLimits:
    """Thresholds of the installation's vibration check (the optional ``vibration`` block).

    Defaults and their source: ArduPilot's vibration guide (ardupilot.org, "Measuring
    Vibration"): VIBE levels (the standard deviation of the high-passed accelerometer, per
    axis, m/s^2) below 30 are normally acceptable, above 30 may cause problems, above 60
    nearly always do; any accelerometer clipping (samples at the sensor's range) is a
    problem. imudiag's level is the RMS of the specific force high-passed at
    ``highpass_hz`` over ``window_s`` (docs/diagnosis.md).
    """

    accel_high: float = 30.0  #: m/s^2 RMS per axis: vibration ``high`` beyond it
    accel_severe: float = 60.0  #: m/s^2 RMS per axis: ``severe`` beyond it
    clipping: int = 0  #: clipped samples tolerated before the vibration is ``high``
    #: rad/s RMS per axis of the high-passed angular rate beyond which it is ``high``
    #: (no published default: None, the angular level is reported only)
    gyro_high: float | None = None

    def to_dict(self) -> dict[str, Any]:
        """The YAML block as plain Python types."""
        out: dict[str, Any] = {
            "accel_high": float(self.accel_high),
            "accel_severe": float(self.accel_severe),
            "clipping": int(self.clipping),
        }
        if self.gyro_high is not None:
            out["gyro_high"] = float(self.gyro_high)
        return out


def _parse_vibration(node: Any) -> VibrationLimits:
    v = _mapping(node, "vibration")
    _check_keys(v, "vibration", (), ("accel_high", "accel_severe", "clipping", "gyro_high"))
    out = VibrationLimits()
    for key in ("accel_high", "accel_severe", "gyro_high"):
        if key in v:
            setattr(out, key, _positive(_finite(v[key], f"vibration.{key}"), f"vibration.{key}"))
    if out.accel_severe < out.accel_high:
        raise CertificateError("vibration.accel_severe", "must be >= vibration.accel_high")
    if "clipping" in v:
        out.clipping = validate.integer(
            v["clipping"], lambda reason: CertificateError("vibration.clipping", reason), 0
        )
    return out


@dataclass
class Certificate:
    """A whole certificate: device text, environment magnitudes and both triads."""

    gyro: TriadModel
    accel: TriadModel
    gravity: float = STANDARD_GRAVITY_M_S2  #: m/s^2, local gravity magnitude
    earth_rate: float = 7.2921150e-5  #: rad/s
    sample_rate: float = 200.0  #: Hz, nominal
    device: dict[str, Any] = field(default_factory=dict)
    source: str | None = None  #: file it was read from, for messages
    #: the optional ``vibration`` block (thresholds of the installation's vibration check,
    #: docs/spec/certificate.md); None: the defaults of :class:`VibrationLimits`
    vibration: VibrationLimits | None = None

    def triad(self, name: str) -> TriadModel:
        """The triad called ``gyro`` or ``accel``."""
        if name not in TRIADS:
            raise KeyError(name)
        return self.gyro if name == "gyro" else self.accel

    def magnitude_si(self, name: str) -> float:
        """Known magnitude of a triad's input at rest: gravity m/s^2 or Earth rate rad/s."""
        return self.gravity if name == "accel" else self.earth_rate

    def copy(self) -> Certificate:
        """A deep copy (for perturbing in tests and calibration)."""
        return copy.deepcopy(self)

    # -- serialisation ------------------------------------------------------

    def to_dict(self) -> dict[str, Any]:
        """The YAML document as plain Python types."""
        out: dict[str, Any] = {"format": FORMAT, "device": dict(self.device)}
        out["environment"] = {"gravity": float(self.gravity), "earth_rate": float(self.earth_rate)}
        rate = float(self.sample_rate)
        out["sample_rate"] = int(rate) if rate.is_integer() else rate
        for name in TRIADS:
            out[name] = _triad_to_dict(self.triad(name))
        if self.vibration is not None:
            out["vibration"] = self.vibration.to_dict()
        return out

    def dumps(self) -> str:
        """YAML text of the certificate."""
        return yaml.dump(self.to_dict(), Dumper=_FlowListDumper, sort_keys=False)

    def save(self, path: str | Path) -> None:
        """Write the certificate to ``path`` (YAML); reading it back gives the same numbers."""
        from .atomic import write_text_atomic

        write_text_atomic(path, self.dumps())


def _triad_to_dict(t: TriadModel) -> dict[str, Any]:
    d: dict[str, Any] = {
        "input_unit": t.input_unit,
        "output_unit": t.output_unit,
        "scale_factor": [float(v) for v in t.scale_factor],
        "scale_factor_error": [float(v) for v in t.scale_factor_error],
        "bias": [float(v) for v in t.bias],
        "misalignment": {k: float(t.misalignment[k]) for k in MISALIGNMENT_KEYS},
    }
    if t.noise is not None:
        n: dict[str, Any] = {}
        for key in NOISE_FIELDS:
            vals = getattr(t.noise, key)
            if vals is not None:
                n[key] = [float(v) for v in vals]
        d["noise"] = n
    d["limits"] = {
        "f0": float(t.limits.f0),
        "bias": [float(v) for v in t.limits.bias],
        "scale_factor_error": [float(v) for v in t.limits.scale_factor_error],
        "misalignment": [float(v) for v in t.limits.misalignment],
    }
    if t.uncertainty is not None:
        d["uncertainty"] = {
            key: [float(v) if math.isfinite(v) else None for v in getattr(t.uncertainty, key)]
            for key in UNCERTAINTY_KEYS
        }
    if t.temperature is not None:
        d["temperature"] = {
            "reference": float(t.temperature.reference),
            "bias_coefficient": [float(v) for v in t.temperature.bias_coefficient],
            "scale_coefficient": [float(v) for v in t.temperature.scale_coefficient],
        }
    if t.nonlinearity is not None:
        d["nonlinearity"] = [float(v) for v in t.nonlinearity]
    if t.g_sensitivity is not None:
        d["g_sensitivity"] = [[float(v) for v in row] for row in t.g_sensitivity]
    return d


class _FlowListDumper(yaml.SafeDumper):
    """Safe dumper writing short numeric lists in flow style ``[a, b, c]``."""


def _represent_list(dumper: yaml.SafeDumper, data: list) -> yaml.Node:
    flow = all(isinstance(v, (int, float)) for v in data) or all(isinstance(v, list) for v in data)
    return dumper.represent_sequence("tag:yaml.org,2002:seq", data, flow_style=flow)


_FlowListDumper.add_representer(list, _represent_list)


# ---------------------------------------------------------------------------
# parsing


def _parse_triad(node: Any, name: str) -> TriadModel:
    node = _mapping(node, name)
    _check_keys(
        node,
        name,
        (
            "input_unit",
            "output_unit",
            "scale_factor",
            "scale_factor_error",
            "bias",
            "misalignment",
            "limits",
        ),
        ("noise", "temperature", "nonlinearity", "g_sensitivity", "uncertainty"),
    )
    unit = node["input_unit"]
    if not isinstance(unit, str) or unit not in INPUT_UNITS_TO_SI[name]:
        allowed = " or ".join(INPUT_UNITS_TO_SI[name])
        raise CertificateError(f"{name}.input_unit", f"must be {allowed}, got {unit!r}")
    out_unit = node["output_unit"]
    if not isinstance(out_unit, str) or not out_unit:
        raise CertificateError(f"{name}.output_unit", f"expected text, got {out_unit!r}")
    scale = _vector(node["scale_factor"], f"{name}.scale_factor")
    for i, s in enumerate(scale):
        _positive(s, f"{name}.scale_factor[{i}]")
    mis = _mapping(node["misalignment"], f"{name}.misalignment")
    _check_keys(mis, f"{name}.misalignment", MISALIGNMENT_KEYS)
    misalignment = {k: _finite(mis[k], f"{name}.misalignment.{k}") for k in MISALIGNMENT_KEYS}

    lim = _mapping(node["limits"], f"{name}.limits")
    _check_keys(lim, f"{name}.limits", ("f0", "bias", "scale_factor_error", "misalignment"))
    limits = Limits(
        f0=_positive(_finite(lim["f0"], f"{name}.limits.f0"), f"{name}.limits.f0"),
        bias=_vector(lim["bias"], f"{name}.limits.bias"),
        scale_factor_error=_vector(lim["scale_factor_error"], f"{name}.limits.scale_factor_error"),
        misalignment=_vector(lim["misalignment"], f"{name}.limits.misalignment"),
    )
    for key in ("bias", "scale_factor_error", "misalignment"):
        for i, v in enumerate(getattr(limits, key)):
            _positive(v, f"{name}.limits.{key}[{i}]")

    noise = None
    if "noise" in node:
        nn = _mapping(node["noise"], f"{name}.noise")
        _check_keys(nn, f"{name}.noise", (), tuple(NOISE_FIELDS))
        noise = Noise(
            **{key: _vector(nn[key], f"{name}.noise.{key}") for key in NOISE_FIELDS if key in nn}
        )
        for key in NOISE_FIELDS:
            vals = getattr(noise, key)
            if vals is not None:
                for i, v in enumerate(vals):
                    if v < 0:
                        raise CertificateError(f"{name}.noise.{key}[{i}]", f"must be >= 0, got {v}")
        has_s, has_t = "gauss_markov_sigma" in nn, "gauss_markov_time" in nn
        if has_s != has_t:
            missing = "gauss_markov_time" if has_s else "gauss_markov_sigma"
            raise CertificateError(
                f"{name}.noise.{missing}",
                "a Gauss-Markov bias needs both gauss_markov_sigma (u) and gauss_markov_time (s)",
            )
        if noise.gauss_markov_time is not None:
            for i, v in enumerate(noise.gauss_markov_time):
                _positive(v, f"{name}.noise.gauss_markov_time[{i}]")

    temperature = None
    if "temperature" in node:
        tn = _mapping(node["temperature"], f"{name}.temperature")
        _check_keys(
            tn, f"{name}.temperature", (), ("reference", "bias_coefficient", "scale_coefficient")
        )
        temperature = Temperature()
        if "reference" in tn:
            temperature.reference = _finite(tn["reference"], f"{name}.temperature.reference")
        for key in ("bias_coefficient", "scale_coefficient"):
            if key in tn:
                setattr(temperature, key, _vector(tn[key], f"{name}.temperature.{key}"))

    nonlinearity = (
        _vector(node["nonlinearity"], f"{name}.nonlinearity") if "nonlinearity" in node else None
    )
    g_sens = None
    if "g_sensitivity" in node:
        if name != "gyro":
            raise CertificateError(f"{name}.g_sensitivity", "only the gyro triad has g_sensitivity")
        rows = node["g_sensitivity"]
        if not isinstance(rows, (list, tuple)) or len(rows) != 3:
            raise CertificateError(f"{name}.g_sensitivity", "expected 3 rows of 3 numbers")
        g_sens = np.vstack([_vector(r, f"{name}.g_sensitivity[{i}]") for i, r in enumerate(rows)])

    uncertainty = None
    if "uncertainty" in node:
        un = _mapping(node["uncertainty"], f"{name}.uncertainty")
        _check_keys(un, f"{name}.uncertainty", (), UNCERTAINTY_KEYS)
        uncertainty = Uncertainty(
            *(_std_vector(un.get(key), f"{name}.uncertainty.{key}") for key in UNCERTAINTY_KEYS)
        )

    return TriadModel(
        name=name,
        input_unit=unit,
        output_unit=out_unit,
        scale_factor=scale,
        scale_factor_error=_vector(node["scale_factor_error"], f"{name}.scale_factor_error"),
        bias=_vector(node["bias"], f"{name}.bias"),
        misalignment=misalignment,
        limits=limits,
        noise=noise,
        temperature=temperature,
        nonlinearity=nonlinearity,
        g_sensitivity=g_sens,
        uncertainty=uncertainty,
    )


def _std_vector(value: Any, key: str) -> np.ndarray:
    """Three standard deviations >= 0 (null, or the key left out: not stated, NaN)."""
    if value is None:
        return np.full(3, np.nan)
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        raise CertificateError(key, f"expected a list of 3 numbers (or null), got {value!r}")
    out = np.array(
        [np.nan if v is None else _finite(v, f"{key}[{i}]") for i, v in enumerate(value)]
    )
    for i, v in enumerate(out):
        if v < 0:
            raise CertificateError(f"{key}[{i}]", f"a standard deviation must be >= 0, got {v}")
    return out


def from_dict(doc: Any, source: str | None = None) -> Certificate:
    """Build and validate a certificate from a parsed YAML document."""
    try:
        doc = _mapping(doc, "(document)")
        _check_keys(
            doc,
            "",
            ("format", "device", "environment", "sample_rate", "gyro", "accel"),
            ("vibration",),
        )
        if doc["format"] != FORMAT:
            raise CertificateError("format", f"expected {FORMAT!r}, got {doc['format']!r}")
        device = _mapping(doc["device"], "device")
        env = _mapping(doc["environment"], "environment")
        _check_keys(env, "environment", ("gravity", "earth_rate"))
        gravity = _positive(_finite(env["gravity"], "environment.gravity"), "environment.gravity")
        earth_rate = _positive(
            _finite(env["earth_rate"], "environment.earth_rate"), "environment.earth_rate"
        )
        rate = _positive(_finite(doc["sample_rate"], "sample_rate"), "sample_rate")
        if rate_problem(rate):  # a certificate's rate sizes the daemon's buffers too
            raise CertificateError("sample_rate", str(rate_problem(rate)))
        return Certificate(
            gyro=_parse_triad(doc["gyro"], "gyro"),
            accel=_parse_triad(doc["accel"], "accel"),
            gravity=gravity,
            earth_rate=earth_rate,
            sample_rate=rate,
            device={str(k): v for k, v in device.items()},
            source=source,
            vibration=_parse_vibration(doc["vibration"]) if "vibration" in doc else None,
        )
    except CertificateError as exc:
        if source and exc.source is None:
            raise CertificateError(exc.key, exc.reason, source) from None
        raise


def loads(text: str, source: str | None = None) -> Certificate:
    """Parse certificate YAML text (duplicate keys refused, see :mod:`imudiag.yamlio`)."""
    try:
        doc = yamlio.parse(text)
    except yamlio.YamlError as exc:
        where = f"line {exc.line}" if exc.line is not None else "(document)"
        raise CertificateError(where, exc.problem, source) from None
    return from_dict(doc, source=source)


def load(path: str | Path) -> Certificate:
    """Read and validate a certificate file."""
    path = Path(path)
    try:
        text = yamlio.read_text(path)
    except OSError as exc:
        raise CertificateError("(file)", f"cannot read: {exc.strerror or exc}", str(path)) from None
    except yamlio.YamlError as exc:
        raise CertificateError("(file)", exc.problem, str(path)) from None
    return loads(text, source=str(path))


DEFAULT_CERTIFICATE_NAME = "default-certificate.yaml"


def default_certificate_path() -> Path:
    """Path of the bundled certificate of the simulated board."""
    from importlib import resources  # only for the bundled one (issue 14: start-up)

    return Path(str(resources.files("imudiag.config").joinpath(DEFAULT_CERTIFICATE_NAME)))


def load_default() -> Certificate:
    """The bundled certificate of the simulated ADXRS300/ADXL202 board."""
    return load(default_certificate_path())


#: ``certificate: auto`` / ``--certificate auto``: the bundled data-sheet certificate named
#: by the source's ``device_info["datasheet"]`` (docs/devices.md)
AUTO = "auto"
DATASHEETS_DIR = "datasheets"  #: bundled data-sheet certificates: config/datasheets/<key>.yaml
#: The bundled data-sheet certificate of a flight controller's MEMS IMU in physical units: an
#: autopilot names no IMU part over MAVLink nor in its logs (ULog, DataFlash), so one generic
#: certificate of the class (config/datasheets/mavlink-fc-imu.yaml, docs/devices.md)
FLIGHT_CONTROLLER_DATASHEET = "mavlink-fc-imu"
_DATASHEET_KEY = re.compile(r"^[a-z0-9][a-z0-9._-]*$")


def datasheet_keys() -> list[str]:
    """The keys of the bundled data-sheet certificates."""
    from importlib import resources

    folder = resources.files("imudiag.config").joinpath(DATASHEETS_DIR)
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".yaml"))


def datasheet_path(key: str) -> Path:
    """Path of the bundled data-sheet certificate ``key``; CertificateError naming the
    bundled keys when there is none of that name."""
    from importlib import resources

    if not _DATASHEET_KEY.match(key) or key not in datasheet_keys():
        raise CertificateError(
            "(datasheet)",
            f"no bundled data-sheet certificate {key!r} (bundled: {', '.join(datasheet_keys())})",
        )
    folder = resources.files("imudiag.config").joinpath(DATASHEETS_DIR)
    return Path(str(folder.joinpath(f"{key}.yaml")))


def datasheet_of(cert: Certificate) -> str | None:
    """The data-sheet key of a data-sheet certificate (``device.datasheet``), else None: a
    data-sheet certificate holds a part's typical figures, not a unit's calibration."""
    key = cert.device.get("datasheet")
    return str(key) if key else None


__all__ = [
    "FLIGHT_CONTROLLER_DATASHEET",
    "FORMAT",
    "Certificate",
    "CertificateError",
    "Limits",
    "UNCERTAINTY_KEYS",
    "Uncertainty",
    "Noise",
    "Temperature",
    "TriadModel",
    "from_dict",
    "load",
    "load_default",
    "loads",
    "default_certificate_path",
    "datasheet_keys",
    "datasheet_of",
    "datasheet_path",
    "SENSOR_NAMES",
    "MISALIGNMENT_PAIRS",
    "TRIADS",
]

"""The common ground of the calibration formats: a tool's calibration as matrices in SI, and
its exact mapping onto a certificate's ``U = B + diag(S) N x`` (docs/interop.md).

Every tool module reads its file into an :class:`Interchange` and writes one: per triad the
forward matrix ``M`` (raw output per SI input unit: per rad/s, per m/s^2; physical -> raw,
the certificate's direction), the bias (output units), the gyro g-sensitivity (gyro output
per m/s^2) and the white-noise terms (output units), each None when the format does not
carry it. :func:`to_certificate` turns one into a certificate, taking what the file lacks
from a ``like`` certificate and saying which field came from where; :func:`from_certificate`
is its inverse.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .. import validate, yamlio
from ..certificate import INPUT_UNITS_TO_SI, NOISE_FIELDS, TRIADS, Certificate, Noise, TriadModel
from ..diagnosis.calibrate import fields_from_n
from ..diagnosis.gauge import polar
from ..errors import BadInput

#: Import gauges: ``symmetric`` re-frames both triads so the accelerometer N is symmetric
#: (the gauge ``imudiag calibrate`` writes); ``tool`` keeps the tool's frame as it is.
GAUGES = ("symmetric", "tool")
DEFAULT_GAUGE = "symmetric"

#: A like scale factor S is kept when every diagonal entry of the file's M is within this
#: factor of it (same units, E takes the difference); otherwise S is the file's row norm.
SCALE_AGREEMENT_FACTOR = 2.0

#: A frame rotation (rad) smaller than this is float noise, not worth a note.
ANGLE_NOTE_RAD = 1e-12


@dataclass
class TriadCal:
    """One triad as a tool file holds it, None where the format does not carry a field.

    ``matrix``: M (3x3), output units per SI input unit (rad/s or m/s^2), U = bias + M x.
    ``bias``: output units. ``g_sensitivity``: gyro output per m/s^2 (3x3).
    ``noise_density``: one-sided white-noise density, output units/sqrt(Hz) (the
    certificate's ``noise.density``). ``bias_random_walk``: output units/sqrt(s).
    ``noise_input_referred``: the two noise figures are in SI input units instead (a file
    with noise and no matrix); the certificate's scale factor takes them to output units.
    ``implied_output_unit``: the output unit a tool that does not write one assumes (Kalibr
    and iKalibr read SI), used when the matrix does not match the like's scale factors.
    """

    matrix: np.ndarray | None = None
    bias: np.ndarray | None = None
    g_sensitivity: np.ndarray | None = None
    output_unit: str | None = None
    noise_density: np.ndarray | None = None
    bias_random_walk: np.ndarray | None = None
    noise_input_referred: bool = False
    implied_output_unit: str | None = None


@dataclass
class Interchange:
    """A whole tool calibration: both triads, the sample rate (Hz) if the file gives it,
    and notes on what the conversion lost or assumed (printed by the command)."""

    gyro: TriadCal = field(default_factory=TriadCal)
    accel: TriadCal = field(default_factory=TriadCal)
    sample_rate_hz: float | None = None
    notes: list[str] = field(default_factory=list)

    def triad(self, name: str) -> TriadCal:
        """The triad called ``gyro`` or ``accel``."""
        return self.gyro if name == "gyro" else self.accel


# ---------------------------------------------------------------------------
# reading helpers shared by the tool modules


def as_matrix(value: Any, source: str, key: str, shape: tuple[int, ...] = (3, 3)) -> np.ndarray:
    """``value`` as a finite float array of ``shape``, or BadInput naming file and key."""
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise BadInput(f"{source}: {key}: expected numbers, got {value!r}") from None
    if arr.shape != shape:
        want = "x".join(str(n) for n in shape)
        got = "x".join(str(n) for n in arr.shape) or "a scalar"
        raise BadInput(f"{source}: {key}: expected a {want} matrix, got {got}")
    if not np.all(np.isfinite(arr)):
        raise BadInput(f"{source}: {key}: not all finite numbers")
    return arr


def as_number(value: Any, source: str, key: str, positive: bool = False) -> float:
    """``value`` as a finite float (> 0 with ``positive``), or BadInput naming file and key."""
    lo = 0.0 if positive else -math.inf
    return validate.number(value, f"{source}: {key}", lo, lo_open=positive)


def require_key(node: Any, key: str, source: str, path: str = "") -> Any:
    """``node[key]``, or BadInput naming the file and the key path when it is missing."""
    where = f"{path}.{key}" if path else key
    if not isinstance(node, dict):
        raise BadInput(f"{source}: {path or '(document)'}: expected a mapping")
    if key not in node:
        raise BadInput(f"{source}: {where}: missing required key")
    return node[key]


def load_yaml(path: str) -> Any:
    """A YAML file parsed (duplicate keys refused), or BadInput naming the file and line."""
    try:
        return yamlio.parse(yamlio.read_text(path))
    except OSError as exc:
        raise BadInput(f"{path}: cannot read: {exc.strerror or exc}") from None
    except yamlio.YamlError as exc:
        where = f"line {exc.line}" if exc.line is not None else "(document)"
        raise BadInput(f"{path}: {where}: {exc.problem}") from None


def invertible(m: np.ndarray, source: str, key: str) -> np.ndarray:
    """``m`` unchanged, or BadInput when it is singular (condition number above 1e12)."""
    if not np.isfinite(np.linalg.cond(m)) or np.linalg.cond(m) > 1e12:
        raise BadInput(f"{source}: {key}: singular matrix, the calibration cannot be inverted")
    return m


# ---------------------------------------------------------------------------
# triangular factorisations (the tools whose matrices are triangular)


def triangular_times_rotation(m: np.ndarray, lower: bool) -> tuple[np.ndarray, np.ndarray]:
    """``m = T Q``: T triangular (lower or upper) with a positive diagonal, Q orthogonal.

    Q is a proper rotation when det(m) > 0.
    """
    if lower:
        q, r = np.linalg.qr(m.T)  # m^T = q r  ->  m = r^T q^T
        t, rot = r.T, q.T
    else:
        p = np.eye(3)[::-1]
        q, r = np.linalg.qr((p @ m).T)  # (P m)^T = q r  ->  m = P r^T q^T = (P r^T P)(P q^T)
        t, rot = p @ r.T @ p, p @ q.T
    sign = np.diag(np.where(np.diag(t) < 0, -1.0, 1.0))
    return t @ sign, sign @ rot


def rotation_angle_rad(q: np.ndarray) -> float:
    """Angle (rad) of the rotation matrix ``q``."""
    return float(np.arccos(np.clip((np.trace(q) - 1.0) / 2.0, -1.0, 1.0)))


def reframe(ic: Interchange, rot: np.ndarray) -> None:
    """Express both triads in the frame ``x' = rot x`` (the matrices become ``M rot^T``)."""
    for name in TRIADS:
        tri = ic.triad(name)
        if tri.matrix is not None:
            tri.matrix = tri.matrix @ rot.T
    if ic.gyro.g_sensitivity is not None:
        ic.gyro.g_sensitivity = ic.gyro.g_sensitivity @ rot.T


# ---------------------------------------------------------------------------
# Interchange -> certificate


@dataclass
class Provenance:
    """Where each certificate field came from: ``file``, ``like`` or a note, by key path."""

    fields: dict[str, str] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    def lines(self, file_name: str, like_name: str) -> list[str]:
        """Human-readable lines: the keys from the file, from the like certificate, notes."""
        by: dict[str, list[str]] = {}
        for key, src in self.fields.items():
            by.setdefault(src, []).append(key)
        out = []
        for src, keys in by.items():
            label = {"file": f"from {file_name}", "like": f"from {like_name}"}.get(src, src)
            out.append(f"{label}: {', '.join(keys)}")
        return out + [f"note: {n}" for n in self.notes]


def _rescale_like(t: TriadModel, k: np.ndarray) -> None:
    """Scale the like triad's output-unit fields by ``k`` per axis (its S -> k S)."""
    t.limits.bias = t.limits.bias * k
    t.limits.scale_factor_error = t.limits.scale_factor_error * k
    if t.noise is not None:
        for key in NOISE_FIELDS:
            vals = getattr(t.noise, key)
            if vals is not None and key != "gauss_markov_time":  # the one field in seconds
                setattr(t.noise, key, vals * k)
    if t.temperature is not None:
        t.temperature.bias_coefficient = t.temperature.bias_coefficient * k
    if t.nonlinearity is not None:
        t.nonlinearity = t.nonlinearity * k
    if t.g_sensitivity is not None:
        t.g_sensitivity = t.g_sensitivity * k[:, None]


def choose_scale(m: np.ndarray, like: TriadModel) -> tuple[np.ndarray, bool]:
    """Scale factors S (output per input unit) for the forward matrix ``m`` (output per
    certificate input unit): the like's when every diagonal entry of ``m`` is within
    :data:`SCALE_AGREEMENT_FACTOR` of it (True), else the norm of each row (False)."""
    ratio = np.diag(m) / like.scale_factor
    limit = SCALE_AGREEMENT_FACTOR
    if np.all((ratio >= 1.0 / limit) & (ratio <= limit)):
        return like.scale_factor.copy(), True
    return np.linalg.norm(m, axis=1), False


def _triad_from_cal(
    name: str,
    cal: TriadCal,
    like: TriadModel,
    prov: Provenance,
    accel_unit_si: float,
    scale: np.ndarray | None = None,
) -> TriadModel:
    out = copy.deepcopy(like)
    f = like.unit_to_si  # SI per certificate input unit
    if cal.output_unit is not None:
        out.output_unit = cal.output_unit
        prov.fields[f"{name}.output_unit"] = "file"
    elif cal.matrix is not None and cal.implied_output_unit is not None:
        if not choose_scale(cal.matrix * f, like)[1]:
            out.output_unit = cal.implied_output_unit
            prov.fields[f"{name}.output_unit"] = (
                f"implied by the format ({cal.implied_output_unit})"
            )
        else:
            prov.fields[f"{name}.output_unit"] = "like"
    else:
        prov.fields[f"{name}.output_unit"] = "like"
    prov.fields[f"{name}.input_unit"] = "like"
    if cal.matrix is not None:
        m = cal.matrix * f  # output per certificate input unit
        scale, from_like = choose_scale(m, like) if scale is None else (scale, False)
        if from_like or np.array_equal(scale, like.scale_factor):
            prov.fields[f"{name}.scale_factor"] = "like"
        else:
            k = scale / like.scale_factor
            _rescale_like(out, k)
            prov.fields[f"{name}.scale_factor"] = "file"
            prov.notes.append(
                f"{name}: the like scale factors {like.scale_factor.tolist()} are not the file's "
                f"(diagonal {np.diag(m).tolist()} {out.output_unit} per {like.input_unit}): "
                "S is the norm of each row of the file's matrix, and the like limits, noise "
                "and other output-unit fields are rescaled by S / S_like "
                f"({k.tolist()}) so they keep their size in {like.input_unit}"
            )
        out.scale_factor = scale
        out.scale_factor_error, out.misalignment = fields_from_n(m / scale[:, None], scale)
        prov.fields[f"{name}.scale_factor_error"] = "file"
        prov.fields[f"{name}.misalignment"] = "file"
    else:
        for key in ("scale_factor", "scale_factor_error", "misalignment"):
            prov.fields[f"{name}.{key}"] = "like"
    if cal.bias is not None:
        out.bias = np.asarray(cal.bias, dtype=float).copy()
        prov.fields[f"{name}.bias"] = "file"
    elif out.output_unit != like.output_unit:
        out.bias = np.zeros(3)
        prov.fields[f"{name}.bias"] = "set to 0"
        prov.notes.append(
            f"{name}.bias: not in the file, and the like bias is in {like.output_unit!r}, "
            f"not {out.output_unit!r}: set to 0"
        )
    else:
        prov.fields[f"{name}.bias"] = "like"
    if name == "gyro":
        if cal.g_sensitivity is not None and not (
            like.g_sensitivity is None and not np.any(cal.g_sensitivity)
        ):
            out.g_sensitivity = cal.g_sensitivity * accel_unit_si
            prov.fields["gyro.g_sensitivity"] = "file"
        elif out.g_sensitivity is not None:
            prov.fields["gyro.g_sensitivity"] = "like"
    to_output = out.scale_factor / f if cal.noise_input_referred else np.ones(3)
    for key, vals in (("density", cal.noise_density), ("bias_random_walk", cal.bias_random_walk)):
        if vals is not None:
            out.noise = out.noise or Noise()
            setattr(out.noise, key, np.asarray(vals, dtype=float) * to_output)
            prov.fields[f"{name}.noise.{key}"] = "file"
    if out.noise is not None:
        for key in NOISE_FIELDS:
            if getattr(out.noise, key) is not None and f"{name}.noise.{key}" not in prov.fields:
                prov.fields[f"{name}.noise.{key}"] = "like"
    prov.fields[f"{name}.limits"] = "like"
    for key in ("temperature", "nonlinearity"):
        if getattr(out, key) is not None:
            prov.fields[f"{name}.{key}"] = "like"
    return out


def to_certificate(
    ic: Interchange, like: Certificate, gauge: str = DEFAULT_GAUGE
) -> tuple[Certificate, Provenance]:
    """The certificate of a tool calibration; what the file lacks comes from ``like``.

    ``gauge``: ``symmetric`` re-frames both triads by the rotation that makes the
    accelerometer N symmetric (reported in the provenance notes: the scalar method cannot
    see it); ``tool`` keeps the tool's frame exactly.
    """
    if gauge not in GAUGES:
        raise BadInput(f"--gauge: must be one of {', '.join(GAUGES)}, got {gauge!r}")
    ic = copy.deepcopy(ic)
    prov = Provenance(notes=list(ic.notes))
    accel_scale = None
    if ic.accel.matrix is not None:
        accel_scale, _ = choose_scale(ic.accel.matrix * like.accel.unit_to_si, like.accel)
    if gauge == "symmetric" and ic.accel.matrix is not None and accel_scale is not None:
        n_a = ic.accel.matrix * like.accel.unit_to_si / accel_scale[:, None]
        if np.linalg.det(n_a) <= 0:
            raise BadInput(
                "accelerometer matrix with a negative determinant (a left-handed triad): "
                "the symmetric gauge would mirror the frame; use --gauge tool"
            )
        _, q = polar(n_a)
        angle = rotation_angle_rad(q)
        reframe(ic, q)
        if angle > ANGLE_NOTE_RAD:
            axis = np.array([q[2, 1] - q[1, 2], q[0, 2] - q[2, 0], q[1, 0] - q[0, 1]])
            axis = axis / np.linalg.norm(axis)
            prov.notes.append(
                f"gauge symmetric: the tool's frame is turned by {angle:.4e} rad about "
                f"{np.round(axis, 6).tolist()} to the frame in which the accelerometer N is "
                "symmetric, as imudiag calibrate writes it; the scalar method cannot see this "
                "rotation (--gauge tool keeps the tool's frame)"
            )
    out = like.copy()
    out.source = None
    accel_unit_si = like.accel.unit_to_si
    out.accel = _triad_from_cal("accel", ic.accel, like.accel, prov, accel_unit_si, accel_scale)
    out.gyro = _triad_from_cal("gyro", ic.gyro, like.gyro, prov, accel_unit_si)
    if ic.sample_rate_hz is not None:
        out.sample_rate = float(ic.sample_rate_hz)
        prov.fields["sample_rate"] = "file"
    else:
        prov.fields["sample_rate"] = "like"
    prov.fields["device"] = "like"
    prov.fields["environment"] = "like"
    return out, prov


# ---------------------------------------------------------------------------
# certificate -> Interchange


def from_certificate(cert: Certificate) -> Interchange:
    """The certificate as matrices in SI (every field a format may carry)."""
    ic = Interchange(sample_rate_hz=float(cert.sample_rate))
    for name in TRIADS:
        t = cert.triad(name)
        tri = ic.triad(name)
        f = INPUT_UNITS_TO_SI[name][t.input_unit]
        tri.matrix = (t.scale_factor[:, None] * t.n_matrix()) / f
        tri.bias = t.bias.copy()
        tri.output_unit = t.output_unit
        if t.noise is not None:
            tri.noise_density = None if t.noise.density is None else t.noise.density.copy()
            brw = t.noise.bias_random_walk
            tri.bias_random_walk = None if brw is None else brw.copy()
        if t.temperature is not None or t.nonlinearity is not None:
            ic.notes.append(f"{name}: the temperature and nonlinearity blocks are not exported")
    if cert.gyro.g_sensitivity is not None:
        ic.gyro.g_sensitivity = cert.gyro.g_sensitivity / cert.accel.unit_to_si
    return ic


__all__ = [
    "DEFAULT_GAUGE",
    "GAUGES",
    "Interchange",
    "Provenance",
    "TriadCal",
    "as_matrix",
    "as_number",
    "choose_scale",
    "from_certificate",
    "invertible",
    "load_yaml",
    "reframe",
    "require_key",
    "rotation_angle_rad",
    "to_certificate",
    "triangular_times_rotation",
]

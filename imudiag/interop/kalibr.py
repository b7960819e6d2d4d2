"""Kalibr (github.com/ethz-asl/kalibr) IMU YAML: ``imu.yaml`` noise and the
scale-misalignment results.

Kalibr's ``imu.yaml`` holds ``accelerometer_noise_density`` (m/s^2/sqrt(Hz)),
``accelerometer_random_walk`` (m/s^3/sqrt(Hz)), ``gyroscope_noise_density``
(rad/s/sqrt(Hz)), ``gyroscope_random_walk`` (rad/s^2/sqrt(Hz)), ``update_rate`` (Hz) and
``rostopic``. ``kalibr_calibrate_imu_camera --imu-models scale-misalignment`` writes the
same keys under ``imu0:`` in ``<bag>-imu.yaml`` together with ``model``,
``accelerometers: {M}`` and ``gyroscopes: {M, A, C_gyro_i}`` of its model (IMU frame i,
SI in and out):

    a_meas = M_a a + b_a
    w_meas = M_g C_gyro_i w + A C_gyro_i a + b_g

so the certificate's M_accel = M_a, M_gyro = M_g C_gyro_i and g-sensitivity A C_gyro_i;
Kalibr's biases are random walks it does not write, so they come from ``--like``.

Noise: Kalibr's noise density sigma_c is the continuous-time white-noise density with the
discrete sigma = sigma_c sqrt(rate); the certificate's one-sided density n has the
per-sample sigma = n sqrt(rate / 2), so n = sqrt(2) sigma_c. Kalibr's random walk sigma_b
(bias variance sigma_b^2 t) is the certificate's ``bias_random_walk`` K as it is. Both are
multiplied by each axis' gain (the row norm of M, output per SI input unit; for a file with
noise and no matrix, the like's S per SI unit) into output units; one figure per triad.

Writing, M_a is made lower triangular and M_g = L_g C_gyro_i (Kalibr's own design
variables: lower-triangular M, a rotation C_gyro_i) by re-framing both triads; the rotation
that takes is reported, as the scalar method cannot see it.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import yaml

from ..atomic import write_text_atomic
from ..errors import BadInput
from .model import (
    Interchange,
    as_matrix,
    as_number,
    invertible,
    load_yaml,
    reframe,
    require_key,
    rotation_angle_rad,
    triangular_times_rotation,
)

NOISE_KEYS = {
    "accel": ("accelerometer_noise_density", "accelerometer_random_walk"),
    "gyro": ("gyroscope_noise_density", "gyroscope_random_walk"),
}
MODELS = ("calibrated", "scale-misalignment", "scale-misalignment-size-effect")
#: the certificate's one-sided density over Kalibr's continuous-time noise density
DENSITY_FACTOR = math.sqrt(2.0)
DEFAULT_ROSTOPIC = "/imu0"


def read(path: str, imu: str = "imu0") -> Interchange:
    """A Kalibr ``imu.yaml`` or ``<bag>-imu.yaml`` (the ``imu`` block, e.g. imu0)."""
    doc = load_yaml(path)
    if not isinstance(doc, dict):
        raise BadInput(f"{path}: (document): expected a mapping")
    prefix = ""
    if "accelerometer_noise_density" not in doc:
        node = require_key(doc, imu, path)
        if not isinstance(node, dict):
            raise BadInput(f"{path}: {imu}: expected a mapping")
        doc, prefix = node, f"{imu}."
    ic = Interchange()
    rate = as_number(
        require_key(doc, "update_rate", path, prefix[:-1]), path, f"{prefix}update_rate", True
    )
    ic.sample_rate_hz = rate
    # the SI noise, scaled into output units once the matrices are known (see module doc)
    noise = {}
    for name, (dkey, rkey) in NOISE_KEYS.items():
        d = as_number(require_key(doc, dkey, path, prefix[:-1]), path, prefix + dkey, True)
        r = as_number(require_key(doc, rkey, path, prefix[:-1]), path, prefix + rkey, True)
        noise[name] = (d, r)
    model = doc.get("model", "calibrated")
    if model not in MODELS:
        raise BadInput(f"{path}: {prefix}model: expected one of {', '.join(MODELS)}, got {model!r}")
    if model != "calibrated":
        acc = require_key(doc, "accelerometers", path, prefix[:-1])
        gyr = require_key(doc, "gyroscopes", path, prefix[:-1])
        a_key, g_key = f"{prefix}accelerometers", f"{prefix}gyroscopes"
        m_a = as_matrix(require_key(acc, "M", path, a_key), path, f"{a_key}.M")
        m_g = as_matrix(require_key(gyr, "M", path, g_key), path, f"{g_key}.M")
        a_g = as_matrix(require_key(gyr, "A", path, g_key), path, f"{g_key}.A")
        c = as_matrix(require_key(gyr, "C_gyro_i", path, g_key), path, f"{g_key}.C_gyro_i")
        invertible(m_a, path, f"{a_key}.M")
        invertible(m_g, path, f"{g_key}.M")
        if not np.allclose(c @ c.T, np.eye(3), atol=1e-6) or np.linalg.det(c) <= 0:
            raise BadInput(f"{path}: {g_key}.C_gyro_i: not a rotation matrix")
        ic.accel.matrix, ic.gyro.matrix, ic.gyro.g_sensitivity = m_a, m_g @ c, a_g @ c
        for name, unit in (("accel", "m/s^2"), ("gyro", "rad/s")):
            ic.triad(name).implied_output_unit = unit
        if model == "scale-misalignment-size-effect":
            ic.notes.append("kalibr: the accelerometer lever arms (size effect) are not imported")
    for name, (d, r) in noise.items():
        tri = ic.triad(name)
        if tri.matrix is None:  # noise only: input-referred, the like's S scales it
            scale, tri.noise_input_referred = np.ones(3), True
        else:
            scale = np.linalg.norm(tri.matrix, axis=1)
        tri.noise_density = DENSITY_FACTOR * d * scale
        tri.bias_random_walk = r * scale
    return ic


def _scalar(vals: np.ndarray | None, scale: np.ndarray, name: str, key: str) -> float:
    """One SI figure per triad from per-axis output-unit figures (their quadratic mean)."""
    if vals is None:
        raise BadInput(
            f"{name}.noise.{key}: missing, and Kalibr's imu.yaml needs it "
            "(add it to the certificate, output units; see docs/interop.md)"
        )
    si = np.asarray(vals, dtype=float) / scale
    return float(np.sqrt(np.mean(si**2)))


def document(ic: Interchange, rostopic: str = DEFAULT_ROSTOPIC) -> dict[str, Any]:
    """The Kalibr YAML mapping: imu.yaml keys and the scale-misalignment model keys."""
    for name in ("accel", "gyro"):
        if ic.triad(name).matrix is None:
            raise BadInput(f"{name}: the certificate has no matrix to export")
    assert ic.accel.matrix is not None and ic.gyro.matrix is not None
    det = np.linalg.det(ic.accel.matrix)
    if det <= 0 or np.linalg.det(ic.gyro.matrix) <= 0:
        raise BadInput("a left-handed triad (negative determinant): Kalibr's model has none")
    m_a, q = triangular_times_rotation(ic.accel.matrix, lower=True)
    if rotation_angle_rad(q) > 0:
        ic.notes.append(
            f"kalibr: both triads re-framed by {rotation_angle_rad(q):.3e} rad so that "
            "accelerometers.M is lower triangular, as Kalibr estimates it; the rotation is not "
            "in the file (the scalar method cannot see it)"
        )
    reframe(ic, q)
    m_g, c = triangular_times_rotation(ic.gyro.matrix, lower=True)
    g_sens = ic.gyro.g_sensitivity
    a_g = np.zeros((3, 3)) if g_sens is None else g_sens @ c.T
    out: dict[str, Any] = {}
    for name, (dkey, rkey) in NOISE_KEYS.items():
        tri = ic.triad(name)
        assert tri.matrix is not None  # checked above
        scale = np.linalg.norm(tri.matrix, axis=1)
        out[dkey] = _scalar(tri.noise_density, scale, name, "density") / DENSITY_FACTOR
        out[rkey] = _scalar(tri.bias_random_walk, scale, name, "bias_random_walk")
        for key, vals in (
            ("density", tri.noise_density),
            ("bias_random_walk", tri.bias_random_walk),
        ):
            si = None if vals is None else np.asarray(vals) / scale
            if si is not None and np.ptp(si) > 1e-12 * np.max(np.abs(si)):
                ic.notes.append(f"kalibr: {name}.noise.{key} differs by axis: written as their RMS")
    out["rostopic"] = rostopic
    out["update_rate"] = float(ic.sample_rate_hz) if ic.sample_rate_hz else 200.0
    out["model"] = "scale-misalignment"
    out["accelerometers"] = {"M": m_a.tolist()}
    out["gyroscopes"] = {"A": a_g.tolist(), "C_gyro_i": c.tolist(), "M": m_g.tolist()}
    for name in ("accel", "gyro"):
        tri = ic.triad(name)
        unit = "m/s^2" if name == "accel" else "rad/s"
        if tri.output_unit != unit:
            ic.notes.append(
                f"kalibr: {name} outputs are in {tri.output_unit!r}, Kalibr reads {unit}: "
                f"M is {tri.output_unit} per {unit}"
            )
    ic.notes.append("kalibr: the biases are not part of Kalibr's files: not exported")
    return out


def write(ic: Interchange, path: str) -> list[str]:
    """Write the Kalibr YAML as Kalibr's ``writeYaml`` does (``yaml.dump``, flow lists)."""
    doc = document(ic)
    write_text_atomic(path, yaml.dump(doc, default_flow_style=None, width=2147483647))
    return [path]


__all__ = ["DENSITY_FACTOR", "NOISE_KEYS", "document", "read", "write"]

"""iKalibr (github.com/Unsigned-Long/iKalibr) IMU intrinsics YAML (``IMUIntrinsics::Save``).

cereal writes ``Intrinsics: ptr_wrapper: {id, data: {ACCE, GYRO, SO3_AtoG}}``; ACCE and
GYRO each hold ``BIAS`` (r0c0..r2c0) and ``MAP_COEFF`` (r0c0..r5c0, v1..v6), the map
matrix ``[[v1, v4, v5], [0, v2, v6], [0, 0, v3]]``; SO3_AtoG is a unit quaternion
(qx, qy, qz, qw), the rotation from the accelerometer frame A to the gyro frame G. The
model (``InvolveForceIntri``, ``InvolveGyroIntri``; SI in and out):

    f_meas = Map_a f + b_a
    w_meas = Map_g R_AtoG w + b_g

so the certificate's M_accel = Map_a and M_gyro = Map_g R_AtoG, in the accelerometer frame.
Writing, the accelerometer matrix must be upper triangular: both triads are re-framed by
the rotation that makes it so (reported; the scalar method cannot see it), and
M_gyro = Map_g R_AtoG is factored the same way. Noise and g-sensitivity are not part of the
file.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import yaml

from ..atomic import write_text_atomic
from ..errors import BadInput
from ..rotations import matrix_quat, quat_matrix
from .model import (
    Interchange,
    as_number,
    invertible,
    load_yaml,
    reframe,
    require_key,
    rotation_angle_rad,
    triangular_times_rotation,
)

ROOT = ("Intrinsics", "ptr_wrapper", "data")
#: cereal's polymorphic pointer id in iKalibr's files (its comment: "don't care")
PTR_ID = 2147483649
TRIAD_KEYS = {"accel": "ACCE", "gyro": "GYRO"}


def _vector(node: Any, path: str, key: str, n: int) -> np.ndarray:
    return np.array(
        [
            as_number(require_key(node, f"r{i}c0", path, key), path, f"{key}.r{i}c0")
            for i in range(n)
        ]
    )


def map_matrix(v: np.ndarray) -> np.ndarray:
    """iKalibr's map matrix of MAP_COEFF v1..v6 (``BiasMapCoeff::MapMatrix``)."""
    return np.array([[v[0], v[3], v[4]], [0.0, v[1], v[5]], [0.0, 0.0, v[2]]])


def read(path: str) -> Interchange:
    """An iKalibr IMU intrinsics YAML file."""
    node: Any = load_yaml(path)
    key = ""
    for part in ROOT:
        node = require_key(node, part, path, key)
        key = f"{key}.{part}" if key else part
    ic = Interchange()
    maps = {}
    for name, tk in TRIAD_KEYS.items():
        tri_node = require_key(node, tk, path, key)
        base = f"{key}.{tk}"
        ic.triad(name).bias = _vector(
            require_key(tri_node, "BIAS", path, base), path, f"{base}.BIAS", 3
        )
        coeff = _vector(
            require_key(tri_node, "MAP_COEFF", path, base), path, f"{base}.MAP_COEFF", 6
        )
        maps[name] = invertible(map_matrix(coeff), path, f"{base}.MAP_COEFF")
        ic.triad(name).implied_output_unit = "m/s^2" if name == "accel" else "rad/s"
    qn = require_key(node, "SO3_AtoG", path, key)
    q = np.array(
        [
            as_number(require_key(qn, c, path, f"{key}.SO3_AtoG"), path, f"{key}.SO3_AtoG.{c}")
            for c in ("qw", "qx", "qy", "qz")
        ]
    )
    norm = float(np.linalg.norm(q))
    if abs(norm - 1.0) > 1e-6:
        raise BadInput(f"{path}: {key}.SO3_AtoG: not a unit quaternion (norm {norm:.9g})")
    ic.accel.matrix = maps["accel"]
    ic.gyro.matrix = maps["gyro"] @ quat_matrix(q)
    return ic


def _coeff(m: np.ndarray) -> dict[str, float]:
    v = [m[0, 0], m[1, 1], m[2, 2], m[0, 1], m[0, 2], m[1, 2]]
    return {f"r{i}c0": float(x) for i, x in enumerate(v)}


def _bias(b: np.ndarray | None, name: str) -> dict[str, float]:
    if b is None:
        raise BadInput(f"{name}: the certificate has no bias to export")
    return {f"r{i}c0": float(x) for i, x in enumerate(b)}


def document(ic: Interchange) -> dict[str, Any]:
    """The iKalibr intrinsics mapping (cereal's layout)."""
    for name in ("accel", "gyro"):
        m = ic.triad(name).matrix
        if m is None:
            raise BadInput(f"{name}: the certificate has no matrix to export")
        if np.linalg.det(m) <= 0:
            raise BadInput(f"{name}: a left-handed triad (negative determinant): iKalibr has none")
    assert ic.accel.matrix is not None
    map_a, q = triangular_times_rotation(ic.accel.matrix, lower=False)
    if rotation_angle_rad(q) > 0:
        ic.notes.append(
            f"ikalibr: both triads re-framed by {rotation_angle_rad(q):.3e} rad so that the "
            "accelerometer map matrix is upper triangular, as iKalibr's is; the rotation is not "
            "in the file (the scalar method cannot see it)"
        )
    reframe(ic, q)
    assert ic.gyro.matrix is not None
    map_g, r = triangular_times_rotation(ic.gyro.matrix, lower=False)
    quat = matrix_quat(r)
    if ic.gyro.g_sensitivity is not None and np.any(ic.gyro.g_sensitivity):
        ic.notes.append("ikalibr: no g-sensitivity in its model: gyro.g_sensitivity not exported")
    ic.notes.append("ikalibr: noise and sample rate are not part of its file: not exported")
    data = {
        "ACCE": {"BIAS": _bias(ic.accel.bias, "accel"), "MAP_COEFF": _coeff(map_a)},
        "GYRO": {"BIAS": _bias(ic.gyro.bias, "gyro"), "MAP_COEFF": _coeff(map_g)},
        "SO3_AtoG": {
            "qx": float(quat[1]),
            "qy": float(quat[2]),
            "qz": float(quat[3]),
            "qw": float(quat[0]),
        },
    }
    return {"Intrinsics": {"ptr_wrapper": {"id": PTR_ID, "data": data}}}


def write(ic: Interchange, path: str) -> list[str]:
    """Write the intrinsics YAML in cereal's block layout; returns [path]."""
    text = yaml.safe_dump(document(ic), sort_keys=False, default_flow_style=False)
    write_text_atomic(path, text)
    return [path]


__all__ = ["document", "map_matrix", "read", "write"]

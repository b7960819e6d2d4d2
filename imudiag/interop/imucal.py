"""imucal (github.com/mad-lab-fau/imucal) ``FerrarisCalibrationInfo``, JSON or HDF5.

imucal's model (raw -> calibrated, ``acc_unit`` and ``gyr_unit`` on the calibrated side,
``from_acc_unit`` and ``from_gyr_unit`` on the raw side):

    a = R_a^-1 K_a^-1 (a_raw - b_a)
    g = R_g^-1 K_g^-1 (g_raw - K_ga a - b_g)

so the certificate's forward model is ``a_raw = b_a + K_a R_a a`` and
``g_raw = b_g + K_g R_g g + K_ga a``: M_a = K_a R_a, M_g = K_g R_g (per imucal's unit),
the gyro g-sensitivity K_ga (gyro raw output per ``acc_unit``). Writing, K is the norm of
each row of M and R the rows of unit length, as imucal's Ferraris calibration makes them.
JSON is written as ``CalibrationInfo.to_json_file`` writes it; HDF5 (``.h5``, ``.hdf5``,
``.hdf``) as ``to_hdf5`` does, with h5py (``pip install 'imudiag[mat]'``).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from ..atomic import atomic_path, write_text_atomic
from ..certificate import INPUT_UNITS_TO_SI
from ..errors import BadInput
from .model import Interchange, as_matrix, invertible, require_key

CAL_TYPES = ("Ferraris", "Turntable")
FORMAT_VERSION = "2.0"
HDF5_SUFFIXES = (".h5", ".hdf5", ".hdf")
PARAMETERS = ("K_a", "R_a", "b_a", "K_g", "R_g", "K_ga", "b_g")
#: imucal's unit spellings on the calibrated side, to the certificate's.
UNITS = {
    "accel": {"m/s^2": "m/s^2", "m/s2": "m/s^2", "g": "g"},
    "gyro": {"deg/s": "deg/s", "dps": "deg/s", "rad/s": "rad/s"},
}
UNIT_KEY = {"accel": "acc_unit", "gyro": "gyr_unit"}
FROM_UNIT_KEY = {"accel": "from_acc_unit", "gyro": "from_gyr_unit"}


def _h5py() -> Any:
    from ..logs.extras import require

    return require("h5py", "mat", "imucal HDF5 calibrations")


def _load(path: str) -> dict[str, Any]:
    if Path(path).suffix.lower() in HDF5_SUFFIXES:
        h5py = _h5py()
        try:
            with h5py.File(path, "r") as hdf:
                doc: dict[str, Any] = {}
                for key in hdf:
                    data = hdf[key]
                    if h5py.check_string_dtype(data.dtype):
                        doc[key] = data.asstr()[()]
                    else:
                        doc[key] = np.asarray(data[()]).tolist()
                return doc
        except OSError as exc:
            raise BadInput(f"{path}: cannot read as HDF5: {exc}") from None
    try:
        with open(path, encoding="utf-8") as fh:
            doc = json.load(fh)
    except OSError as exc:
        raise BadInput(f"{path}: cannot read: {exc.strerror or exc}") from None
    except json.JSONDecodeError as exc:
        raise BadInput(f"{path}: line {exc.lineno}: not JSON: {exc.msg}") from None
    if not isinstance(doc, dict):
        raise BadInput(f"{path}: (document): expected a JSON object")
    return doc


def read(path: str) -> Interchange:
    """An imucal Ferraris (or Turntable) calibration file."""
    doc = _load(path)
    cal_type = require_key(doc, "cal_type", path)
    if cal_type not in CAL_TYPES:
        raise BadInput(
            f"{path}: cal_type: expected one of {', '.join(CAL_TYPES)}, got {cal_type!r}"
        )
    p = {}
    for key in PARAMETERS:
        shape = (3,) if key.startswith("b_") else (3, 3)
        p[key] = as_matrix(require_key(doc, key, path), path, key, shape)
    for key in ("K_a", "K_g"):
        invertible(p[key], path, key)
    for key in ("R_a", "R_g"):
        invertible(p[key], path, key)
    ic = Interchange()
    factors = {}
    for name in ("accel", "gyro"):
        unit = require_key(doc, UNIT_KEY[name], path)
        if unit not in UNITS[name]:
            allowed = ", ".join(UNITS[name])
            raise BadInput(f"{path}: {UNIT_KEY[name]}: expected one of {allowed}, got {unit!r}")
        factors[name] = INPUT_UNITS_TO_SI[name][UNITS[name][unit]]
        raw = doc.get(FROM_UNIT_KEY[name])
        tri = ic.triad(name)
        tri.output_unit = str(raw) if raw else None
        if not raw:
            ic.notes.append(f"imucal: {FROM_UNIT_KEY[name]} is not set: output_unit from --like")
    ic.accel.matrix = p["K_a"] @ p["R_a"] / factors["accel"]
    ic.accel.bias = p["b_a"]
    ic.gyro.matrix = p["K_g"] @ p["R_g"] / factors["gyro"]
    ic.gyro.bias = p["b_g"]
    ic.gyro.g_sensitivity = p["K_ga"] / factors["accel"]
    return ic


def _split(m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``m = K R``: K diagonal, the row norms; R with rows of unit length."""
    k = np.linalg.norm(m, axis=1)
    return np.diag(k), m / k[:, None]


def document(ic: Interchange, input_units: dict[str, str]) -> dict[str, Any]:
    """The ``to_json`` dictionary of a calibration (keys in imucal's order).

    ``input_units``: the certificate's input unit per triad, imucal's ``acc_unit`` and
    ``gyr_unit`` (the matrices are written per that unit).
    """
    for name in ("accel", "gyro"):
        tri = ic.triad(name)
        if tri.matrix is None or tri.bias is None:
            raise BadInput(f"{name}: the certificate has no matrix or bias to export")
    assert ic.accel.matrix is not None and ic.gyro.matrix is not None  # checked above
    fa = INPUT_UNITS_TO_SI["accel"][input_units["accel"]]
    fg = INPUT_UNITS_TO_SI["gyro"][input_units["gyro"]]
    k_a, r_a = _split(ic.accel.matrix * fa)
    k_g, r_g = _split(ic.gyro.matrix * fg)
    g_sens = ic.gyro.g_sensitivity
    k_ga = np.zeros((3, 3)) if g_sens is None else g_sens * fa
    return {
        "acc_unit": input_units["accel"],
        "gyr_unit": input_units["gyro"],
        "from_acc_unit": ic.accel.output_unit,
        "from_gyr_unit": ic.gyro.output_unit,
        "comment": "exported by imudiag certificate export",
        "K_a": k_a.tolist(),
        "R_a": r_a.tolist(),
        "b_a": np.asarray(ic.accel.bias).tolist(),
        "K_g": k_g.tolist(),
        "R_g": r_g.tolist(),
        "K_ga": k_ga.tolist(),
        "b_g": np.asarray(ic.gyro.bias).tolist(),
        "cal_type": "Ferraris",
        "_format_version": FORMAT_VERSION,
    }


def write(ic: Interchange, path: str, input_units: dict[str, str]) -> list[str]:
    """Write the calibration as imucal JSON, or HDF5 by the file name; returns [path]."""
    doc = document(ic, input_units)
    ic.notes.append("imucal: noise and sample rate are not part of its files: not exported")
    if Path(path).suffix.lower() in HDF5_SUFFIXES:
        h5py = _h5py()
        with atomic_path(path) as tmp, h5py.File(tmp, "w") as hdf:
            for key, value in doc.items():
                if key in PARAMETERS:
                    hdf.create_dataset(key, data=value)
                elif value:
                    hdf[key] = value
        return [path]
    write_text_atomic(path, json.dumps(doc, indent=4))
    return [path]


__all__ = ["CAL_TYPES", "HDF5_SUFFIXES", "document", "read", "write"]

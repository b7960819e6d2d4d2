"""Calibration interop: other tools' calibration files to and from certificates.

One module per tool (:mod:`.imu_tk`, :mod:`.imucal`, :mod:`.kalibr`, :mod:`.ikalibr`),
each reading its files into an :class:`~.model.Interchange` (matrices in SI) and writing
one; :mod:`.model` maps an Interchange onto the certificate's ``U = B + diag(S) N x`` and
back. docs/interop.md says what each direction keeps and loses.
"""

from __future__ import annotations

from ..certificate import Certificate
from . import ikalibr, imu_tk, imucal, kalibr
from .model import (
    DEFAULT_GAUGE,
    GAUGES,
    Interchange,
    Provenance,
    from_certificate,
    to_certificate,
)

#: The formats of ``imudiag certificate import/export``.
FORMATS = ("imu_tk", "imucal", "kalibr", "ikalibr")


def read(fmt: str, path: str, accel: str | None = None, gyro: str | None = None) -> Interchange:
    """Read a tool's calibration: ``path`` is the file (imu_tk: the prefix of the two
    ``PREFIX_acc.calib``/``PREFIX_gyro.calib`` files, or ``accel`` and ``gyro`` given)."""
    if fmt == "imu_tk":
        names = imu_tk.paths(path) if path else {}
        return imu_tk.read(accel or names["accel"], gyro or names["gyro"])
    if fmt == "imucal":
        return imucal.read(path)
    if fmt == "kalibr":
        return kalibr.read(path)
    return ikalibr.read(path)


def output_paths(fmt: str, out: str) -> list[str]:
    """The files an export to ``out`` writes (imu_tk: two files from the prefix)."""
    if fmt == "imu_tk":
        return list(imu_tk.paths(out).values())
    return [out]


def write(fmt: str, cert: Certificate, out: str) -> tuple[list[str], list[str]]:
    """Export ``cert`` in ``fmt`` to ``out``; returns (paths written, notes on what was lost)."""
    ic = from_certificate(cert)
    if fmt == "imu_tk":
        written = imu_tk.write(ic, out)
    elif fmt == "imucal":
        units = {"accel": cert.accel.input_unit, "gyro": cert.gyro.input_unit}
        written = imucal.write(ic, out, units)
    elif fmt == "kalibr":
        written = kalibr.write(ic, out)
    else:
        written = ikalibr.write(ic, out)
    return written, ic.notes


__all__ = [
    "DEFAULT_GAUGE",
    "FORMATS",
    "GAUGES",
    "Interchange",
    "Provenance",
    "from_certificate",
    "output_paths",
    "read",
    "to_certificate",
    "write",
]

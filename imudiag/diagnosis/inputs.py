"""Checks and side inputs of the diagnosis commands: log units, sample rate, magnitudes.

- :func:`check_units`: a log whose ``# units:`` metadata (``gyro=deg/s
  accel=m/s^2``) differs from the certificate's ``output_unit`` is converted exactly
  when both are physical units, else rejected naming both.
- :func:`log_rate_hz`: the sample rate from the log's ``sample_rate`` metadata,
  else from its time stamps, else the certificate's; :func:`session_rate_hz`: a stated
  rate (``--rate``) checked against the time stamps, else that.
- :class:`MagnitudeTable`: independent magnitudes for the moving-base variant,
  a CSV ``t,accel,gyro`` (s, m/s^2, rad/s; either magnitude column may be
  missing), interpolated onto sample times.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..argtypes import rate_problem
from ..certificate import Certificate
from ..errors import BadInput
from ..logs.timing import first_block_rate_hz, stated_rate_problem
from ..samples import SampleBlock
from ..units import Conversion, conform_meta


def check_units(log_path: str, meta: dict[str, Any], cert: Certificate) -> Conversion:
    """The exact conversion from the log's stated output units (its ``units`` metadata) to
    the certificate's (:func:`imudiag.units.conform_meta`): identity when they agree or the
    log states none; raises BadInput naming both when they cannot be converted."""
    return conform_meta(meta, cert, log_path)


def log_rate_hz(
    meta: dict[str, Any], first: SampleBlock | None, cert: Certificate, name: str = "the log"
) -> float:
    """Sample rate (Hz): log metadata, else the median time step of the first block, else cert.

    BadInput naming the log ``name`` when its ``sample_rate`` is not an IMU's rate."""
    if "sample_rate" in meta:
        try:
            rate = float(meta["sample_rate"])
            if rate > 0 and np.isfinite(rate):
                problem = rate_problem(rate)
                if problem:
                    raise BadInput(f"{name}: sample_rate (metadata): {problem}")
                return rate
        except (TypeError, ValueError):
            pass
    stamped = first_block_rate_hz(first.t) if first is not None else None
    return stamped if stamped is not None else float(cert.sample_rate)


def session_rate_hz(
    stated: float | None,
    meta: dict[str, Any],
    first: SampleBlock | None,
    cert: Certificate,
    name: str = "the log",
) -> float:
    """The sample rate (Hz) a recording is analysed at: ``stated`` (``--rate``) when given,
    else :func:`log_rate_hz`. BadInput when ``stated`` is not an IMU's rate, or disagrees
    with the time stamps of the first block by more than
    :data:`~imudiag.logs.timing.RATE_TOLERANCE` (both figures named)."""
    if stated is None:
        return log_rate_hz(meta, first, cert, name)
    problem = rate_problem(stated)
    if problem:
        raise BadInput(f"--rate: {problem}")
    if first is not None and len(first) > 2:
        problem = stated_rate_problem(stated, first.t)
        if problem:
            raise BadInput(f"{name}: {problem}")
    return float(stated)


class MagnitudeTable:
    """Independent input magnitudes over time (the moving-base variant's |a| and |w|)."""

    def __init__(self, path: str | Path) -> None:
        self.path = str(path)
        try:
            with open(path, encoding="utf-8") as fh:
                lines = fh.read().splitlines()
        except OSError as exc:
            raise BadInput(f"{path}: cannot read: {exc.strerror or exc}") from None
        header_line = None
        rows: list[list[float]] = []
        for no, line in enumerate(lines, start=1):
            s = line.strip()
            if not s or s.startswith("#"):
                continue
            fields = [f.strip() for f in s.split(",")]
            if header_line is None:
                header_line = no
                self.columns = fields
                if "t" not in fields or not ({"accel", "gyro"} & set(fields)):
                    raise BadInput(
                        f"{path}:{no}: header must name t and at least one of accel, gyro"
                    )
                continue
            if len(fields) != len(self.columns):
                raise BadInput(
                    f"{path}:{no}: expected {len(self.columns)} fields, got {len(fields)}"
                )
            try:
                vals = [float(f) for f in fields]
            except ValueError:
                raise BadInput(f"{path}:{no}: not a number in {s!r}") from None
            if not all(np.isfinite(vals)):
                raise BadInput(f"{path}:{no}: non-finite value")
            rows.append(vals)
        if header_line is None or not rows:
            raise BadInput(f"{path}: no magnitudes")
        data = np.array(rows)
        self.t = data[:, self.columns.index("t")]
        if np.any(np.diff(self.t) <= 0):
            bad = int(np.flatnonzero(np.diff(self.t) <= 0)[0])
            raise BadInput(f"{path}: t not strictly increasing at data row {bad + 2}")
        self.values = {
            k: data[:, self.columns.index(k)] for k in ("accel", "gyro") if k in self.columns
        }

    def at(self, t: np.ndarray) -> dict[str, np.ndarray]:
        """Magnitudes (SI) at times ``t`` (s), linearly interpolated."""
        return {k: np.interp(t, self.t, v) for k, v in self.values.items()}


def write_magnitudes(path: str | Path, t: np.ndarray, accel: np.ndarray, gyro: np.ndarray) -> None:
    """Write a magnitude table (t s, accel m/s^2, gyro rad/s) for the moving-base variant."""
    data = np.column_stack([t, accel, gyro])
    np.savetxt(path, data, delimiter=",", header="t,accel,gyro", comments="", fmt="%.9g")


__all__ = [
    "check_units",
    "log_rate_hz",
    "session_rate_hz",
    "MagnitudeTable",
    "write_magnitudes",
]

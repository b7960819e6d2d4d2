"""Figures of ``imudiag calibrate --plots DIR``: the residuals the calibration summary's
spreads are made of, before (with ``--like``) and after (with the new certificate).

- ``accel_norm_residuals.png``: |a|/g - 1 of each quasi-static interval (dimensionless,
  drawn in units of 10^-3, about 1 mg);
- ``rotation_residuals.png``: the angle between the gravity direction measured after each
  rotation and the one predicted by integrating the gyros through it (deg); only when the
  session has rotations;
- ``gyro_norm_residuals.png``: ``--known-rate``: |w|/rate - 1 of each plateau used
  (dimensionless, in units of 10^-3).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..diagnosis.calibrate import CalibrationResult
from . import TITLE_ROOM, save, subplots

#: The files that may be written, in order (each only when its residuals exist).
FILES = ("accel_norm_residuals.png", "rotation_residuals.png", "gyro_norm_residuals.png")

#: residual kind -> (file, what one point is, y label, factor from the residuals' unit to the
#: drawn unit, the drawn unit, title)
_KINDS: dict[str, tuple[str, str, str, float, str, str]] = {
    "accel_norm": (
        FILES[0],
        "quasi-static interval",
        "|a|/g - 1 [10^-3]",
        1e3,
        "x 10^-3",
        "Accelerometers: |a|/g - 1 of each quasi-static interval",
    ),
    "rotation": (
        FILES[1],
        "rotation between two still intervals",
        "gravity direction error [deg]",
        1.0,
        "deg",
        "Gyros: gravity direction after each integrated rotation, measured minus predicted",
    ),
    "gyro_norm": (
        FILES[2],
        "constant-rate plateau",
        "|w|/rate - 1 [10^-3]",
        1e3,
        "x 10^-3",
        "Gyros on the turntable: |w|/rate - 1 of each plateau",
    ),
}


def _figure(kind: str, data: dict[str, np.ndarray], like_name: str) -> Any:
    _file, point, ylabel, k, unit, title = _KINDS[kind]
    before = np.asarray(data["before"], dtype=float) * k
    after = np.asarray(data["after"], dtype=float) * k
    x = np.arange(1, before.size + 1)
    fig, axes = subplots(2, 1, figsize=(11, 7), sharex=True)
    for ax, values, label, colour in (
        (axes[0], before, f"before: certificate {like_name} (--like)", "tab:orange"),
        (axes[1], after, "after: the calibrated certificate", "tab:blue"),
    ):
        rms = float(np.sqrt(np.mean(values**2))) if values.size else float("nan")
        ax.axhline(0.0, color="k", lw=0.8)
        ax.plot(x, values, "o-", ms=4, lw=0.6, color=colour)
        ax.set_title(
            f"{label}: rms {rms:.4g} {unit}, peak-to-peak {np.ptp(values):.4g} {unit}", fontsize=10
        )
        ax.set_ylabel(ylabel)
        ax.grid(True, alpha=0.3)
    axes[1].set_xlabel(f"{point}, in time order")
    if "t" in data and len(data["t"]):
        t = np.asarray(data["t"], dtype=float)
        span = f"{t[0]:.6g} .. {t[-1]:.6g} s of the log's time"
        axes[1].annotate(span, (1.0, -0.16), xycoords="axes fraction", ha="right", fontsize=8)
    fig.suptitle(title)
    return fig


def write_calibration_plots(
    result: CalibrationResult, directory: str | Path, like_name: str = "--like"
) -> list[Path]:
    """Write the figures of :data:`FILES` whose residuals ``result`` has into ``directory``
    (created); returns the paths written."""
    written = []
    for kind, (file, *_rest) in _KINDS.items():
        data = result.residuals.get(kind)
        if data is None or not len(data["before"]):
            continue
        written.append(save(_figure(kind, data, like_name), directory, file, rect=TITLE_ROOM))
    return written


__all__ = ["FILES", "write_calibration_plots"]

"""The scalar functions of Avrutov (2015), vectorised over samples.

A triad's corrected output normalised by the known magnitude (gravity for
accelerometers, Earth rate or a known rate for gyros) has unit norm; the F0
function is ``1/2 (|u|^2 - 1)`` (dimensionless), zero for a healthy triad.
"""

from __future__ import annotations

import numpy as np

from .certificate import TriadModel


def f0(u: np.ndarray) -> np.ndarray:
    """F0 = 1/2(|u|^2 - 1) for normalised vectors ``u`` (N, 3); dimensionless, (N,)."""
    u = np.asarray(u, dtype=float)
    return 0.5 * (np.einsum("ij,ij->i", u, u) - 1.0)


def corrected_si(
    triad: TriadModel,
    raw: np.ndarray,
    temp_c: np.ndarray | None = None,
    accel_input: np.ndarray | None = None,
) -> np.ndarray:
    """Certificate-corrected input (N, 3) in SI units (rad/s or m/s^2) from raw outputs."""
    return triad.inverse_si(raw, temp_c=temp_c, accel_input=accel_input)


def f0_raw(
    triad: TriadModel,
    raw: np.ndarray,
    magnitude_si: float | np.ndarray,
    temp_c: np.ndarray | None = None,
    accel_input: np.ndarray | None = None,
) -> np.ndarray:
    """F0 of raw outputs (N, 3) against ``magnitude_si`` (scalar or (N,), SI units)."""
    mag = np.asarray(magnitude_si, dtype=float)
    linear = (
        triad.nonlinearity is None
        and (triad.temperature is None or temp_c is None)
        and (triad.g_sensitivity is None or accel_input is None)
    )
    if linear and mag.ndim == 0:
        # one matrix folds N^-1, 1/S, the unit and the magnitude: a single pass over U
        m = np.linalg.inv(triad.n_matrix()) / triad.scale_factor * (triad.unit_to_si / mag)
        u = (np.asarray(raw, dtype=float) - triad.bias) @ m.T
        return f0(u)
    x = corrected_si(triad, raw, temp_c=temp_c, accel_input=accel_input)
    if mag.ndim:
        mag = mag[:, None]
    return f0(x / mag)


def norm(x: np.ndarray) -> np.ndarray:
    """Row norms of an (N, 3) array, same unit as ``x``."""
    x = np.asarray(x, dtype=float)
    return np.sqrt(np.einsum("ij,ij->i", x, x))

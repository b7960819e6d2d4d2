"""The observable part of a triad's misalignment matrix and the gauge used to write it.

The scalar method measures only norms: ``|N^-1 (U - B) / S| = magnitude``. The
norm is unchanged when the triad frame is rotated, ``N -> N Q`` with Q
orthogonal, so it sees ``N N^T`` and nothing else. Every N has the polar
decomposition ``N = P Q`` with P symmetric positive definite, unique; P holds
the 6 observable numbers. The diagnosis works with them as

    P = [[1 + e_x, d1 / 2, d2 / 2],
         [d1 / 2, 1 + e_y, d3 / 2],
         [d2 / 2, d3 / 2, 1 + e_z]]

(e dimensionless relative scale errors, d rad), which to first order are the
certificate's ``e_j = E_j / S_j`` and ``d1 = D_xz - D_yz, d2 = D_zy - D_xy,
d3 = D_yx - D_zx``. Deviations from the certificate are taken between the P of
the estimate and the P of the certificate's own N, so second-order terms of
the certificate's misalignment do not show up as faults.

Gauge written by ``imudiag calibrate`` (``n_symmetric``): N = P, i.e.
``D_xz = d1/2, D_yz = -d1/2, D_zy = d2/2, D_xy = -d2/2, D_yx = d3/2, D_zx = -d3/2``.
It reproduces N N^T exactly (not only to first order, as putting the whole
difference on one angle of each pair does), and Q = I makes the certificate's
frame the orthonormal frame nearest to the sensor axes (polar decomposition),
splitting each difference equally between its two angles.
"""

from __future__ import annotations

import numpy as np

from ..certificate import MISALIGNMENT_DIFFERENCES, MISALIGNMENT_KEYS, TriadModel

#: Names of the 6 shape parameters, in order.
SHAPE_NAMES = ("e_x", "e_y", "e_z", "d1", "d2", "d3")


def p_matrix(shape: np.ndarray) -> np.ndarray:
    """Symmetric P (..., 3, 3) from shape parameters (..., 6) ``e_x e_y e_z d1 d2 d3``."""
    s = np.asarray(shape, dtype=float)
    if s.shape == (6,):
        # one shape (every fit iteration): the same sums and halvings on Python floats,
        # one array built, without the strided writes of the stacked form
        ex, ey, ez, d1, d2, d3 = s.tolist()
        a, b, c = 0.5 * d1, 0.5 * d2, 0.5 * d3
        return np.array([[1.0 + ex, a, b], [a, 1.0 + ey, c], [b, c, 1.0 + ez]])
    p = np.empty(s.shape[:-1] + (3, 3))
    p[..., 0, 0] = 1.0 + s[..., 0]
    p[..., 1, 1] = 1.0 + s[..., 1]
    p[..., 2, 2] = 1.0 + s[..., 2]
    p[..., 0, 1] = p[..., 1, 0] = 0.5 * s[..., 3]
    p[..., 0, 2] = p[..., 2, 0] = 0.5 * s[..., 4]
    p[..., 1, 2] = p[..., 2, 1] = 0.5 * s[..., 5]
    return p


def shape_of_p(p: np.ndarray) -> np.ndarray:
    """Shape parameters (6,) of a symmetric 3x3 P."""
    return np.array(
        [p[0, 0] - 1.0, p[1, 1] - 1.0, p[2, 2] - 1.0, 2 * p[0, 1], 2 * p[0, 2], 2 * p[1, 2]]
    )


def polar(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Polar decomposition ``N = P Q``: P symmetric positive definite, Q orthogonal."""
    w, v = np.linalg.eigh(n @ n.T)
    p = (v * np.sqrt(w)) @ v.T
    q = np.linalg.solve(p, n)
    return p, q


#: Polar decompositions already made, by the bytes of N (every window's fits ask again for
#: the certificate's); at most _POLAR_CACHE_SIZE, emptied when full.
_POLAR_CACHE: dict[bytes, tuple[np.ndarray, np.ndarray]] = {}
_POLAR_CACHE_SIZE = 64


def shape_of_triad(triad: TriadModel) -> tuple[np.ndarray, np.ndarray]:
    """The certificate's observable shape (6,) and the rotation Q of its N = P Q (copies of
    the ones made for the same N before: the same numbers, bit for bit)."""
    n = triad.n_matrix()
    key = n.tobytes()
    known = _POLAR_CACHE.get(key)
    if known is None:
        p, q = polar(n)
        known = (shape_of_p(p), q)
        if len(_POLAR_CACHE) >= _POLAR_CACHE_SIZE:
            _POLAR_CACHE.clear()
        _POLAR_CACHE[key] = known
    return known[0].copy(), known[1].copy()


def n_symmetric(triad: TriadModel, shape: np.ndarray) -> tuple[np.ndarray, dict[str, float]]:
    """Certificate fields (E (3,) output per input unit, misalignment dict rad) for N = P(shape).

    This is the gauge ``imudiag calibrate`` writes (module docstring).
    """
    s = np.asarray(shape, dtype=float)
    e = s[:3] * triad.scale_factor
    mis: dict[str, float] = {}
    for d, (plus, minus) in zip(s[3:], MISALIGNMENT_DIFFERENCES, strict=True):
        mis[plus], mis[minus] = d / 2, -d / 2
    return e, {k: float(mis[k]) for k in MISALIGNMENT_KEYS}


def n_with_rotation(shape: np.ndarray, q: np.ndarray) -> np.ndarray:
    """N = P(shape) Q."""
    return p_matrix(shape) @ q


def small_rotation(phi: np.ndarray) -> np.ndarray:
    """Rotation matrix exp([phi x]) of a rotation vector phi (3,), rad."""
    phi = np.asarray(phi, dtype=float)
    a = float(np.linalg.norm(phi))
    k = np.array([[0.0, -phi[2], phi[1]], [phi[2], 0.0, -phi[0]], [-phi[1], phi[0], 0.0]])
    if a < 1e-12:
        return np.eye(3) + k
    return np.eye(3) + np.sin(a) / a * k + (1 - np.cos(a)) / a**2 * (k @ k)


__all__ = [
    "SHAPE_NAMES",
    "p_matrix",
    "shape_of_p",
    "polar",
    "shape_of_triad",
    "n_symmetric",
    "n_with_rotation",
    "small_rotation",
]

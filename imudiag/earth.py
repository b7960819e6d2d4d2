"""WGS-84 Earth model for the navigation-frame (NED) specific force.

Normal gravity on the ellipsoid by Somigliana's closed formula, continued to
height h by the second-order free-air expansion (NIMA TR8350.2, eq. 4-3):

    gamma(phi, 0) = gamma_e (1 + k sin^2 phi) / sqrt(1 - e^2 sin^2 phi)
    gamma(phi, h) = gamma(phi, 0) (1 - 2/a (1 + f + m - 2 f sin^2 phi) h + 3 h^2 / a^2)

It is the magnitude of gravitation plus the centrifugal acceleration of the
Earth's rotation, normal to the ellipsoid (deflection of the vertical, below
1e-4 rad, neglected), so in NED ``g_n = (0, 0, gamma)``.
"""

from __future__ import annotations

import numpy as np

A = 6378137.0  #: m, semi-major axis
F = 1.0 / 298.257223563  #: flattening
E2 = F * (2.0 - F)  #: first eccentricity squared
OMEGA_E = 7.292115e-5  #: rad/s, Earth rotation rate
GAMMA_E = 9.7803253359  #: m/s^2, normal gravity at the equator
GAMMA_P = 9.8321849378  #: m/s^2, normal gravity at the poles
GM = 3.986004418e14  #: m^3/s^2
B = A * (1.0 - F)  #: m, semi-minor axis
K_SOMIGLIANA = B * GAMMA_P / (A * GAMMA_E) - 1.0
M_RATIO = OMEGA_E**2 * A**2 * B / GM  #: omega^2 a^2 b / GM


def normal_gravity(lat_deg: np.ndarray | float, h_m: np.ndarray | float = 0.0) -> np.ndarray:
    """Normal gravity magnitude (m/s^2) at geodetic latitude (deg) and ellipsoidal height (m)."""
    s2 = np.sin(np.radians(np.asarray(lat_deg, dtype=float))) ** 2
    h = np.asarray(h_m, dtype=float)
    g0 = GAMMA_E * (1.0 + K_SOMIGLIANA * s2) / np.sqrt(1.0 - E2 * s2)
    return g0 * (1.0 - 2.0 / A * (1.0 + F + M_RATIO - 2.0 * F * s2) * h + 3.0 * h * h / A**2)


def radii(lat_deg: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    """Meridian and prime-vertical radii of curvature (m) at latitude (deg)."""
    s2 = np.sin(np.radians(np.asarray(lat_deg, dtype=float))) ** 2
    w = np.sqrt(1.0 - E2 * s2)
    return A * (1.0 - E2) / w**3, A / w


def earth_rate_ned(lat_deg: np.ndarray | float, rate_rad_s: float = OMEGA_E) -> np.ndarray:
    """Earth rate Omega_ie in NED (..., 3), rad/s: (Omega cos phi, 0, -Omega sin phi), Omega
    = ``rate_rad_s`` (WGS-84's by default; the simulator's trajectories may set another)."""
    phi = np.radians(np.asarray(lat_deg, dtype=float))
    return np.stack([rate_rad_s * np.cos(phi), np.zeros_like(phi), -rate_rad_s * np.sin(phi)], -1)


def transport_rate_ned(
    lat_deg: np.ndarray | float, h_m: np.ndarray | float, vel_ned: np.ndarray
) -> np.ndarray:
    """Transport rate omega_en in NED (..., 3), rad/s, of velocity ``vel_ned`` (m/s):
    (vE/(RN+h), -vN/(RM+h), -vE tan(phi)/(RN+h))."""
    v = np.asarray(vel_ned, dtype=float)
    rm, rn = radii(lat_deg)
    h = np.asarray(h_m, dtype=float)
    phi = np.radians(np.asarray(lat_deg, dtype=float))
    return np.stack(
        [v[..., 1] / (rn + h), -v[..., 0] / (rm + h), -v[..., 1] * np.tan(phi) / (rn + h)], -1
    )


def coriolis_term(
    lat_deg: np.ndarray | float, h_m: np.ndarray | float, vel_ned: np.ndarray
) -> np.ndarray:
    """(2 Omega_ie + omega_en) x v_n (..., 3), m/s^2: what the navigation equation
    ``dv/dt = f + g - (2 Omega_ie + omega_en) x v`` subtracts from f + g."""
    w = 2.0 * earth_rate_ned(lat_deg) + transport_rate_ned(lat_deg, h_m, vel_ned)
    return np.cross(w, np.asarray(vel_ned, dtype=float))


__all__ = [
    "A",
    "OMEGA_E",
    "coriolis_term",
    "earth_rate_ned",
    "normal_gravity",
    "radii",
    "transport_rate_ned",
]

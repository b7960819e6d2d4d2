"""Rotation helpers for the simulator (vectorised; angles in rad unless named ``_deg``).

Conventions: the local level frame is NED (x north, y east, z down); an
attitude matrix ``C`` maps body coordinates to NED (``v_n = C @ v_b``).
"""

from __future__ import annotations

import math

import numpy as np

from ..rotations import skew


def axis_angle_matrix(axis: np.ndarray, angle: np.ndarray | float) -> np.ndarray:
    """Rotation matrices about unit ``axis`` (..., 3) by ``angle`` (...) rad (Rodrigues)."""
    axis = np.asarray(axis, dtype=float)
    angle = np.asarray(angle, dtype=float)
    k = skew(axis)
    s = np.sin(angle)[..., None, None]
    c = np.cos(angle)[..., None, None]
    eye = np.eye(3)
    return eye + s * k + (1.0 - c) * (k @ k)


def rotation_vector(r: np.ndarray) -> np.ndarray:
    """Rotation vectors (axis * angle, rad) of rotation matrices (..., 3, 3); angle in [0, pi]."""
    r = np.asarray(r, dtype=float)
    tr = np.trace(r, axis1=-2, axis2=-1)
    cos_a = np.clip((tr - 1.0) / 2.0, -1.0, 1.0)
    angle = np.arccos(cos_a)
    w = np.stack(
        [r[..., 2, 1] - r[..., 1, 2], r[..., 0, 2] - r[..., 2, 0], r[..., 1, 0] - r[..., 0, 1]],
        axis=-1,
    )
    sin_a = np.sin(angle)
    out = np.empty(w.shape)
    small = angle < 1e-6
    big = angle > math.pi - 1e-4
    mid = ~(small | big)
    out[mid] = w[mid] * (angle[mid] / (2.0 * sin_a[mid]))[..., None]
    out[small] = 0.5 * w[small]  # angle ~ sin(angle)
    if np.any(big):
        # near pi: axis from the symmetric part, sign from the skew part
        rb = r[big]
        ab = angle[big]
        sym = (rb + np.swapaxes(rb, -1, -2)) / 2.0 - np.cos(ab)[..., None, None] * np.eye(3)
        diag = np.clip(np.diagonal(sym, axis1=-2, axis2=-1), 0.0, None)
        j = np.argmax(diag, axis=-1)
        axis = np.take_along_axis(sym, j[:, None, None], axis=-2)[:, 0, :]
        axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
        sign = np.sign(np.sum(axis * w[big], axis=-1))
        sign[sign == 0] = 1.0
        out[big] = axis * (sign * ab)[:, None]
    return out


def rpy_matrix(roll_deg: float, pitch_deg: float, yaw_deg: float) -> np.ndarray:
    """Body-to-NED matrix from roll, pitch, yaw in degrees (C = Rz(yaw) Ry(pitch) Rx(roll))."""
    r, p, y = (math.radians(v) for v in (roll_deg, pitch_deg, yaw_deg))
    cr, sr, cp, sp = math.cos(r), math.sin(r), math.cos(p), math.sin(p)
    cy, sy = math.cos(y), math.sin(y)
    rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    return rz @ ry @ rx


def attitude_with_up(up_body: np.ndarray, yaw_rad: float = 0.0) -> np.ndarray:
    """Body-to-NED matrix that puts the body direction ``up_body`` straight up.

    At rest the specific force then reads ``+g * up_body / |up_body|`` in body
    axes. ``yaw_rad`` turns the body about the vertical.
    """
    u = np.asarray(up_body, dtype=float)
    u = u / np.linalg.norm(u)
    down = -u  # third row of C: the NED down axis in body coordinates
    helper = np.array([1.0, 0.0, 0.0]) if abs(down[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    north = helper - np.dot(helper, down) * down
    north /= np.linalg.norm(north)
    east = np.cross(down, north)
    c = np.vstack([north, east, down])
    cy, sy = math.cos(yaw_rad), math.sin(yaw_rad)
    rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    return rz @ c

"""The gyro rotation fit's analytic Jacobian equals central differences (issue 14).

The fit's Jacobian used to be forward differences (h = 1e-6, one product of every motion's
rotations per parameter); it is now carried down the product tree once
(:func:`imudiag.rotations.segmented_product_sensitivity`). Checked here against central
differences on the real Xsens MTi recording's windows, and the pieces on their own.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from imudiag.certificate import Certificate, load
from imudiag.diagnosis.gauge import shape_of_triad
from imudiag.diagnosis.gyro_fit import (
    ninv_derivatives,
    predict_end_directions,
    predict_with_jacobian,
    stack_pairs,
)
from imudiag.diagnosis.inputs import log_rate_hz
from imudiag.diagnosis.intervals import IntervalCollector, QuasiStaticInterval
from imudiag.diagnosis.session import blocks
from imudiag.diagnosis.window import rotation_pairs
from imudiag.rotations import (
    quat_matrix,
    rotvec_quat,
    rotvec_right_jacobian,
    segment_product_plan,
    segmented_product_of_rotvecs,
    segmented_product_sensitivity,
)

DATA = Path(__file__).resolve().parent / "data"
XSENS = DATA / "real" / "xsens-mti-multiposition" / "session.csv.gz"
LIKE_XSENS = DATA / "diagnosis" / "like-xsens.yaml"
#: step of the central differences (parameter units: dimensionless or rad)
H = 1e-6
#: |analytic - central difference| allowed, per unit of the parameter (rad of direction per
#: unit): the central difference's own error here is about 3e-10 (rounding, eps / H, and
#: truncation, H^2 times the third derivative); the forward difference it replaced was off
#: by about 1e-6
JAC_TOL = 1e-8


def _central_jacobian(stack, shape_c, q_c, x, up0):
    """d pred / dx (n, 3, npar) by central differences of the plain prediction."""
    out = np.empty((up0.shape[0], 3, x.shape[0]))
    for j in range(x.shape[0]):
        e = np.zeros_like(x)
        e[j] = H
        sets = np.stack([ninv_derivatives(shape_c, q_c, x + s * e, True)[0] for s in (1.0, -1.0)])
        plus, minus = predict_end_directions(stack, sets, up0)
        out[:, :, j] = (plus - minus) / (2.0 * H)
    return out


def collect_xsens_intervals(cert: Certificate) -> list[QuasiStaticInterval]:
    """The still intervals of the real Xsens recording, as the diagnosis collects them
    (the detector measuring the data's noise)."""
    intervals = []
    with blocks(XSENS) as (meta, stream):
        collector = None
        for block in stream:
            if collector is None:
                collector = IntervalCollector(
                    cert,
                    log_rate_hz(meta, block, cert),
                    detector_options={"certificate_noise": False},
                )
            intervals.extend(collector.update(block))
        assert collector is not None
        intervals.extend(collector.flush())
    return intervals


@pytest.fixture(scope="module")
def xsens_windows():
    """Rotation pairs of windows of 24 consecutive intervals of the real Xsens recording
    (the diagnosis's default window), every 8th window start."""
    cert = load(LIKE_XSENS)
    intervals = collect_xsens_intervals(cert)
    windows = []
    for start in range(0, max(1, len(intervals) - 23), 8):
        pairs = rotation_pairs(cert, cert.accel, intervals[start : start + 24])
        if pairs:
            windows.append(pairs)
    assert len(windows) >= 3
    return cert, windows


def test_analytic_jacobian_equals_central_differences_on_real_windows(xsens_windows):
    """Every motion of every window, at the certificate and 1e-2 away from it (shape and
    frame), every parameter: within JAC_TOL; the prediction is the plain one bit for bit."""
    cert, windows = xsens_windows
    shape_c, q_c = shape_of_triad(cert.gyro)
    rng = np.random.default_rng(14)
    worst = 0.0
    for pairs in windows:
        stack = stack_pairs(cert.gyro, pairs)
        up0 = np.array([p.up0 for p in pairs])
        for x in (np.zeros(9), rng.normal(scale=1e-2, size=9)):
            ninv, dninv = ninv_derivatives(shape_c, q_c, x, True)
            pred, jac = predict_with_jacobian(stack, ninv, dninv, up0)
            assert np.array_equal(pred, predict_end_directions(stack, ninv[None], up0)[0])
            central = _central_jacobian(stack, shape_c, q_c, x, up0)
            assert np.abs(jac).max() > 0.1  # the motions do turn the directions
            worst = max(worst, float(np.abs(jac - central).max()))
    assert worst < JAC_TOL, worst


def test_segment_sensitivity_against_central_differences():
    """Segments of 0, 1, 2, odd and even lengths, blocks below the series thresholds: the
    products equal segmented_product_of_rotvecs bit for bit, and a change dL of the
    matrix moves each product by the right perturbation the sensitivity says."""
    rng = np.random.default_rng(7)
    lengths = np.array([5, 0, 1, 2, 37, 16])
    k = int(lengths.sum())
    inc = rng.normal(scale=0.02, size=(k, 3))  # rad, blocks of about a degree
    inc[:3] *= 1e-6  # below the series thresholds
    ell = np.eye(3) + rng.normal(scale=0.05, size=(3, 3))
    plan = segment_product_plan(lengths)
    q, sens = segmented_product_sensitivity(inc @ ell.T, inc, lengths, plan)
    assert np.array_equal(q, segmented_product_of_rotvecs((inc @ ell.T)[None], plan)[0])
    assert sens.shape == (6, 3, 3, 3) and not sens[1].any()  # the empty segment
    r0 = quat_matrix(q)
    for c in range(3):
        for d in range(3):
            dl = np.zeros((3, 3))
            dl[c, d] = H
            rp = quat_matrix(segmented_product_of_rotvecs((inc @ (ell + dl).T)[None], plan)[0])
            rm = quat_matrix(segmented_product_of_rotvecs((inc @ (ell - dl).T)[None], plan)[0])
            # right perturbation: R^T dR = [omega]x
            w = np.einsum("sji,sjk->sik", r0, (rp - rm) / (2.0 * H))
            omega = np.stack([w[:, 2, 1], w[:, 0, 2], w[:, 1, 0]], axis=1)
            assert np.allclose(sens[:, :, c, d], omega, rtol=0, atol=1e-8)


@pytest.mark.parametrize("angle", [0.0, 1e-9, 1e-5, 9e-3, 1.1e-2, 0.3, 3.0])
def test_right_jacobian(angle):
    """R(theta + d) = R(theta) exp([J_r d]x) to first order, on both sides of the series
    threshold (1e-2 rad) and at large angles."""
    axis = np.array([0.48, -0.6, 0.64])
    theta = angle * axis
    jr = rotvec_right_jacobian(theta)
    r0 = quat_matrix(rotvec_quat(theta))
    for j in range(3):
        e = np.zeros(3)
        e[j] = H
        dr = (quat_matrix(rotvec_quat(theta + e)) - quat_matrix(rotvec_quat(theta - e))) / (2 * H)
        w = r0.T @ dr
        assert np.allclose([w[2, 1], w[0, 2], w[1, 0]], jr[:, j], rtol=0, atol=1e-9)
    assert rotvec_right_jacobian(np.tile(theta, (2, 4, 1))).shape == (2, 4, 3, 3)


def test_kept_rotations_equal_the_batch_bit_for_bit(xsens_windows):
    """A window's fit starts at the certificate, where each motion's rotation and
    sensitivity are kept in its memo (a motion is in every window of its interval): the
    kept ones, computed in another window's batch, equal this window's own bit for bit."""
    from imudiag.diagnosis.gyro_fit import motion_sensitivities

    cert, windows = xsens_windows
    shape_c, q_c = shape_of_triad(cert.gyro)
    ninv, _ = ninv_derivatives(shape_c, q_c, np.zeros(9), True)
    pairs = windows[0]
    plain = motion_sensitivities(stack_pairs(cert.gyro, pairs), ninv)
    memos: list[dict | None] = [{} for _ in pairs]
    half = len(pairs) // 2  # an earlier window held only the first half of them
    motion_sensitivities(stack_pairs(cert.gyro, pairs[:half]), ninv, memos[:half])
    assert all(len(m) == 1 for m in memos[:half]) and not any(memos[half:])
    kept = motion_sensitivities(stack_pairs(cert.gyro, pairs), ninv, memos)
    assert all(len(m) == 1 for m in memos)
    assert np.array_equal(kept[0], plain[0]) and np.array_equal(kept[1], plain[1])
    again = motion_sensitivities(stack_pairs(cert.gyro, pairs), ninv, memos)
    assert np.array_equal(again[1], plain[1])

"""Issue 10: sliding windows reject isolated outlier intervals, but not a step change (a fault
onset inside the window), which the window keeps whole; the stream then starts its next
windows at the step (tests/test_fault_onset.py), where before they rolled past it over 24
intervals.

Real recording: tests/data/real/xsens-mti-multiposition (SOURCE.md there).
"""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path

import numpy as np
import pytest
from conftest import run_imudiag_in_process

from imudiag.certificate import load, load_default
from imudiag.diagnosis.changepoint import STEP_SIGMA, window_exact_fit
from imudiag.diagnosis.params import limit_vector
from imudiag.diagnosis.scalar_fit import robust_exact_fit
from imudiag.sim.trajectories import spread_up_directions

G = 9.80665
DATA = Path(__file__).parent / "data"
XSENS = DATA / "real" / "xsens-mti-multiposition" / "session.csv.gz"
LIKE = DATA / "diagnosis" / "like-xsens.yaml"
K = 24


def _means(triad, up, n, rng):
    u = triad.forward_si(up * G)
    sigma = triad.noise_sigma(200.0)
    return u + rng.normal(size=u.shape) * sigma / math.sqrt(n), np.tile(sigma**2 / n, (len(up), 1))


def _window(seed: int):
    cert = load_default()
    rng = np.random.default_rng(seed)
    up = spread_up_directions(K, seed)
    means, var = _means(cert.accel, up, 400, rng)
    return cert, up, means, var, [f"interval {i}" for i in range(K)]


def _fit(cert, means, var, labels):
    return window_exact_fit(
        cert.accel, means, var, G / cert.accel.unit_to_si, labels, 3.0, prior_factor=10.0
    )


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_an_isolated_outlier_in_a_window_is_rejected(seed):
    cert, up, means, var, labels = _window(seed)
    clean = _fit(cert, means, var, labels)
    assert "rejected" not in clean.extra and "rejection_withheld" not in clean.extra
    bad = 4 + seed * 5  # inside the window, intervals on both sides
    means[bad] += 40.0 * np.sqrt(var[bad]) * up[bad]
    fit = _fit(cert, means, var, labels)
    assert [r["point"] for r in fit.extra["rejected"]] == [labels[bad]]
    assert "rejection_withheld" not in fit.extra and "step_change" not in fit.extra
    assert labels[bad] not in fit.point_labels and len(fit.point_labels) == K - 1
    assert np.all(np.abs(fit.estimate - clean.estimate) <= 2.0 * clean.std)


@pytest.mark.parametrize("newest", [True, False])
def test_a_step_change_in_a_window_is_not_rejected(newest):
    """The unit's accelerometer biases step by 20 limits for the newest (or the oldest) 5 of
    24 intervals: the outlier rejection alone drops all 5; the window keeps them, says
    why, and its estimate is the plain fit's."""
    cert, up, means, var, labels = _window(6)
    changed = copy.deepcopy(cert.accel)
    changed.bias = changed.bias + 20.0 * limit_vector(changed)[:3]
    rows = np.arange(K - 5, K) if newest else np.arange(5)
    rng = np.random.default_rng(6)
    means[rows] = _means(changed, up[rows], 400, rng)[0]
    g_in = G / cert.accel.unit_to_si
    robust = robust_exact_fit(cert.accel, means, var, g_in, labels=labels, min_dof=3.0)
    assert sorted(r["point"] for r in robust.extra["rejected"]) == sorted(labels[i] for i in rows)
    fit = _fit(cert, means, var, labels)
    assert "rejected" not in fit.extra
    step = fit.extra["rejection_withheld"]
    assert step["points"] == [r["point"] for r in robust.extra["rejected"]]
    assert "a step change, not outliers" in step["reason"]
    assert float(step["reason"].split(" sigma")[0].split()[-1]) > STEP_SIGMA
    assert fit.point_labels == labels
    # where the unit as it is now begins: the stream starts its next windows there
    first = K - 5 if newest else 5
    assert fit.extra["step_change"] == {"first": labels[first], "index": first}


def test_an_outlier_at_the_newest_end_is_kept_until_the_window_rolls():
    cert, up, means, var, labels = _window(7)
    means[K - 1] += 40.0 * np.sqrt(var[K - 1]) * up[K - 1]
    fit = _fit(cert, means, var, labels)
    assert "rejected" not in fit.extra
    assert "end of the window" in fit.extra["rejection_withheld"]["reason"]
    assert "step_change" not in fit.extra  # not a step: nothing beyond it to tell
    # one interval later it is no longer at the end: rejected
    more, mvar = _means(cert.accel, up[:1], 400, np.random.default_rng(8))
    m2, v2 = np.vstack([means[1:], more]), np.vstack([var[1:], mvar])
    fit2 = _fit(cert, m2, v2, labels[1:] + ["interval 24"])
    assert [r["point"] for r in fit2.extra["rejected"]] == [labels[K - 1]]


def test_diagnose_windows_reject_the_offset_hold_of_a_real_session(tmp_path):
    """The Xsens session with one hold offset by 15 counts on ax: the windows that hold it
    in their middle reject it and name it; no fault, no step change claimed. Both commands in
    this process: calibrate and diagnose of the Xsens session run as real subprocesses in
    test_interop.py."""
    from test_robust_fit import _xsens_with_offset_hold

    log, (t0, t1) = _xsens_with_offset_hold(tmp_path, 15.0)
    cal = tmp_path / "cal.yaml"
    r = run_imudiag_in_process("calibrate", str(XSENS), "--like", str(LIKE), "--out", str(cal))
    assert r.returncode == 0, r.stderr
    r = run_imudiag_in_process("diagnose", str(log), "--certificate", str(cal), "--json", "-")
    assert r.returncode == 0, r.stderr
    rep = json.loads(r.stdout)
    assert rep["verdict"]["faults"] == []
    label = f"({t0:.2f}-{t1:.2f} s)"
    hits = [
        w["index"]
        for w in rep["windows"]
        if any(label in x["point"] for x in w["accel"].get("rejected", []))
    ]
    assert hits, "no window rejected the offset hold"
    assert not any("rejection_withheld" in w["accel"] for w in rep["windows"] if w["index"] in hits)
    assert load(cal).accel is not None

"""GNSS latency and lever arm solved together (issue 15; aiding/joint.py).

The simulator knows the true latency (0.12 s) and lever arm ((1.0, -0.8, -1.2) m);
``benchmarks.latency_lever`` runs the estimates the diagnosis runs. Fixed seeds.
"""

from __future__ import annotations

import math

import numpy as np

from benchmarks.latency_lever import LATENCY_S, LEVER, run_drive
from imudiag.aiding.moving import MovingConfig, moving_base_diagnosis
from imudiag.aiding.tpv import parse_tpv, track_from_reports
from imudiag.certificate import load_default
from imudiag.sim.drive import GnssSimConfig, simulate_drive


def test_joint_solution_undoes_the_confound_on_exact_kinematics():
    """Hilly drive, exact kinematics: the grades' |f| changes make a latency error look
    like the longitudinal lever term. Separately, the correlation's latency is 53 ms off
    and the lever's x component comes out near 0 (true 1.0 m); together both are within
    the stated tolerances (0.03 s, 0.25 m), the latency std is small enough for the
    joint solution to be used, and the two are reported strongly correlated."""
    r = run_drive("hilly", 21, "exact", 600.0)
    sep, joint, chosen = r["separate"], r["joint"], r["chosen"]
    assert abs(sep["latency_error_ms"]) > 30.0 and abs(sep["lever_error_m"][0]) > 0.5
    assert abs(joint["latency_error_ms"]) < 30.0
    assert joint["lever_error_m"][0] is not None and abs(joint["lever_error_m"][0]) < 0.25
    assert joint["converged"] and joint["latency_std_ms"] <= 10.0
    assert joint["correlation"][0] > 0.8
    assert chosen["joint"] and chosen["latency_error_ms"] == joint["latency_error_ms"]


def test_joint_solution_keeps_a_flat_urban_drive_within_tolerance():
    """Urban drive, exact kinematics: the separate estimates are already good (latency
    within 10 ms, lever x, y within 0.05 m); the joint solution keeps them within the
    tolerances and the latency within 5 ms."""
    r = run_drive("urban", 21, "exact", 600.0)
    joint = r["joint"]
    assert r["chosen"]["joint"]
    assert abs(joint["latency_error_ms"]) < 5.0
    for i in (0, 1):
        assert joint["lever_error_m"][i] is not None and abs(joint["lever_error_m"][i]) < 0.25


def test_confounded_mems_drive_keeps_the_separate_estimates():
    """MEMS noise and RTK GNSS with a 1 m lever arm on the hilly drive: the joint latency
    std (38 ms) is above 10 ms, so the diagnosis keeps the correlation's latency (used_s
    equals it) and says why in ``latency_lever``; the correlation with the lever is
    reported. The correlation's own std (14 ms) would call its 0.054 s (66 ms off)
    determined: the joint solution 95 ms away (std 38 ms) shows the lever arm's pull,
    which widens the std used (to 102 ms) and makes the latency undetermined."""
    cert = load_default()
    gnss = GnssSimConfig(
        sigma_h_m_s=0.01, sigma_v_m_s=0.015, latency_s=LATENCY_S, lever_arm_m=LEVER
    )
    res, reports, _ = simulate_drive("hilly", 400.0, cert, seed=21, gnss=gnss)
    track = track_from_reports([p for p in (parse_tpv(x) for x in reports) if p is not None])
    out = moving_base_diagnosis(res.samples, cert, track, MovingConfig())
    lat, joint = out["gnss"]["latency"], out["gnss"]["latency_lever"]
    assert joint["used"] is False
    assert joint["latency_std_s"] is None or joint["latency_std_s"] > 0.01
    assert "separate estimates kept" in joint["note"]
    assert lat["used_s"] == lat["latency_s"]
    assert len(joint["latency_lever_correlation"]) == 3
    assert lat["std_s"] <= 0.03 < lat["used_std_s"]
    # its error is the distance to the joint latency plus the joint one's error
    pull = math.hypot(joint["latency_s"] - lat["latency_s"], joint["latency_std_s"])
    assert math.isclose(lat["used_std_s"], pull, abs_tol=2e-4)  # rounded to 0.1 ms
    assert not lat["determined"] and "lever arm left out" in lat["reason"]
    assert abs(lat["latency_s"] - LATENCY_S) <= 2 * lat["used_std_s"]


def test_configured_latency_or_lever_arm_skips_the_joint_solution():
    """A configured latency or lever arm is used as given: no joint solution."""
    cert = load_default()
    res, reports, _ = simulate_drive("urban", 200.0, cert, seed=3)
    track = track_from_reports([p for p in (parse_tpv(x) for x in reports) if p is not None])
    for cfg in (MovingConfig(latency_s=0.12), MovingConfig(lever_arm_m=(0.0, 0.0, 0.0))):
        out = moving_base_diagnosis(res.samples, cert, track, cfg)
        assert "latency_lever" not in out["gnss"]


def test_joint_estimate_reports_stds_and_correlation():
    """The report holds the latency std (ms), the lever stds (m) and the correlations."""
    r = run_drive("urban", 22, "exact", 300.0)
    joint = r["joint"]
    assert math.isfinite(joint["latency_std_ms"]) and joint["latency_std_ms"] > 0
    assert all(np.isfinite(joint["lever_std_m"][:2]))
    assert all(-1.0 <= c <= 1.0 for c in joint["correlation"] if c == c)

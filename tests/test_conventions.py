"""Issue 30 item 2: each convention and each fit defined once, and every consumer of it
agreeing: the misalignment sign table (imudiag.certificate), the cross-product matrix
(imudiag.rotations.skew), the Earth model (imudiag.earth, on the ground floor), the gyro
rest-bias plus rotation fit (imudiag.diagnosis.gyro_fit.rest_rotation_fit), the simulator's
kinematics (imudiag.sim.trajectories.Motion.evaluate) and the validator of configuration
values (imudiag.validate)."""

from __future__ import annotations

import ast
import functools
from pathlib import Path

import numpy as np
import pytest

from imudiag.certificate import (
    MISALIGNMENT_DIFFERENCES,
    MISALIGNMENT_KEYS,
    MISALIGNMENT_N_ENTRY,
    MISALIGNMENT_PAIRS,
    load_default,
    misalignment_of_n,
)
from imudiag.diagnosis.calibrate import fields_from_n
from imudiag.diagnosis.gauge import n_symmetric
from imudiag.earth import OMEGA_E, earth_rate_ned
from imudiag.rotations import skew
from imudiag.sim import Effects, Fault, multi_position, simulate
from imudiag.sim.faults import PAIR_KEYS, apply_faults
from imudiag.sim.trajectories import EARTH_RATE

ROOT = Path(__file__).resolve().parents[1]
#: the package's sources (imudiag/drivers and imudiag/config are links to the last two)
SOURCES = sorted(
    p
    for d in ("imudiag", "drivers", "config")
    for p in (ROOT / d).rglob("*.py")
    if p.relative_to(ROOT).parts[1] not in ("drivers", "config")
)


#: Words of a hand-written value check's reason: only imudiag.validate writes them.
VALIDATOR_WORDS = (
    "is out of range",
    "expected a number, got",
    "expected an integer",
    "expected true or false",
    "expected a non-empty string",
    "not a finite number",
)


def _strings(node: ast.AST) -> list[str]:
    """The literal text of a string constant or f-string."""
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return [node.value]
    if isinstance(node, ast.JoinedStr):
        return ["".join(v.value for v in node.values if isinstance(v, ast.Constant))]
    return []


@functools.cache
def _definitions() -> dict[str, list[str]]:
    """Where each function name is defined (a method as ``Class.name`` too), where a literal
    dict keyed by the six misalignment keys (a sign table written out again) appears, where
    a TriadFit of method ``rest+rotation`` is built, where a value check's reason is written
    and where a specific force is formed from a navigation-frame acceleration and gravity."""
    found: dict[str, list[str]] = {}
    for path in SOURCES:
        rel = str(path.relative_to(ROOT))
        tree = ast.parse(path.read_text(), rel)
        for node in ast.walk(tree):
            if isinstance(node, ast.ClassDef):
                for item in node.body:
                    if isinstance(item, ast.FunctionDef):
                        found.setdefault(f"{node.name}.{item.name}", []).append(rel)
            if isinstance(node, ast.FunctionDef):
                found.setdefault(node.name, []).append(rel)
            elif isinstance(node, ast.Dict):
                keys = {k.value for k in node.keys if isinstance(k, ast.Constant)}
                if keys == set(MISALIGNMENT_KEYS):
                    found.setdefault("<misalignment table>", []).append(rel)
            elif isinstance(node, ast.keyword) and node.arg == "method":
                if "rest+rotation" in _strings(node.value):
                    found.setdefault("<rest+rotation fit>", []).append(rel)
            elif isinstance(node, (ast.Constant, ast.JoinedStr)):
                if any(w in text for text in _strings(node) for w in VALIDATOR_WORDS):
                    found.setdefault("<value check reason>", []).append(rel)
        for call in ast.walk(tree):
            if isinstance(call, ast.Call) and getattr(call.func, "id", "") == "Trajectory":
                found.setdefault("<Trajectory built>", []).append(rel)
    return found


def test_each_convention_is_defined_once():
    defs = _definitions()
    assert defs["skew"] == ["imudiag/rotations.py"] and "_skew" not in defs
    assert defs["earth_rate_ned"] == ["imudiag/earth.py"]
    assert defs["normal_gravity"] == ["imudiag/earth.py"]
    assert defs["<misalignment table>"] == ["imudiag/certificate.py"]


def test_each_fit_kinematics_and_validator_is_defined_once():
    """A second copy of the rest-bias plus rotation fit, of the simulator's kinematics or
    of a hand-written value check fails here (issue 30 item 2)."""
    defs = _definitions()
    # the gyro rest-bias plus rotation fit: assembled in one function, used by both callers
    assert defs["rest_rotation_fit"] == ["imudiag/diagnosis/gyro_fit.py"]
    assert defs["<rest+rotation fit>"] == ["imudiag/diagnosis/gyro_fit.py"]
    assert defs["rest_bias"] == ["imudiag/diagnosis/gyro_fit.py"]
    for caller in ("window.py", "calibrate.py"):
        text = (ROOT / "imudiag" / "diagnosis" / caller).read_text()
        assert "rest_rotation_fit(" in text and "rest_bias(" not in text
    # the simulator's kinematics: one evaluate (body rate and specific force from the
    # motion), every motion giving only its kinematics and its navigation frame
    assert [d for d in defs if d.endswith(".evaluate")] == ["Motion.evaluate"]
    assert defs["Motion.evaluate"] == ["imudiag/sim/trajectories.py"]
    # (the model check replays measured specific forces at rest: no kinematics of its own)
    built = set(defs["<Trajectory built>"])
    assert built == {"imudiag/sim/trajectories.py", "imudiag/modelcheck/simulate.py"}
    assert defs["DriveMotion.navigation_frame"] == ["imudiag/sim/drive.py"]
    # the validator: the reasons of a value check are written in imudiag.validate alone
    # (argtypes parses option text for argparse; logs/base names a column's integer range)
    allowed = {"imudiag/validate.py", "imudiag/argtypes.py", "imudiag/logs/base.py"}
    assert set(defs["<value check reason>"]) <= allowed, defs["<value check reason>"]
    # the readers that had their own checks: each goes through it
    for reader in (
        "imudiag/diagnosis/config.py",
        "imudiag/service/config.py",
        "imudiag/bench/scenario.py",
        "imudiag/sim/scenarios.py",
        "imudiag/certificate.py",
        "imudiag/interop/model.py",
    ):
        assert "validate." in (ROOT / reader).read_text(), reader


def test_the_sign_table_is_the_models_n_and_its_inverse():
    """N from the certificate's fields, and the fields read back from N by every reader
    (calibration, window estimates through misalignment_of_n), agree key by key."""
    rng = np.random.default_rng(30)
    cert = load_default()
    for tri in (cert.gyro, cert.accel):
        tri.misalignment = {
            k: float(v) for k, v in zip(MISALIGNMENT_KEYS, rng.normal(0, 1e-3, 6), strict=True)
        }
        n = tri.n_matrix()
        for key, (row, col, sign) in MISALIGNMENT_N_ENTRY.items():
            assert n[row, col] == sign * tri.misalignment[key]
        assert misalignment_of_n(n) == tri.misalignment
        e, mis = fields_from_n(n, tri.scale_factor)
        assert mis == tri.misalignment
        np.testing.assert_allclose(e, tri.scale_factor_error, rtol=1e-12, atol=1e-15)
        # every position off the diagonal is one key's, exactly once
        cells = sorted((r, c) for r, c, _ in MISALIGNMENT_N_ENTRY.values())
        assert cells == sorted((r, c) for r in range(3) for c in range(3) if r != c)


def test_the_differences_pairs_faults_and_gauge_agree():
    """d_k = D_plus - D_minus for the pair MISALIGNMENT_PAIRS[k]; a misalignment fault on
    that pair adds its value to d_k; the gauge calibrate writes gives back the same d."""
    cert = load_default()
    rng = np.random.default_rng(31)
    cert.accel.misalignment = {
        k: float(v) for k, v in zip(MISALIGNMENT_KEYS, rng.normal(0, 1e-3, 6), strict=True)
    }
    tri = cert.accel
    d = tri.misalignment_differences
    for k, (plus, minus) in enumerate(MISALIGNMENT_DIFFERENCES):
        assert d[k] == tri.misalignment[plus] - tri.misalignment[minus]
        a, b = MISALIGNMENT_PAIRS["accel"][k].split("/")
        assert PAIR_KEYS[(a[1], b[1])] == (k, plus)
        faulty = apply_faults(cert, [Fault("misalignment", f"{a}/{b}", 0.0, 0.002)], 1.0)
        expected = d.copy()
        expected[k] += 0.002
        np.testing.assert_allclose(faulty.accel.misalignment_differences, expected, atol=1e-15)
    shape = np.concatenate([np.zeros(3), d])
    _, mis = n_symmetric(tri, shape)
    np.testing.assert_allclose(
        [mis[p] - mis[m] for p, m in MISALIGNMENT_DIFFERENCES], d, rtol=0, atol=1e-15
    )


@pytest.mark.parametrize("pair", ["ax/ay", "ax/az", "ay/az", "gx/gy", "gx/gz", "gy/gz"])
def test_the_simulators_fault_is_the_certificates_misalignment(pair):
    """The simulator injects a misalignment fault through the same table: noise off, a
    fault in force from t = 0 gives the outputs of the certificate with the fault applied."""
    cert = load_default()
    trajectory = multi_position(n_attitudes=4, rate_hz=50.0, seed=3)
    fault = Fault("misalignment", pair, 0.0, 0.003)
    faulty = simulate(cert, trajectory, seed=1, effects=Effects.none(), faults=[fault]).samples
    applied = apply_faults(cert, [fault], 0.0)
    clean = simulate(applied, trajectory, seed=1, effects=Effects.none()).samples
    np.testing.assert_allclose(faulty.gyro, clean.gyro, rtol=0, atol=1e-6)
    np.testing.assert_allclose(faulty.accel, clean.accel, rtol=0, atol=1e-6)


def test_skew_is_the_cross_product_for_every_consumer():
    rng = np.random.default_rng(32)
    v, u = rng.normal(size=(5, 3)), rng.normal(size=(5, 3))
    np.testing.assert_allclose(np.einsum("nij,nj->ni", skew(v), u), np.cross(v, u), atol=1e-15)


def test_one_earth_rate():
    """The simulator's trajectories and the aiding share imudiag.earth's Earth rate."""
    assert EARTH_RATE == OMEGA_E
    for lat in (-60.0, 0.0, 45.0, 89.0):
        w = earth_rate_ned(lat)
        assert np.linalg.norm(w) == pytest.approx(OMEGA_E, rel=1e-15)
        np.testing.assert_allclose(earth_rate_ned(lat, 2 * OMEGA_E), 2 * w, rtol=1e-15)

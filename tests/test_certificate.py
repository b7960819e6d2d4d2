"""Calibration certificate (spec/certificate.md): every rule names its key path, round trips
are exact, and the sensor model matches the spec's formula and inverts."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from imudiag.certificate import (
    FORMAT,
    Certificate,
    CertificateError,
    Temperature,
    default_certificate_path,
    from_dict,
    load,
    load_default,
    loads,
)

TRIAD_REQUIRED = (
    "input_unit",
    "output_unit",
    "scale_factor",
    "scale_factor_error",
    "bias",
    "misalignment",
    "limits",
)
MISALIGNMENT_KEYS = ("xz", "xy", "yz", "yx", "zy", "zx")
LIMIT_KEYS = ("f0", "bias", "scale_factor_error", "misalignment")


@pytest.fixture
def doc() -> dict[str, Any]:
    """The bundled certificate as a plain YAML document (safe to modify)."""
    return yaml.safe_load(default_certificate_path().read_text())


def error_for(doc: dict[str, Any]) -> CertificateError:
    """The error of loading ``doc`` written out as real YAML text."""
    with pytest.raises(CertificateError) as info:
        loads(yaml.safe_dump(doc, sort_keys=False), source="cert.yaml")
    assert info.value.source == "cert.yaml"
    assert str(info.value).startswith(f"cert.yaml: {info.value.key}: ")
    return info.value


def error_for_text(text: str) -> CertificateError:
    with pytest.raises(CertificateError) as info:
        loads(text, source="cert.yaml")
    return info.value


def set_path(doc: dict[str, Any], path: str, value: Any) -> None:
    """Set ``a.b.c`` or ``a.b[2]`` in ``doc``; value ``...`` deletes the key."""
    *parents, last = path.split(".")
    node: Any = doc
    for p in parents:
        node = node[p]
    if last.endswith("]"):
        name, index = last[:-1].split("[")
        node[name][int(index)] = value
    elif value is ...:
        del node[last]
    else:
        node[last] = value


# ---------------------------------------------------------------------------
# rules: each names the key path


@pytest.mark.parametrize(
    "path",
    [
        "colour",
        "gyro.bias_error",
        "accel.limits.noise",
        "gyro.misalignment.xx",
        "environment.speed_of_light",
        "gyro.noise.density_x",
        "accel.temperature.slope",
    ],
)
def test_unknown_key(doc: dict[str, Any], path: str) -> None:
    doc["accel"]["temperature"] = {"reference": 20.0}
    set_path(doc, path, 1.0)
    err = error_for(doc)
    assert (err.key, err.reason) == (path, "unknown key")


@pytest.mark.parametrize("value", ["imudiag-certificate/2", "imu-cert/1", 1, None])
def test_wrong_format(doc: dict[str, Any], value: Any) -> None:
    doc["format"] = value
    err = error_for(doc)
    assert err.key == "format" and FORMAT in err.reason


REQUIRED_PATHS = (
    ["format", "device", "environment", "sample_rate", "gyro", "accel"]
    + ["environment.gravity", "environment.earth_rate"]
    + [f"{t}.{k}" for t in ("gyro", "accel") for k in TRIAD_REQUIRED]
    + [f"{t}.misalignment.{k}" for t in ("gyro", "accel") for k in MISALIGNMENT_KEYS]
    + [f"{t}.limits.{k}" for t in ("gyro", "accel") for k in LIMIT_KEYS]
)


@pytest.mark.parametrize("path", REQUIRED_PATHS)
def test_missing_required_key(doc: dict[str, Any], path: str) -> None:
    set_path(doc, path, ...)
    err = error_for(doc)
    assert (err.key, err.reason) == (path, "missing required key")


@pytest.mark.parametrize(
    ("path", "value", "key", "reason"),
    [
        ("gyro.scale_factor", [65.5, 65.5], "gyro.scale_factor", "expected 3 values, got 2"),
        ("accel.bias", [1.0, 2.0, 3.0, 4.0], "accel.bias", "expected 3 values, got 4"),
        ("accel.limits.bias", [1.0], "accel.limits.bias", "expected 3 values, got 1"),
        ("gyro.limits.misalignment", 0.005, "gyro.limits.misalignment", "expected a list"),
        ("gyro.noise.density", [1.0, 1.0], "gyro.noise.density", "expected 3 values"),
        ("gyro.nonlinearity", [0.1, 0.2], "gyro.nonlinearity", "expected 3 values"),
        ("gyro.g_sensitivity", [[0, 0, 0], [0, 0, 0]], "gyro.g_sensitivity", "3 rows"),
        (
            "gyro.g_sensitivity",
            [[0, 0, 0], [0, 0], [0, 0, 0]],
            "gyro.g_sensitivity[1]",
            "expected 3 values, got 2",
        ),
        (
            "accel.temperature",
            {"bias_coefficient": [0.1]},
            "accel.temperature.bias_coefficient",
            "expected 3 values, got 1",
        ),
    ],
)
def test_wrong_length(doc: dict[str, Any], path: str, value: Any, key: str, reason: str) -> None:
    set_path(doc, path, value)
    err = error_for(doc)
    assert err.key == key and reason in err.reason


@pytest.mark.parametrize("literal", [".nan", ".inf", "-.inf", ".NaN", ".Inf"])
@pytest.mark.parametrize(
    "path",
    [
        "accel.limits.bias[2]",
        "gyro.bias[0]",
        "gyro.scale_factor[1]",
        "accel.scale_factor_error[2]",
        "gyro.misalignment.zy",
        "accel.limits.f0",
        "gyro.noise.density[1]",
        "environment.gravity",
        "environment.earth_rate",
        "sample_rate",
        "gyro.g_sensitivity[2][1]",
        "accel.temperature.reference",
        "accel.nonlinearity[0]",
    ],
)
def test_non_finite(doc: dict[str, Any], path: str, literal: str) -> None:
    doc["gyro"]["g_sensitivity"] = [[0.0] * 3 for _ in range(3)]
    doc["accel"]["temperature"] = {"reference": 25.0}
    doc["accel"]["nonlinearity"] = [0.0, 0.0, 0.0]
    if path.startswith("gyro.g_sensitivity"):
        doc["gyro"]["g_sensitivity"][2][1] = "@@"
    else:
        set_path(doc, path, "@@")
    text = yaml.safe_dump(doc, sort_keys=False).replace("'@@'", literal)
    assert math.isnan(yaml.safe_load(f"x: {literal}")["x"]) or literal.endswith(("inf", "Inf"))
    err = error_for_text(text)
    assert err.key == path and "not a finite number" in err.reason


@pytest.mark.parametrize(
    ("path", "value"),
    [
        ("gyro.scale_factor[1]", 0.0),
        ("gyro.scale_factor[0]", -65.5),
        ("accel.scale_factor[2]", -1e-300),
    ],
)
def test_non_positive_scale_factor(doc: dict[str, Any], path: str, value: float) -> None:
    set_path(doc, path, value)
    err = error_for(doc)
    assert err.key == path and "must be > 0" in err.reason


@pytest.mark.parametrize(
    ("triad", "value"),
    [
        ("gyro", "rad/h"),
        ("gyro", "m/s^2"),
        ("accel", "deg/s"),
        ("accel", "G"),
        ("accel", ["g"]),
        ("gyro", None),
    ],
)
def test_bad_input_unit(doc: dict[str, Any], triad: str, value: Any) -> None:
    doc[triad]["input_unit"] = value
    err = error_for(doc)
    assert err.key == f"{triad}.input_unit" and "must be" in err.reason


@pytest.mark.parametrize(
    ("path", "value", "reason"),
    [
        ("gyro.bias[1]", "32683", "expected a number"),
        ("accel.limits.f0", True, "expected a number"),
        ("gyro.misalignment", [0.0] * 6, "expected a mapping"),
        ("accel", "none", "expected a mapping"),
        ("gyro.output_unit", "", "expected text"),
        ("accel.limits.scale_factor_error[0]", 0.0, "must be > 0"),
        ("gyro.noise.bias_random_walk[2]", -0.1, "must be >= 0"),
        ("environment.gravity", -9.8, "must be > 0"),
    ],
)
def test_wrong_type_or_range(doc: dict[str, Any], path: str, value: Any, reason: str) -> None:
    set_path(doc, path, value)
    err = error_for(doc)
    assert err.key == path and reason in err.reason


def test_g_sensitivity_only_on_the_gyro(doc: dict[str, Any]) -> None:
    doc["accel"]["g_sensitivity"] = [[0.0] * 3] * 3
    assert error_for(doc).key == "accel.g_sensitivity"


def test_bad_yaml_names_the_line() -> None:
    text = default_certificate_path().read_text().splitlines()
    row = next(i for i, s in enumerate(text) if s.startswith("  bias: [32888.0"))
    text[row] = "  bias: [32888.0, 32683.0, 32808.0"  # unclosed flow sequence
    err = error_for_text("\n".join(text) + "\n")
    assert err.key == f"line {row + 2}" and "not valid YAML" in err.reason
    err = error_for_text("format: imudiag-certificate/1\ndevice: {}\n\tgyro: 1\n")
    assert err.key == "line 3" and err.source == "cert.yaml"
    assert error_for_text("").key == "(document)"
    assert error_for_text("- just\n- a list\n").key == "(document)"


def test_unreadable_file_names_the_file(tmp_path: Path) -> None:
    cases: dict[Path, str] = {
        tmp_path / "missing.yaml": "cannot read",
        tmp_path: "cannot read",  # a directory
    }
    latin = tmp_path / "latin1.yaml"
    latin.write_bytes(b"format: imudiag-certificate/1\ndevice: {model: caf\xe9}\n")
    cases[latin] = "not UTF-8"
    for path, reason in cases.items():
        with pytest.raises(CertificateError) as info:
            load(path)
        assert info.value.source == str(path) and reason in info.value.reason
        assert str(path) in str(info.value)


def test_error_in_a_file_names_file_and_key(tmp_path: Path, doc: dict[str, Any]) -> None:
    doc["accel"]["limits"]["bias"][2] = float("nan")
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(CertificateError) as info:
        load(path)
    assert str(info.value) == f"{path}: accel.limits.bias[2]: not a finite number: nan"


# ---------------------------------------------------------------------------
# round trip


def extended(cert: Certificate, seed: int = 0) -> Certificate:
    """``cert`` with full-precision random extended blocks on both triads."""
    rng = np.random.default_rng(seed)
    c = cert.copy()
    for t in (c.gyro, c.accel):
        t.temperature = Temperature(
            reference=float(rng.uniform(15, 35)),
            bias_coefficient=rng.normal(0, 0.5, 3),
            scale_coefficient=rng.normal(0, 1e-4, 3),
        )
        t.nonlinearity = rng.normal(0, 1e-4, 3)
        t.scale_factor = t.scale_factor * (1 + rng.normal(0, 1e-3, 3))
        t.bias = t.bias + rng.normal(0, 1, 3)
        t.misalignment = {k: float(rng.normal(0, 1e-3)) for k in MISALIGNMENT_KEYS}
    c.gyro.g_sensitivity = rng.normal(0, 0.05, (3, 3))
    c.gravity = 9.80665 + float(rng.normal(0, 1e-3))
    c.sample_rate = 204.8
    return c


def assert_same_numbers(a: Certificate, b: Certificate) -> None:
    assert a.to_dict() == b.to_dict()  # every number, exactly (floats compare by value)
    for name in ("gyro", "accel"):
        ta, tb = a.triad(name), b.triad(name)
        for field in (
            "scale_factor",
            "scale_factor_error",
            "bias",
            "nonlinearity",
            "g_sensitivity",
        ):
            va, vb = getattr(ta, field), getattr(tb, field)
            assert (va is None and vb is None) or np.array_equal(va, vb)
        assert np.array_equal(ta.n_matrix(), tb.n_matrix())


def test_round_trip_default(tmp_path: Path, default_certificate: Certificate) -> None:
    path = tmp_path / "c.yaml"
    default_certificate.save(path)
    back = load(path)
    assert_same_numbers(default_certificate, back)
    assert back.device == default_certificate.device and back.source == str(path)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_round_trip_extended(tmp_path: Path, default_certificate: Certificate, seed: int) -> None:
    cert = extended(default_certificate, seed)
    path = tmp_path / "ext.yaml"
    cert.save(path)
    back = load(path)
    assert_same_numbers(cert, back)
    assert np.array_equal(
        back.gyro.temperature.scale_coefficient, cert.gyro.temperature.scale_coefficient
    )
    assert back.gyro.temperature.reference == cert.gyro.temperature.reference
    assert back.sample_rate == 204.8
    assert back.dumps() == cert.dumps()  # writing again gives the same text
    raw = yaml.safe_load(path.read_text())
    assert raw["format"] == FORMAT and "g_sensitivity" not in raw["accel"]


# ---------------------------------------------------------------------------
# the sensor model


def hand_certificate(doc: dict[str, Any]) -> Certificate:
    """Gyro with simple numbers for the hand-computed example."""
    g = doc["gyro"]
    g["input_unit"] = "rad/s"
    g["scale_factor"] = [2.0, 4.0, 5.0]
    g["scale_factor_error"] = [0.2, -0.4, 0.5]  # e = (0.1, -0.1, 0.1)
    g["bias"] = [10.0, 20.0, 30.0]
    g["misalignment"] = {"xz": 0.01, "xy": 0.02, "yz": 0.03, "yx": 0.04, "zy": 0.05, "zx": 0.06}
    return from_dict(doc)


def test_forward_matches_the_spec_formula_by_hand(doc: dict[str, Any]) -> None:
    g = hand_certificate(doc).gyro
    # N = [[1.1, 0.01, -0.02], [-0.03, 0.9, 0.04], [0.05, -0.06, 1.1]]
    np.testing.assert_allclose(
        g.n_matrix(), [[1.1, 0.01, -0.02], [-0.03, 0.9, 0.04], [0.05, -0.06, 1.1]], atol=1e-15
    )
    # x = (1, 2, 3) rad/s: N x = (1.1 + 0.02 - 0.06, -0.03 + 1.8 + 0.12, 0.05 - 0.12 + 3.3)
    #                          = (1.06, 1.89, 3.23)
    # U = B + S * N x = (10 + 2 * 1.06, 20 + 4 * 1.89, 30 + 5 * 3.23) = (12.12, 27.56, 46.15)
    u = g.forward(np.array([[1.0, 2.0, 3.0]]))
    np.testing.assert_allclose(u[0], [12.12, 27.56, 46.15], rtol=0, atol=1e-12)
    # d1 = D_xz - D_yz, d2 = D_zy - D_xy, d3 = D_yx - D_zx
    np.testing.assert_allclose(g.misalignment_differences, [-0.02, 0.03, -0.02], atol=1e-15)
    np.testing.assert_allclose(g.relative_scale_error, [0.1, -0.1, 0.1], atol=1e-15)
    # the same in deg/s: x in deg/s is (1, 2, 3) * 180 / pi
    g.input_unit = "deg/s"
    u_si = g.forward_si(np.array([[1.0, 2.0, 3.0]]) * math.pi / 180.0)
    np.testing.assert_allclose(u_si[0], [12.12, 27.56, 46.15], rtol=0, atol=1e-12)


def test_forward_extended_blocks_by_hand(doc: dict[str, Any]) -> None:
    doc["gyro"]["temperature"] = {
        "reference": 25.0,
        "bias_coefficient": [0.1, 0.0, 0.0],
        "scale_coefficient": [0.01, 0, 0],
    }
    doc["gyro"]["nonlinearity"] = [0.5, 0.0, 0.0]
    doc["gyro"]["g_sensitivity"] = [[0.0, 0.0, 0.3], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]
    g = hand_certificate(doc).gyro
    # at 35 degC: B_x = 10 + 0.1 * 10 = 11, S_x = 2 * (1 + 0.01 * 10) = 2.2;
    # U_x = 11 + 2.2 * 1.06 + 0.5 * 1.06^2 + 0.3 * a_z = 11 + 2.332 + 0.5618 + 0.3 = 14.1938
    u = g.forward(np.array([[1.0, 2.0, 3.0]]), temp_c=35.0, accel_input=np.array([[0, 0, 1.0]]))
    np.testing.assert_allclose(u[0], [14.1938, 27.56, 46.15], rtol=0, atol=1e-12)


@pytest.mark.parametrize("with_extended", [False, True])
@pytest.mark.parametrize("triad", ["gyro", "accel"])
def test_forward_and_inverse_are_inverse(
    default_certificate: Certificate, with_extended: bool, triad: str
) -> None:
    cert = extended(default_certificate, seed=7) if with_extended else default_certificate
    t = cert.triad(triad)
    rng = np.random.default_rng(11)
    n = 20_000
    full_scale = 300.0 if triad == "gyro" else 2 * 9.80665  # deg/s, m/s^2
    x = rng.uniform(-full_scale, full_scale, (n, 3))
    kw: dict[str, Any] = {}
    if with_extended:
        kw = {"temp_c": rng.uniform(-40.0, 85.0, n), "accel_input": rng.normal(0, 9.8, (n, 3))}
    u = t.forward(x, **kw)
    np.testing.assert_allclose(t.inverse(u, **kw), x, rtol=0, atol=1e-9)
    np.testing.assert_allclose(t.forward(t.inverse(u, **kw), **kw), u, rtol=1e-13, atol=0)
    x_si = x * t.unit_to_si
    np.testing.assert_allclose(t.inverse_si(t.forward_si(x_si, **kw), **kw), x_si, atol=1e-9)


def test_inverse_with_a_strong_nonlinearity(default_certificate: Certificate) -> None:
    """The nonlinear inverse is exact, not a truncated iteration."""
    g = default_certificate.gyro
    g.nonlinearity = np.array([2e-3, -2e-3, 1e-3])  # counts/(deg/s)^2: 180 counts at 300 deg/s
    x = np.random.default_rng(3).uniform(-300, 300, (5000, 3))
    np.testing.assert_allclose(g.inverse(g.forward(x)), x, rtol=0, atol=1e-9)


def test_default_certificate_loads() -> None:
    cert = load_default()
    assert cert.source == str(default_certificate_path())
    assert (cert.gyro.input_unit, cert.accel.input_unit) == ("deg/s", "m/s^2")
    assert cert.gyro.output_unit == cert.accel.output_unit == "count"
    np.testing.assert_array_equal(cert.gyro.scale_factor, [65.52, 65.31, 65.74])
    np.testing.assert_array_equal(cert.accel.bias, [33078.0, 32518.0, 32888.0])
    assert cert.sample_rate == 200.0 and cert.gravity == 9.80665
    assert cert.gyro.noise is not None and cert.gyro.limits.f0 == 0.01
    assert cert.device["serial"] == "0001"
    # at rest, level, the accelerometer reads gravity on z and the model inverts to it
    u = cert.accel.forward_si(np.array([[0.0, 0.0, cert.gravity]]))
    np.testing.assert_allclose(np.linalg.norm(cert.accel.inverse_si(u)), cert.gravity)


@pytest.mark.parametrize("path", ["gyro.scale_factor[0]", "accel.scale_factor[2]"])
def test_value_in_a_message_is_plain(doc: dict[str, Any], path: str) -> None:
    """Issue 12 item 7: the message shows the value as written, never numpy's repr."""
    set_path(doc, path, -65.52)
    err = error_for(doc)
    assert err.key == path and err.reason == "must be > 0, got -65.52"
    assert "np." not in str(err)

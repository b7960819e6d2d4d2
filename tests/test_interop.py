"""Issue 11 item 3: calibration interop with imu_tk, imucal, Kalibr and iKalibr, both ways.

Files in tests/data/interop (SOURCE.md there): the tools' own example files where they ship
one, else files written exactly as the tool's writer writes them. Each import is checked
against the tool's own model equations (written out here from the tool's source), each
export-import round trip to float precision, and the acceptance path on the real Xsens
recording through real subprocesses: calibrate, export to imu_tk, import, diagnose. The other
command cases (refusals, the iKalibr frame rotation, the CLI import of each tool's file but
Kalibr's) run the command's entry point in this process (``conftest.run_imudiag_in_process``).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import run_imudiag, run_imudiag_in_process, run_imudiag_without

from imudiag import interop
from imudiag.certificate import Certificate, Noise, load, load_default
from imudiag.diagnosis.gauge import polar
from imudiag.rotations import quat_matrix

DATA = Path(__file__).parent / "data"
IO = DATA / "interop"
XSENS = DATA / "real" / "xsens-mti-multiposition" / "session.csv.gz"
LIKE_XSENS = DATA / "diagnosis" / "like-xsens.yaml"
LIKE_SI = IO / "like-si.yaml"

#: relative agreement of a round trip: float precision of the forward matrix
ROUND_TRIP_RTOL = 1e-13

rng = np.random.default_rng(2026_11_25)
#: physical inputs (SI) to compare models on: 20 specific forces (m/s^2), 20 rates (rad/s)
F_SI = rng.normal(scale=9.8, size=(20, 3))
W_SI = rng.normal(scale=2.0, size=(20, 3))


def _forward_si(cert: Certificate, name: str, x_si: np.ndarray, a_si: np.ndarray | None = None):
    """Raw outputs of a certificate triad for SI inputs (g-sensitivity with ``a_si``)."""
    t = cert.triad(name)
    acc_in = None if a_si is None else a_si / cert.accel.unit_to_si
    return t.forward_si(x_si, accel_input=acc_in)


def _matrix(cert: Certificate, name: str) -> np.ndarray:
    t = cert.triad(name)
    return t.scale_factor[:, None] * t.n_matrix()


def _symmetric_cert() -> Certificate:
    """A certificate in the gauge imudiag calibrate writes (accelerometer N symmetric) with
    a gyro frame rotation, a g-sensitivity and per-axis noise equal in SI (Kalibr's one
    figure per triad)."""
    cert = load(LIKE_XSENS)
    acc, gyr = cert.accel, cert.gyro
    acc.scale_factor_error = np.array([1.3, -0.7, 0.4])
    acc.bias = acc.bias + np.array([5.0, -3.0, 2.0])
    d = {"xz": 0.0011, "yz": -0.0011, "zy": -0.0024, "xy": 0.0024, "yx": 0.0007, "zx": -0.0007}
    acc.misalignment = d
    gyr.scale_factor_error = np.array([-9.0, 14.0, 3.0])
    gyr.misalignment = {
        "xz": 0.004,
        "yz": -0.002,
        "zy": 0.003,
        "xy": -0.001,
        "yx": 0.006,
        "zx": 0.0,
    }
    gyr.g_sensitivity = np.array([[0.5, -0.2, 0.1], [0.0, 0.3, -0.4], [0.2, 0.1, -0.6]])
    for t, density, walk in ((acc, 0.00849, 2e-4), (gyr, 0.00057, 4e-6)):
        gain = np.linalg.norm(_matrix(cert, t.name), axis=1) / t.unit_to_si  # count per SI unit
        t.noise = Noise(density=density * gain, bias_random_walk=walk * gain)
    return cert


def _export_import(fmt: str, cert: Certificate, tmp: Path, gauge: str = "symmetric"):
    out = tmp / ("x" if fmt == "imu_tk" else f"x.{fmt}")
    interop.write(fmt, cert, str(out))
    ic = interop.read(fmt, str(out))
    back, prov = interop.to_certificate(ic, cert, gauge=gauge)
    return back, prov


@pytest.mark.parametrize("fmt", interop.FORMATS)
def test_round_trip_of_a_calibrate_gauge_certificate(fmt, tmp_path):
    cert = _symmetric_cert()
    back, prov = _export_import(fmt, cert, tmp_path)
    for name in ("accel", "gyro"):
        m, mb = _matrix(cert, name), _matrix(back, name)
        assert np.abs(mb - m).max() <= ROUND_TRIP_RTOL * np.abs(m).max(), (fmt, name)
        assert back.triad(name).scale_factor.tolist() == cert.triad(name).scale_factor.tolist()
        if fmt != "kalibr":  # Kalibr writes no biases: they come from --like, here the same
            assert prov.fields[f"{name}.bias"] == "file"
        np.testing.assert_allclose(back.triad(name).bias, cert.triad(name).bias, rtol=1e-15)
    if fmt in ("imucal", "kalibr"):  # the formats with a g-sensitivity
        g, gb = cert.gyro.g_sensitivity, back.gyro.g_sensitivity
        assert prov.fields["gyro.g_sensitivity"] == "file"
        assert np.abs(gb - g).max() <= ROUND_TRIP_RTOL * np.abs(g).max()
    if fmt == "kalibr":  # the format with noise
        for name in ("accel", "gyro"):
            nb, n = back.triad(name).noise, cert.triad(name).noise
            assert prov.fields[f"{name}.noise.density"] == "file"
            np.testing.assert_allclose(nb.density, n.density, rtol=1e-12)
            np.testing.assert_allclose(nb.bias_random_walk, n.bias_random_walk, rtol=1e-12)
        assert back.sample_rate == cert.sample_rate


@pytest.mark.parametrize("fmt", ["imu_tk", "imucal"])
def test_tool_gauge_keeps_every_field_of_a_general_certificate(fmt, tmp_path):
    """imu_tk's and imucal's files hold a general 3x3: with --gauge tool the certificate's own
    fields come back (the bundled certificate's N is neither symmetric nor triangular)."""
    cert = load_default()
    back, _ = _export_import(fmt, cert, tmp_path, gauge="tool")
    for name in ("accel", "gyro"):
        t, tb = cert.triad(name), back.triad(name)
        np.testing.assert_allclose(tb.scale_factor_error, t.scale_factor_error, atol=1e-12)
        for k, v in t.misalignment.items():
            assert tb.misalignment[k] == pytest.approx(v, abs=1e-15), (name, k)
        np.testing.assert_array_equal(tb.bias, t.bias)


@pytest.mark.parametrize("fmt", ["kalibr", "ikalibr"])
def test_triangular_formats_lose_only_a_frame_rotation_and_say_so(fmt, tmp_path):
    """Kalibr and iKalibr estimate a triangular accelerometer matrix: a general certificate
    comes back turned by one rotation of both triads (the same N N^T, what the scalar method
    sees), and the export says how far."""
    cert = load_default()
    for name in ("accel", "gyro"):
        cert.triad(name).noise = Noise(
            density=np.full(3, 1.0) * cert.triad(name).scale_factor,
            bias_random_walk=np.full(3, 0.01) * cert.triad(name).scale_factor,
        )
    out = tmp_path / f"x.{fmt}"
    _, notes = interop.write(fmt, cert, str(out))
    assert any("re-framed by" in n for n in notes)
    back, _ = interop.to_certificate(interop.read(fmt, str(out)), cert, gauge="tool")
    ma, mab = _matrix(cert, "accel"), _matrix(back, "accel")
    q = np.linalg.solve(mab, ma)  # ma = mab q
    np.testing.assert_allclose(q @ q.T, np.eye(3), atol=1e-12)
    mg, mgb = _matrix(cert, "gyro"), _matrix(back, "gyro")
    np.testing.assert_allclose(mgb @ q, mg, rtol=0, atol=1e-12 * np.abs(mg).max())
    # the observable shape (P of the polar decomposition) is unchanged
    for m, mb in ((ma, mab), (mg, mgb)):
        np.testing.assert_allclose(polar(mb)[0], polar(m)[0], atol=1e-12 * np.abs(m).max())


def test_imucal_example_file_maps_onto_imucal_model():
    """imucal's own snapshot: the certificate's forward model, run through imucal's
    calibrate equations, gives back the physical inputs."""
    doc = json.loads((IO / "imucal_example_cal.json").read_text())
    k_a, r_a, b_a = (np.array(doc[k]) for k in ("K_a", "R_a", "b_a"))
    k_g, r_g, k_ga, b_g = (np.array(doc[k]) for k in ("K_g", "R_g", "K_ga", "b_g"))
    ic = interop.read("imucal", str(IO / "imucal_example_cal.json"))
    cert, prov = interop.to_certificate(ic, load_default(), gauge="tool")
    assert cert.accel.output_unit == "a.u." and prov.fields["accel.output_unit"] == "file"
    acc_in = F_SI / cert.accel.unit_to_si
    gyr_deg = np.degrees(W_SI)  # imucal's gyr_unit deg/s
    a_raw = cert.accel.forward(acc_in)
    g_raw = cert.gyro.forward(W_SI / cert.gyro.unit_to_si, accel_input=acc_in)
    # imucal: a = R_a^-1 K_a^-1 (a_raw - b_a); g = R_g^-1 K_g^-1 (g_raw - K_ga a - b_g)
    a = (np.linalg.inv(r_a) @ np.linalg.inv(k_a) @ (a_raw - b_a).T).T
    g = (np.linalg.inv(r_g) @ np.linalg.inv(k_g) @ (g_raw - (k_ga @ a.T).T - b_g).T).T
    np.testing.assert_allclose(a, F_SI, atol=1e-9)
    np.testing.assert_allclose(g, gyr_deg, atol=1e-9)
    # the gyro axes of this sensor are inverted (R_g near -I): kept, not refused
    assert np.all(np.diag(cert.gyro.n_matrix()) < 0)


def test_imucal_hdf5_round_trip(tmp_path):
    pytest.importorskip("h5py")
    cert = _symmetric_cert()
    out = tmp_path / "cal.h5"
    interop.write("imucal", cert, str(out))
    back, prov = interop.to_certificate(interop.read("imucal", str(out)), cert)
    for name in ("accel", "gyro"):
        m, mb = _matrix(cert, name), _matrix(back, name)
        assert np.abs(mb - m).max() <= ROUND_TRIP_RTOL * np.abs(m).max()
    assert prov.fields["accel.output_unit"] == "file"


def test_imucal_hdf5_without_h5py_names_the_pip_command(tmp_path):
    out = tmp_path / "cal.h5"
    r = run_imudiag_without(
        "h5py", "certificate", "export", str(LIKE_XSENS), "--format", "imucal", "--out", str(out)
    )
    assert r.returncode == 2, r.stderr
    assert "pip install 'imudiag[mat]'" in r.stderr
    assert not out.exists()


def test_imu_tk_file_maps_onto_imu_tk_model():
    """Files as CalibratedTriad::save writes them (6 digits): X' = T K (X - B) inverts the
    certificate's forward model."""
    prefix = IO / "imu_tk_xsens"
    ic = interop.read("imu_tk", str(prefix))
    cert, prov = interop.to_certificate(ic, load(LIKE_XSENS), gauge="tool")
    assert prov.fields["accel.scale_factor"] == "like"  # same units as the like: S kept
    for name, suffix, x in (("accel", "_acc.calib", F_SI), ("gyro", "_gyro.calib", W_SI)):
        nums = np.array((Path(str(prefix) + suffix)).read_text().split(), dtype=float)
        t, k, b = nums[:9].reshape(3, 3), nums[9:18].reshape(3, 3), nums[18:]
        raw = _forward_si(cert, name, x)
        np.testing.assert_allclose((t @ k @ (raw - b).T).T, x, atol=1e-9)
        np.testing.assert_array_equal(cert.triad(name).bias, b)


def test_imu_tk_pair_named_by_prefix_either_file_or_options(tmp_path):
    prefix = IO / "imu_tk_xsens"
    want = interop.read("imu_tk", str(prefix))
    for path in (f"{prefix}_acc.calib", f"{prefix}_gyro.calib"):
        got = interop.read("imu_tk", path)
        np.testing.assert_array_equal(got.accel.matrix, want.accel.matrix)
        np.testing.assert_array_equal(got.gyro.bias, want.gyro.bias)
    out = tmp_path / "c.yaml"
    # in process: the acceptance test below imports an imu_tk pair as a real subprocess
    r = run_imudiag_in_process(
        "certificate", "import", "--format", "imu_tk", "--accel", f"{prefix}_acc.calib",
        "--gyro", f"{prefix}_gyro.calib", "--like", str(LIKE_XSENS), "--out", str(out),
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    np.testing.assert_array_equal(load(out).gyro.bias, want.gyro.bias)


def test_exported_files_have_the_tools_own_keys(tmp_path):
    """imucal: the keys of its own snapshot, in its order; Kalibr: the imu.yaml keys at the
    top level, where its ImuParameters reads them."""
    cert = _symmetric_cert()
    interop.write("imucal", cert, str(tmp_path / "c.json"))
    ours = list(json.loads((tmp_path / "c.json").read_text()))
    assert ours == list(json.loads((IO / "imucal_example_cal.json").read_text()))
    interop.write("kalibr", cert, str(tmp_path / "imu.yaml"))
    doc = yaml.safe_load((tmp_path / "imu.yaml").read_text())
    example = yaml.safe_load((IO / "kalibr_imu_adis16448.yaml").read_text())
    assert set(example) <= set(doc)
    assert doc["model"] == "scale-misalignment"
    assert np.allclose(np.triu(doc["accelerometers"]["M"], 1), 0.0)  # lower triangular


def test_imu_tk_symmetric_gauge_reports_the_rotation_it_takes():
    ic = interop.read("imu_tk", str(IO / "imu_tk_xsens"))
    cert, prov = interop.to_certificate(ic, load(LIKE_XSENS), gauge="symmetric")
    n = cert.accel.n_matrix()
    np.testing.assert_allclose(n, n.T, atol=1e-15)
    note = next(n for n in prov.notes if n.startswith("gauge symmetric"))
    # the imu_tk accelerometer T is triangular: the rotation is half the misalignment pairs
    angle = float(note.split("turned by ")[1].split(" rad")[0])
    assert 1e-3 < angle < 2e-2
    # the observable shape is the tool's
    tool, _ = interop.to_certificate(ic, load(LIKE_XSENS), gauge="tool")
    np.testing.assert_allclose(polar(n)[0], polar(tool.accel.n_matrix())[0], atol=1e-14)


def test_kalibr_example_imu_yaml_maps_noise_with_units():
    """The ADIS16448 example: noise only. The certificate's one-sided density is sqrt(2)
    Kalibr's (per-sample sigma = n sqrt(rate/2) = sigma_c sqrt(rate)), in output units."""
    ic = interop.read("kalibr", str(IO / "kalibr_imu_adis16448.yaml"))
    like = load_default()  # counts, gyro in deg/s
    cert, prov = interop.to_certificate(ic, like)
    s_a = like.accel.scale_factor  # count per m/s^2
    np.testing.assert_allclose(cert.accel.noise.density, math.sqrt(2) * 0.006 * s_a)
    np.testing.assert_allclose(cert.accel.noise.bias_random_walk, 0.0002 * s_a)
    s_g = like.gyro.scale_factor / like.gyro.unit_to_si  # count per rad/s
    np.testing.assert_allclose(cert.gyro.noise.density, math.sqrt(2) * 0.0004 * s_g)
    np.testing.assert_allclose(cert.gyro.noise.bias_random_walk, 4.0e-06 * s_g)
    assert cert.sample_rate == 200.0 and prov.fields["sample_rate"] == "file"
    # per-sample sigma at 200 Hz equals Kalibr's discrete sigma_c / sqrt(dt)
    np.testing.assert_allclose(cert.accel.noise_sigma(200.0), 0.006 * math.sqrt(200.0) * s_a)
    for key in ("scale_factor_error", "misalignment", "bias"):
        assert prov.fields[f"accel.{key}"] == "like"


def test_kalibr_results_file_maps_onto_kalibr_model():
    """<bag>-imu.yaml as Kalibr writes it: w_meas = M_g C_gyro_i w + A C_gyro_i a + b."""
    doc = yaml.safe_load((IO / "kalibr_results-imu.yaml").read_text())["imu0"]
    m_a = np.array(doc["accelerometers"]["M"])
    m_g, a_g, c = (np.array(doc["gyroscopes"][k]) for k in ("M", "A", "C_gyro_i"))
    ic = interop.read("kalibr", str(IO / "kalibr_results-imu.yaml"))
    cert, prov = interop.to_certificate(ic, load(LIKE_SI), gauge="tool")
    assert prov.fields["accel.bias"] == "like"  # Kalibr writes no biases
    np.testing.assert_allclose(_forward_si(cert, "accel", F_SI), F_SI @ m_a.T, atol=1e-12)
    want = W_SI @ (m_g @ c).T + F_SI @ (a_g @ c).T
    np.testing.assert_allclose(_forward_si(cert, "gyro", W_SI, F_SI), want, atol=1e-12)


def test_kalibr_noise_only_file_with_an_si_like():
    ic = interop.read("kalibr", str(IO / "kalibr_imu_adis16448.yaml"))
    cert, _ = interop.to_certificate(ic, load(LIKE_SI))
    np.testing.assert_allclose(cert.gyro.noise.density, [math.sqrt(2) * 0.0004] * 3)


def test_ikalibr_example_and_model(tmp_path):
    """iKalibr's own file (identity maps, biases in SI) and one written by the writer with
    non-trivial maps: f_meas = Map_a f + b_a, w_meas = Map_g R_AtoG w + b_g."""
    ic = interop.read("ikalibr", str(IO / "ikalibr_imu1-intri.yaml"))
    cert, prov = interop.to_certificate(ic, load(LIKE_SI))
    np.testing.assert_allclose(
        cert.accel.bias, [-0.01048774201847276, -0.004952661434900924, -0.01523462203863955]
    )
    np.testing.assert_allclose(_matrix(cert, "gyro"), np.eye(3), atol=1e-15)
    assert prov.fields["gyro.bias"] == "file"
    doc = yaml.safe_load((IO / "ikalibr_imu1-intri.yaml").read_text())
    data = doc["Intrinsics"]["ptr_wrapper"]["data"]
    coeff_a = [1.002, 0.997, 1.004, 0.0031, -0.0012, 0.0022]
    coeff_g = [0.998, 1.003, 1.001, -0.0021, 0.0008, 0.0015]
    data["ACCE"]["MAP_COEFF"] = {f"r{i}c0": v for i, v in enumerate(coeff_a)}
    data["GYRO"]["MAP_COEFF"] = {f"r{i}c0": v for i, v in enumerate(coeff_g)}
    q = np.array([0.9999, 0.003, -0.008, 0.011])
    q = q / np.linalg.norm(q)
    data["SO3_AtoG"] = {"qx": float(q[1]), "qy": float(q[2]), "qz": float(q[3]), "qw": float(q[0])}
    path = tmp_path / "intri.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    cert, _ = interop.to_certificate(
        interop.read("ikalibr", str(path)), load(LIKE_SI), gauge="tool"
    )
    map_a = interop.ikalibr.map_matrix(np.array(coeff_a))
    map_g = interop.ikalibr.map_matrix(np.array(coeff_g))
    b_g = np.array([data["GYRO"]["BIAS"][f"r{i}c0"] for i in range(3)])
    np.testing.assert_allclose(_forward_si(cert, "accel", F_SI) - cert.accel.bias, F_SI @ map_a.T)
    want = W_SI @ (map_g @ quat_matrix(q)).T + b_g
    np.testing.assert_allclose(_forward_si(cert, "gyro", W_SI), want, atol=1e-12)


def test_like_in_other_units_rescales_what_it_gives(tmp_path):
    """An SI file with a counts like: S from the file, the like's limits and noise keep
    their size in input units, and the command says so."""
    ic = interop.read("kalibr", str(IO / "kalibr_results-imu.yaml"))
    like = load_default()
    cert, prov = interop.to_certificate(ic, like)
    assert cert.accel.output_unit == "m/s^2"
    k = cert.accel.scale_factor / like.accel.scale_factor
    np.testing.assert_allclose(cert.accel.limits.bias, like.accel.limits.bias * k)
    assert prov.fields["accel.scale_factor"] == "file"
    assert any("rescaled" in n for n in prov.notes)
    assert prov.fields["accel.bias"] == "set to 0"  # not in the file, the like's is in counts


# ---------------------------------------------------------------------------
# the command line, through real subprocesses


@pytest.fixture(scope="module")
def xsens_cal(tmp_path_factory) -> Path:
    """The real Xsens session calibrated by ``imudiag calibrate`` (a real subprocess)."""
    cal = tmp_path_factory.mktemp("interop") / "cal.yaml"
    r = run_imudiag("calibrate", str(XSENS), "--like", str(LIKE_XSENS), "--out", str(cal))
    assert r.returncode == 0, r.stderr
    return cal


def _diagnose_verdict(cert: Path, tmp: Path, run=run_imudiag) -> dict:
    """The verdict of ``imudiag diagnose`` of the Xsens session with ``cert``, run by ``run``
    (a real subprocess unless told)."""
    report = tmp / "diag.json"
    r = run("diagnose", str(XSENS), "--certificate", str(cert), "--json", str(report))
    assert r.returncode == 0, r.stderr
    return json.loads(report.read_text())["verdict"]


def test_acceptance_calibrate_export_imu_tk_import_diagnose_real_xsens(xsens_cal, tmp_path):
    cal = xsens_cal
    prefix = tmp_path / "xsens"
    r = run_imudiag("certificate", "export", str(cal), "--format", "imu_tk", "--out", str(prefix))
    assert r.returncode == 0, r.stderr
    acc = Path(f"{prefix}_acc.calib")
    nums = np.array(acc.read_text().split(), dtype=float)
    assert nums.size == 21 and nums[0] == 1.0  # T with a unit diagonal, as imu_tk's
    back = tmp_path / "back.yaml"
    r = run_imudiag(
        "certificate", "import", str(prefix), "--format", "imu_tk", "--like", str(cal),
        "--out", str(back),
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    lines = {ln.strip().split(": ")[0]: ln for ln in r.stdout.splitlines()}
    from_file = lines[f"from {prefix}_acc.calib + {prefix}_gyro.calib"]
    assert "accel.misalignment" in from_file and "gyro.bias" in from_file
    assert "accel.limits" in lines[f"from {cal}"]
    a, b = load(cal), load(back)
    for name in ("accel", "gyro"):
        m, mb = _matrix(a, name), _matrix(b, name)
        assert np.abs(mb - m).max() <= ROUND_TRIP_RTOL * np.abs(m).max()
    verdict = _diagnose_verdict(back, tmp_path)
    assert verdict["accel"] == "ok" and verdict["gyro"] == "ok"
    assert verdict["faults"] == []


def test_a_frame_rotation_kept_by_gauge_tool_changes_no_verdict(xsens_cal, tmp_path):
    """Through iKalibr (triangular: both triads re-framed, 11.8 mrad) and back with --gauge
    tool, the certificate holds the rotation; the diagnosis sees only P: still no fault."""
    out = tmp_path / "intri.yaml"
    r = run_imudiag_in_process(
        "certificate", "export", str(xsens_cal), "--format", "ikalibr", "--out", str(out)
    )
    assert r.returncode == 0, r.stderr
    assert "re-framed by 1.1" in r.stdout
    back = tmp_path / "back.yaml"
    r = run_imudiag_in_process(
        "certificate", "import", str(out), "--format", "ikalibr", "--like", str(xsens_cal),
        "--gauge", "tool", "--out", str(back),
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    n, n_cal = load(back).accel.n_matrix(), load(xsens_cal).accel.n_matrix()
    assert np.abs(n - n.T).max() > 1e-3  # not the symmetric gauge: the rotation is in N
    np.testing.assert_allclose(n @ n.T, n_cal @ n_cal.T, atol=1e-13)
    # in process: the acceptance test above diagnoses as a real subprocess
    verdict = _diagnose_verdict(back, tmp_path, run_imudiag_in_process)
    assert (verdict["accel"], verdict["gyro"], verdict["faults"]) == ("ok", "ok", [])


@pytest.mark.parametrize("fmt", ["imucal", "kalibr", "ikalibr"])
def test_cli_import_of_each_tool_file(fmt, tmp_path):
    src = {
        "imucal": IO / "imucal_example_cal.json",
        "kalibr": IO / "kalibr_results-imu.yaml",
        "ikalibr": IO / "ikalibr_imu1-intri.yaml",
    }[fmt]
    out = tmp_path / "c.yaml"
    # one format as a real subprocess, the others through cli.main in this process
    run = run_imudiag if fmt == "kalibr" else run_imudiag_in_process
    r = run(
        "certificate", "import", str(src), "--format", fmt, "--like", str(LIKE_SI), "--out",
        str(out),
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert f"from {src}:" in r.stdout and f"from {LIKE_SI}:" in r.stdout
    assert load(out).device["calibrated"].startswith(f"imported from {fmt}")


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def _imu_tk_pair(tmp: Path, acc_text: str) -> Path:
    _write(tmp / "bad_acc.calib", acc_text)
    (tmp / "bad_gyro.calib").write_text((IO / "imu_tk_xsens_gyro.calib").read_text())
    return tmp / "bad"


GOOD_ACC = (IO / "imu_tk_xsens_acc.calib").read_text()


@pytest.mark.parametrize(
    "case, text, needle",
    [
        ("missing K", GOOD_ACC.split("\n\n")[0] + "\n", "bad_acc.calib: K: missing"),
        (
            "T not 3x3",
            "1 0\n0 1\n\n" + "\n\n".join(GOOD_ACC.split("\n\n")[1:]),
            "T: expected a 3x3",
        ),
        (
            "singular T",
            "1 0 0\n1 0 0\n0 0 1\n\n" + "\n\n".join(GOOD_ACC.split("\n\n")[1:]),
            "T: singular",
        ),
        ("not a number", GOOD_ACC.replace("-0.00172796", "abc"), "line 1: T: not a number"),
    ],
)
def test_bad_imu_tk_files_exit_2_naming_file_and_key(case, text, needle, tmp_path):
    prefix = _imu_tk_pair(tmp_path, text)
    out = tmp_path / "c.yaml"
    r = run_imudiag_in_process(
        "certificate", "import", str(prefix), "--format", "imu_tk", "--out", str(out)
    )
    assert r.returncode == 2, (case, r.stderr)
    assert needle in r.stderr and str(tmp_path / "bad_acc.calib") in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    assert not out.exists()


def _bad_imucal(tmp: Path) -> Path:
    doc = json.loads((IO / "imucal_example_cal.json").read_text())
    del doc["K_g"]
    return _write(tmp / "bad.json", json.dumps(doc))


def _bad_kalibr(tmp: Path) -> Path:
    doc = yaml.safe_load((IO / "kalibr_results-imu.yaml").read_text())
    doc["imu0"]["accelerometers"]["M"] = [[1.0, 0.0], [0.0, 1.0]]
    return _write(tmp / "bad.yaml", yaml.dump(doc))


def _bad_ikalibr(tmp: Path) -> Path:
    text = (IO / "ikalibr_imu1-intri.yaml").read_text()
    return _write(tmp / "bad.yaml", text.replace("          r5c0: 0\n      GYRO", "      GYRO"))


@pytest.mark.parametrize(
    "fmt, make, needle",
    [
        ("imucal", _bad_imucal, "K_g: missing required key"),
        ("kalibr", _bad_kalibr, "imu0.accelerometers.M: expected a 3x3 matrix, got 2x2"),
        ("ikalibr", _bad_ikalibr, "Intrinsics.ptr_wrapper.data.ACCE.MAP_COEFF.r5c0: missing"),
    ],
)
def test_bad_tool_files_exit_2_naming_file_and_key(fmt, make, needle, tmp_path):
    src = make(tmp_path)
    out = tmp_path / "c.yaml"
    r = run_imudiag_in_process(
        "certificate", "import", str(src), "--format", fmt, "--out", str(out)
    )
    assert r.returncode == 2, r.stderr
    assert f"{src}: {needle}" in r.stderr, r.stderr
    assert not out.exists()


def test_export_never_overwrites_its_input(tmp_path):
    cert = tmp_path / "c.yaml"
    cert.write_text(LIKE_XSENS.read_text())
    r = run_imudiag("certificate", "export", str(cert), "--format", "kalibr", "--out", str(cert))
    assert r.returncode == 2 and "refusing to overwrite an input" in r.stderr
    assert cert.read_text() == LIKE_XSENS.read_text()
    prefix = tmp_path / "p"
    acc = tmp_path / "p_acc.calib"
    acc.write_text(GOOD_ACC)
    (tmp_path / "p_gyro.calib").write_text((IO / "imu_tk_xsens_gyro.calib").read_text())
    # the export's refusal above is the real subprocess; the import's in process
    r = run_imudiag_in_process(
        "certificate", "import", str(prefix), "--format", "imu_tk", "--out", str(acc)
    )
    assert r.returncode == 2 and "refusing to overwrite an input" in r.stderr
    assert acc.read_text() == GOOD_ACC


def test_kalibr_export_without_noise_says_what_is_missing(tmp_path):
    out = tmp_path / "imu.yaml"
    # in process: test_export_never_overwrites_its_input refuses an export in a subprocess
    r = run_imudiag_in_process(
        "certificate", "export", str(LIKE_XSENS), "--format", "kalibr", "--out", str(out)
    )
    assert r.returncode == 2
    assert "accel.noise.density: missing, and Kalibr's imu.yaml needs it" in r.stderr
    assert not out.exists()

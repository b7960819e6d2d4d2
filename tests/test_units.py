"""Physical units convert exactly, in one place (imudiag/units.py); counts never do.

Issue 27 item 4: a header-less table in ms, g and deg/s stated with ``--units`` against a
certificate in m/s^2 and deg/s was refused ("they must match"); g = 9.80665 m/s^2 by
definition, so the same session must give the same diagnosis in either unit.
"""

from __future__ import annotations

import gzip
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import run_imudiag_in_process

from imudiag.certificate import load as load_certificate
from imudiag.errors import BadInput
from imudiag.samples import SampleBlock
from imudiag.units import NO_CONVERSION, canonical, conform, factor, units_of

DATA = Path(__file__).parent / "data"
IMUCAL = DATA / "real" / "imucal-ferraris" / "session.csv.gz"
LIKE_IMUCAL = DATA / "diagnosis" / "like-imucal.yaml"


def test_factors_are_exact_and_invert() -> None:
    assert factor("accel", "g", "m/s^2") == 9.80665
    assert factor("accel", "mg", "g") == pytest.approx(1e-3, rel=1e-15)
    assert factor("gyro", "deg/s", "rad/s") == math.pi / 180.0
    assert factor("gyro", "mrad/s", "rad/s") == 1e-3
    for triad in ("gyro", "accel"):
        units = [u for u in units_of(triad) if u != "count"]
        for a in units:
            for b in units:
                assert factor(triad, a, b) * factor(triad, b, a) == pytest.approx(1.0, rel=1e-15)


def test_aliases_and_counts() -> None:
    assert canonical("m/s2") == "m/s^2" and canonical("dps") == "deg/s"
    assert canonical("counts") == "count" and canonical(" G ") == "g"
    with pytest.raises(BadInput, match="cannot be converted"):
        factor("gyro", "count", "rad/s")
    with pytest.raises(BadInput, match="cannot be converted"):
        factor("accel", "g", "rad/s")


def test_conform_converts_blocks_and_refuses_counts() -> None:
    cert = load_certificate(LIKE_IMUCAL)  # deg/s and m/s^2
    assert conform({}, cert, "x") is NO_CONVERSION or conform({}, cert, "x").identity
    conv = conform({"accel": "g", "gyro": "rad/s"}, cert, "log.txt")
    block = SampleBlock(
        t=np.array([0.0, 0.01]),
        gyro=np.array([[math.pi, 0.0, 0.0], [0.0, 0.0, 0.0]]),
        accel=np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]]),
    )
    out = conv.apply(block)
    assert out.accel[0, 2] == 9.80665 and out.accel[1, 2] == -9.80665
    assert out.gyro[0, 0] == pytest.approx(180.0, rel=1e-15)
    assert block.accel[0, 2] == 1.0  # the input is not changed in place
    assert {d["triad"]: (d["from"], d["to"]) for d in conv.describe()} == {
        "accel": ("g", "m/s^2"),
        "gyro": ("rad/s", "deg/s"),
    }
    with pytest.raises(BadInput) as err:
        conform({"gyro": "count"}, cert, "log.txt")
    assert "log.txt" in str(err.value) and "'count'" in str(err.value)
    assert "output_unit is 'deg/s'" in str(err.value)


def _diagnose(args: list[str], out: Path, in_process: bool = False) -> dict:
    """The report of ``imudiag diagnose ARGS`` (a real subprocess unless ``in_process``)."""
    argv = ["diagnose", *args, "--json", str(out), "--quiet"]
    if in_process:
        r = run_imudiag_in_process(*argv)
    else:
        r = subprocess.run([sys.executable, "-m", "imudiag", *argv], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    return json.loads(out.read_text())


def test_headerless_table_in_ms_g_degs_diagnoses_as_the_si_log(tmp_path: Path) -> None:
    """The real imucal session, written again as a header-less table (t in ms, accel in g)."""
    with gzip.open(IMUCAL, "rt") as fh:
        rows = [ln for ln in fh if ln.strip() and not ln.startswith("#")][1:]
    table = np.array([[float(v) for v in ln.split(",")[:7]] for ln in rows])
    table[:, 0] *= 1e3  # s -> ms
    table[:, 4:7] /= 9.80665  # m/s^2 -> g
    txt = tmp_path / "imu.txt"
    np.savetxt(txt, table, fmt="%.17g", delimiter=" ")
    si = _diagnose([str(IMUCAL), "--certificate", str(LIKE_IMUCAL)], tmp_path / "si.json")
    # the SI log is the real subprocess; the table in g and ms in process
    g = _diagnose(
        [
            str(txt),
            "--certificate",
            str(LIKE_IMUCAL),
            "--columns",
            "t,gx,gy,gz,ax,ay,az",
            "--time-unit",
            "ms",
            "--units",
            "accel=g,gyro=deg/s",
        ],
        tmp_path / "g.json",
        in_process=True,
    )
    assert g["unit_conversion"] == [
        {"triad": "accel", "from": "g", "to": "m/s^2", "factor": 9.80665}
    ]
    assert "unit_conversion" not in si
    assert g["verdict"]["accel"] == si["verdict"]["accel"]
    assert g["verdict"]["gyro"] == si["verdict"]["gyro"]
    assert [(f["sensor"], f["cause"]) for f in g["verdict"]["faults"]] == [
        (f["sensor"], f["cause"]) for f in si["verdict"]["faults"]
    ]
    assert g["f0"] == si["f0"]
    assert len(g["windows"]) == len(si["windows"])


def test_model_check_converts_and_refuses_like_diagnose() -> None:
    """The model check reads logs through the same conversion (it had no unit check)."""
    from imudiag.modelcheck import model_check

    cert = load_certificate(LIKE_IMUCAL)  # deg/s and m/s^2
    n = 200
    block = SampleBlock(
        t=np.arange(n) / 100.0,
        gyro=np.zeros((n, 3)),
        accel=np.tile([0.0, 0.0, 1.0], (n, 1)),
        meta={"units": "gyro=deg/s accel=g"},
    )
    report = model_check(block, cert).report
    assert report["unit_conversion"] == [
        {"triad": "accel", "from": "g", "to": "m/s^2", "factor": 9.80665}
    ]
    block.meta["units"] = "gyro=count accel=g"
    with pytest.raises(BadInput, match="output_unit is 'deg/s'"):
        model_check(block, cert)

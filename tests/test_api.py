"""The library API (docs/api.md): every example in the document runs as written, the
public names resolve, and the functions give what the commands give."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from importlib import resources
from pathlib import Path

import pytest

import imudiag
from imudiag.logs import open_writer
from imudiag.sim import Fault, multi_position, simulate

DOC = Path(__file__).resolve().parents[1] / "docs" / "api.md"
EXAMPLES = re.findall(r"```python\n(.*?)```", DOC.read_text(), flags=re.S)


def test_the_document_has_examples():
    assert len(EXAMPLES) >= 4
    for code in EXAMPLES:
        assert "assert " in code  # each example checks what it shows


@pytest.mark.parametrize("index", range(len(EXAMPLES)))
def test_example_runs_as_written(index, tmp_path):
    r = subprocess.run(
        [sys.executable, "-c", EXAMPLES[index]],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, f"example {index + 1} of docs/api.md failed:\n{r.stderr}"
    assert r.stdout.strip()  # and printed what it says


def test_public_names_resolve_and_are_listed():
    for name in imudiag.__all__:
        assert getattr(imudiag, name) is not None, name
    assert set(imudiag.__all__) <= set(dir(imudiag))
    assert set(imudiag.__all__) == {"__version__", *imudiag._API}
    with pytest.raises(AttributeError, match="no attribute 'Monitr'"):
        imudiag.Monitr  # noqa: B018


def test_import_is_cheap():
    """``import imudiag`` loads no numpy: the names are imported on first use."""
    code = "import sys, imudiag; print(sorted(m for m in ('numpy', 'yaml') if m in sys.modules))"
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert r.stdout.strip() == "[]"


def test_package_is_typed():
    assert resources.files("imudiag").joinpath("py.typed").is_file()


def test_diagnose_on_a_log_is_the_command(tmp_path, imudiag_cli):
    """imudiag.diagnose on a log file gives the report `imudiag diagnose --json` writes."""
    cert = imudiag.load_certificate()
    motion = multi_position(n_attitudes=14, dwell_s=3.0, turn_s=1.5, rate_hz=200, seed=3)
    lim = cert.gyro.limits.bias[0]
    sim = simulate(cert, motion, seed=4, faults=[Fault("bias", "gx", 0.0, 5 * lim)])
    log = tmp_path / "session.npz"
    with open_writer(log, {"sample_rate": 200.0, "units": "gyro=count accel=count"}) as w:
        w.write(sim.samples)
    out = tmp_path / "report.json"
    r = imudiag_cli("diagnose", str(log), "--json", str(out))
    assert r.returncode == 0, r.stderr
    from_command = json.loads(out.read_text())
    from_library = json.loads(json.dumps(imudiag.diagnose(log)))
    assert from_library == from_command
    assert [(f["sensor"], f["cause"]) for f in from_library["verdict"]["faults"]][:1] == [
        ("gx", "bias")
    ]


def test_bad_config_names_the_field():
    cert = imudiag.load_certificate()
    block = imudiag.SampleBlock(t=[0.0, 0.005], gyro=[[0, 0, 0]] * 2, accel=[[0, 0, 0]] * 2)
    with pytest.raises(imudiag.BadInput, match="config: .*method"):
        imudiag.diagnose(block, cert, config={"method": "quadratic"})

"""Issue 12 item 1: one YAML loader for certificates, the daemon configuration and bench
scenarios: duplicate keys refused with both lines, a size cap checked before reading."""

from __future__ import annotations

import time
from pathlib import Path

import pytest
from conftest import run_imudiag_in_process

from imudiag import yamlio
from imudiag.bench.scenario import ScenarioError
from imudiag.bench.scenario import loads as scenario_loads
from imudiag.certificate import CertificateError, load
from imudiag.service.config import ConfigError, loads_config

CERT = Path(__file__).parent.parent / "config" / "default-certificate.yaml"


def _with_second_bias(text: str) -> tuple[str, int]:
    lines = text.splitlines()
    i = next(k for k, ln in enumerate(lines) if ln.startswith("accel:"))
    j = next(k for k in range(i, len(lines)) if lines[k].strip().startswith("bias:"))
    lines.insert(j + 1, "  bias: [0, 0, 0]")
    return "\n".join(lines) + "\n", j + 2


def test_a_duplicated_certificate_key_is_refused_with_both_lines(tmp_path):
    text, line = _with_second_bias(CERT.read_text())
    bad = tmp_path / "dup.yaml"
    bad.write_text(text)
    with pytest.raises(CertificateError) as exc:
        load(bad)
    msg = str(exc.value)
    assert str(bad) in msg and f"line {line}" in msg and "duplicate key 'bias'" in msg
    # in process: diagnose refuses a bad certificate in a real subprocess in test_diagnosis_cli.py
    r = run_imudiag_in_process(
        "diagnose",
        str(Path(__file__).parent / "data" / "real" / "imucal-ferraris" / "session.csv.gz"),
        "--certificate",
        str(bad),
    )
    assert r.returncode == 2 and "duplicate key 'bias'" in r.stderr


def test_every_file_kind_uses_the_same_rules():
    with pytest.raises(ConfigError, match="duplicate key 'source'"):
        loads_config("source: sim://\nsource: sim://static\n", "c.yaml")
    with pytest.raises(ScenarioError, match="duplicate key 'name'"):
        scenario_loads("format: imudiag-bench-scenario/1\nname: a\nname: b\n", "s.yaml")
    with pytest.raises(yamlio.YamlError, match="line 2"):
        yamlio.parse("a: 1\na: 2\n")


def test_an_oversized_file_is_refused_before_it_is_parsed(tmp_path):
    big = tmp_path / "big.yaml"
    text = (
        CERT.read_text()
        + "extra:\n"
        + "".join(f"  k{i}: [1.0, 2.0, 3.0]\n" for i in range(200_000))
    )
    big.write_text(text)  # about 5 MB of keys: minutes for PyYAML
    t0 = time.process_time()
    with pytest.raises(CertificateError, match="larger than"):
        load(big)
    assert time.process_time() - t0 < 1.0  # refused from its size, not parsed
    with pytest.raises(yamlio.YamlError, match="larger than"):
        yamlio.parse(text)

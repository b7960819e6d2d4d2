"""The model check's gain convention (issue 13 item 4), on a real recording through the
command line: every entry of ``gain`` is extended / baseline of the error measure it is
named for, on held-out data (below 1 better); a likelihood improvement is only ever
``heldout_loglik_gain_nats`` (nats, above 0 better); no other key says "gain"."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from conftest import REAL_DATA_DIR, run_imudiag_in_process

from imudiag.modelcheck.extend import GAIN_DEFINITION, HELDOUT_LOGLIK_KEY

MC_DATA = Path(__file__).parent / "data" / "modelcheck"
METRICS = ("residual_rms", "rotation_rms", "f0_false_alarm_rate", "allan_misfit")


def _keys_with_gain(obj: Any, path: str = "") -> list[tuple[str, str]]:
    """(path, key) of every key of the report that contains 'gain'."""
    found: list[tuple[str, str]] = []
    if isinstance(obj, dict):
        for k, v in obj.items():
            if "gain" in k:
                found.append((path, k))
            found += _keys_with_gain(v, f"{path}.{k}")
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            found += _keys_with_gain(v, f"{path}[{i}]")
    return found


def test_every_gain_is_extended_over_baseline_of_its_measure(tmp_path: Path) -> None:
    out = tmp_path / "xsens.json"
    # in process: model-check writes its report in a real subprocess in test_modelcheck.py
    r = run_imudiag_in_process(
        "model-check",
        str(REAL_DATA_DIR / "xsens-mti-multiposition" / "session.csv.gz"),
        "--certificate",
        str(MC_DATA / "xsens-mti.yaml"),
        "--json",
        str(out),
    )
    assert r.returncode == 0, r.stderr
    rep = json.loads(out.read_text())
    assert rep["evaluation"]["gain"] == GAIN_DEFINITION
    assert set(rep["gain"]) <= set(METRICS) and set(rep["gain"]) == set(rep["baseline"])
    checked = 0
    for metric, by_triad in rep["gain"].items():
        for triad, g in by_triad.items():
            base, ext = rep["baseline"][metric][triad], rep["extended"][metric][triad]
            if g is None:
                assert base is None or ext is None or base == 0, (metric, triad)
                continue
            if base == 0 and ext == 0:  # e.g. no false alarm either way: no change
                assert g == 1.0, (metric, triad)
                continue
            assert g == pytest.approx(ext / base, rel=1e-4), (metric, triad)
            checked += 1
    # the g-sensitivity the recording shows lowers the gyro residual (below 1 is better)
    assert rep["gain"]["residual_rms"]["gyro"] < 0.6 and checked >= 5
    # "gain" names only the block of ratios and the likelihood improvement's own key
    for path, key in _keys_with_gain(rep):
        allowed = (path, key) in (("", "gain"), (".evaluation", "gain"))  # ratios, definition
        assert allowed or key == HELDOUT_LOGLIK_KEY, (path, key)
        if key == HELDOUT_LOGLIK_KEY:
            assert not path.startswith(".gain")
    assert all(HELDOUT_LOGLIK_KEY in e for e in rep["effects"])
    assert all(e[HELDOUT_LOGLIK_KEY] > 0 for e in rep["effects"])
    # the console names each gain for its measure
    lines = [ln for ln in r.stdout.splitlines() if ln.startswith("gain")]
    assert lines and all(ln.split()[1].rstrip(":") in METRICS for ln in lines)

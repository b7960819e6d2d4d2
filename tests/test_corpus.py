"""The regression corpus (tests/data/corpus): each real file's summary checked against its
golden summary, made by the format's independent reader (pymavlink's DFReader, pyulog,
Python's csv module), and ``imudiag diagnose`` run on every file without error. A file a
user reads with options (a tool's own CSV export: ``--columns``, ``--units``,
``--time-unit``) states them in its golden summary (``options``); the independent reader
then finds its columns by their header names (``independent``)."""

from __future__ import annotations

import csv
import gzip
import json
from pathlib import Path

import numpy as np
import pytest
import pyulog
from pymavlink import DFReader

from imudiag.cli import main
from imudiag.logs import LogOptions, open_log, read_log
from imudiag.samples import SampleBlock

CORPUS = Path(__file__).parent / "data" / "corpus"
GOLDEN = {p: json.loads((p / "golden.json").read_text()) for p in CORPUS.iterdir() if p.is_dir()}
CASES = [
    (folder, (folder / name).resolve(), summary)
    for folder, golden in sorted(GOLDEN.items())
    for name, summary in golden["files"].items()
]


def _summary(t, g, a):
    return {
        "samples": len(t),
        "first": [t[0], *g[0], *a[0]],
        "last": [t[-1], *g[-1], *a[-1]],
        "rate_hz": round(float(1 / np.median(np.diff(t))), 3),
    }


def _independent(folder: Path, path: Path, golden: dict) -> dict:
    if "independent" in golden:  # a tool's own export: the columns by their header names
        how = golden["independent"]
        with path.open(newline="") as fh:
            lines = [ln for ln in fh if not (how.get("comment") and ln.startswith(how["comment"]))]
        rows = list(csv.DictReader(lines, delimiter=how.get("delimiter", ",")))
        m = np.array([[float(r[c]) for c in how["columns"]] for r in rows])
        if "time" in how:
            t = np.array([float(r[how["time"]]) * how["time_scale"] for r in rows])
        else:  # no time column: the rate the tool states
            t = np.arange(len(rows)) / how["rate_hz"]
        return _summary(t, m[:, 0:3], m[:, 3:6])
    if path.name.endswith(".csv.gz"):
        with gzip.open(path, "rt") as fh:
            rows = list(csv.reader(line for line in fh if not line.startswith("#")))
        cols = [rows[0].index(c) for c in ("t", "gx", "gy", "gz", "ax", "ay", "az")]
        m = np.array([[float(r[i]) for i in cols] for r in rows[1:]])
        return _summary(m[:, 0], m[:, 1:4], m[:, 4:7])
    if folder.name == "pymavlink":
        log = DFReader.DFReader_binary(str(path), zero_time_base=True)
        rows = []
        while (m := log.recv_match(type="IMU")) is not None:
            if int(getattr(m, "I", 0)) == 0:
                rows.append((m.TimeUS * 1e-6, m.GyrX, m.GyrY, m.GyrZ, m.AccX, m.AccY, m.AccZ))
        log.close()
        r = np.asarray(rows)
        return _summary(r[:, 0], r[:, 1:4], r[:, 4:7])
    u = pyulog.ULog(str(path), message_name_filter_list=["sensor_combined"])
    d = u.get_dataset("sensor_combined").data
    t = (d["timestamp"].astype(np.int64) - u.start_timestamp) * 1e-6
    g = np.column_stack([d[f"gyro_rad[{k}]"] for k in range(3)]).astype(float)
    a = np.column_stack([d[f"accelerometer_m_s2[{k}]"] for k in range(3)]).astype(float)
    return _summary(t, g, a)


def _same(got: dict, want: dict) -> None:
    assert got["samples"] == want["samples"]
    np.testing.assert_allclose(got["first"], want["first"], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(got["last"], want["last"], rtol=1e-12, atol=1e-12)
    assert got["rate_hz"] == pytest.approx(want["rate_hz"], rel=1e-6)


@pytest.mark.parametrize(
    ("folder", "path", "golden"), CASES, ids=lambda c: c.name if isinstance(c, Path) else ""
)
def test_corpus_file_matches_its_golden_summary_and_diagnoses(folder, path, golden, tmp_path):
    assert (folder / "SOURCE.md").is_file()
    _same(_independent(folder, path, golden), golden)
    opts = golden.get("options", {})
    if opts:
        options = LogOptions(
            columns=opts["columns"].split(",") if "columns" in opts else None,
            units=dict(kv.split("=") for kv in opts["units"].split(",")),
            time_unit=opts.get("time_unit"),
            rate=float(opts["rate"]) if "rate" in opts else None,
        )
        with open_log(path, options=options) as reader:
            b = SampleBlock.concat(list(reader))
    else:
        b = read_log(path)
    _same(_summary(b.t, b.gyro, b.accel), golden)
    out = tmp_path / "d.json"
    cert = (folder / GOLDEN[folder]["certificate"]).resolve()
    args = ["diagnose", str(path), "-c", str(cert), "--json", str(out), "-q", "--no-windows"]
    args += [a for k, v in opts.items() for a in (f"--{k.replace('_', '-')}", v)]
    assert main(args) == 0
    assert json.loads(out.read_text())["samples"] == golden["samples"]

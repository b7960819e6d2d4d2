"""The sample time at which a verdict or a fault came in force, as the status states it
(``diagnosis.since``, every fault's ``t_first``): the daemon feeds its window diagnosis on
a fixed sample-time grid, so the same samples give the same verdicts at the same sample
times however the reads cut the stream (how fast the daemon keeps up)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from imudiag.certificate import load_default
from imudiag.drivers.wire import encode_samples
from imudiag.service.daemon import Daemon
from imudiag.service.status import diagnosis_verdict
from tests.device_sessions import FAULT_T_S, session_samples, settings
from tests.helpers import CollectSink


def test_diagnosis_object_says_since_when_each_verdict_holds() -> None:
    fault = {"triad": "accel", "sensor": "ax", "cause": "bias"}
    view = diagnosis_verdict([fault], ["gyro"], 1, {"accel": 12.3456789, "gyro": None})
    assert view == {
        "accel": "fault",
        "gyro": "undetermined",
        "raised": 1,
        "since": {"accel": 12.345679, "gyro": None},  # s, to the microsecond
    }


def _session_file(tmp_path: Path) -> Path:
    """The device tests' multi-position session (tests/device_sessions.py: +5-limit ax bias
    at FAULT_T_S) as a native wire capture."""
    block = session_samples(load_default())
    raw = np.rint(np.hstack([block.gyro, block.accel]))
    path = tmp_path / "session.bin"
    path.write_bytes(encode_samples(1, np.rint(block.t * 1e6), raw))
    return path


def _run(path: Path, step_s: float) -> list[dict[str, Any]]:
    sink = CollectSink()
    Daemon(settings(f"replay://{path}?speed=0&step={step_s}", None), [sink]).run()
    return sink.lines


def _in_force(lines: list[dict[str, Any]]) -> tuple[set[tuple[str, float]], set[tuple]]:
    """Every (triad verdict, since) and (fault, t_first) the status lines stated."""
    verdicts: set[tuple[str, float]] = set()
    faults: set[tuple] = set()
    for s in lines:
        d = s.get("diagnosis") or {}
        for triad in ("accel", "gyro"):
            if d.get("since", {}).get(triad) is not None:
                verdicts.add((f"{triad} {d[triad]}", d["since"][triad]))
                assert d["since"][triad] <= s["t"]  # in force by the line's last sample
        for f in s["faults"]:
            faults.add((f["triad"], f["sensor"], f["cause"], f["t_first"]))
            assert f["t_first"] is not None and f["t_first"] <= s["t"]
    return verdicts, faults


def test_verdict_and_fault_times_do_not_depend_on_how_the_reads_cut_the_stream(
    tmp_path: Path,
) -> None:
    path = _session_file(tmp_path)
    fine = _in_force(_run(path, 0.013))  # reads of 2-3 samples: a daemon keeping up
    coarse = _in_force(_run(path, 0.71))  # reads of 142 samples: a daemon behind
    assert fine == coarse
    verdicts, faults = fine
    oks = [t for v, t in verdicts if v.endswith(" ok")]
    assert oks and max(oks) < FAULT_T_S  # both triads judged ok before the bias
    named = [t for triad, sensor, cause, t in faults if (triad, sensor, cause)[2] == "bias"]
    assert ("accel", "ax", "bias") in {f[:3] for f in faults}
    assert min(named) >= FAULT_T_S

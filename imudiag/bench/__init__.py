"""Hardware-in-loop bench: the daemon as a real subprocess against the simulated board.

``imudiag bench`` (docs/bench.md) plays a scenario (:mod:`.scenario`) through a
pty (:mod:`.feeder`, :mod:`.transport`), collects the daemon's status lines
(:mod:`.daemon_process`), for a drive with ``aiding:`` also feeds a real gpsd the
drive's GNSS stream (:mod:`.gnss`), and judges detection, latency (sample time) and
correctness per injected fault (:mod:`.evaluate`, :mod:`.table`).
"""

from .daemon_process import DaemonProcess, StatusRecord
from .runner import BenchError, BenchRun, diagnosis_available, run_bench, run_scenario
from .scenario import (
    AidingSpec,
    BenchScenario,
    Expectation,
    Injection,
    ScenarioError,
    bundled_names,
    load,
    load_bundled,
    loads,
)
from .table import format_table

__all__ = [
    "AidingSpec",
    "BenchError",
    "BenchRun",
    "BenchScenario",
    "DaemonProcess",
    "Expectation",
    "Injection",
    "ScenarioError",
    "StatusRecord",
    "bundled_names",
    "diagnosis_available",
    "format_table",
    "load",
    "load_bundled",
    "loads",
    "run_bench",
    "run_scenario",
]

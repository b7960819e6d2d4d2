"""``imudiag bench``: the hardware-in-loop bench (docs/bench.md).

Runs ``imudiag run`` as a real subprocess against the simulated board over a
pty, injects sensor and transport faults at known sample times and reports,
per fault, whether the daemon detected it, how late (sample time) and whether
it named the right triad, sensor and cause; as a table and as JSON.
"""

from __future__ import annotations

import argparse
import sys

from ..argtypes import positive_float, seed, writable_output_path
from ..atomic import write_text_atomic
from ..errors import BadInput
from ..reports import json_text


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``bench`` subcommand."""
    p = sub.add_parser(
        "bench",
        help="hardware-in-loop bench: the daemon against the simulated board with faults",
        description="Run the daemon as a subprocess against the simulated board over a pty, "
        "inject sensor faults (bias, scale_factor, misalignment, stuck, noise, dead) and "
        "transport faults (garbage, crc, lost, duplicate, unplug) at known sample times, and "
        "report detection, latency in sample time and correctness per fault.",
    )
    p.add_argument(
        "scenario",
        nargs="?",
        metavar="SCENARIO",
        help="bundled scenario name (default sensor-faults; --list shows them)",
    )
    p.add_argument(
        "--scenario",
        dest="scenario_file",
        metavar="FILE.yaml",
        help="scenario file instead of a bundled one",
    )
    p.add_argument(
        "--json",
        type=writable_output_path(stdout=True),
        metavar="OUT",
        help="write the JSON report to OUT ('-': stdout)",
    )
    p.add_argument("--seed", type=seed, help="simulation seed (overrides the scenario's)")
    p.add_argument(
        "--speed",
        type=positive_float("x real time"),
        help="board pace relative to real time (overrides the scenario's)",
    )
    p.add_argument(
        "--device",
        help="the fake device the board's samples go out as: native (default), mavlink, "
        "witmotion, isensor, iio (overrides the scenario's; docs/devices.md)",
    )
    p.add_argument(
        "--no-diagnosis", action="store_true", help="run the daemon with per-sample checks only"
    )
    p.add_argument(
        "--strict",
        action="store_true",
        help="exit 1 when a checked expectation fails (default: 0 whatever the verdict)",
    )
    p.add_argument("--list", action="store_true", help="list the bundled scenarios and exit")
    p.set_defaults(inputs=("scenario_file",), outputs=("json",))
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run one bench scenario; print the table, write the JSON report."""
    from ..bench import BenchError, bundled_names, format_table, load, load_bundled, run_bench

    if args.list:
        for name in bundled_names():
            scenario = load_bundled(name)
            print(f"{name}: {scenario.description.splitlines()[0] if scenario.description else ''}")
        return 0
    if args.scenario and args.scenario_file:
        raise BadInput("give a bundled SCENARIO name or --scenario FILE, not both")
    scenario = (
        load(args.scenario_file)
        if args.scenario_file
        else load_bundled(args.scenario or "sensor-faults")
    )
    scenario = scenario.with_options(seed=args.seed, speed=args.speed, device=args.device)
    try:
        report = run_bench(scenario, diagnosis=False if args.no_diagnosis else None)
    except BenchError as exc:
        print(f"imudiag bench: {exc}", file=sys.stderr)
        return 1
    table = format_table(report)
    text = json_text(report, indent=2)
    if args.json == "-":
        print(table, file=sys.stderr)
        print(text)
    else:
        print(table)
        if args.json:
            try:
                write_text_atomic(args.json, text + "\n")
            except OSError as exc:
                raise BadInput(f"--json {args.json}: cannot write: {exc.strerror or exc}") from None
    return 1 if args.strict and not report["passed"] else 0

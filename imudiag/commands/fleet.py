"""``imudiag fleet PATH... --out DIR``: diagnose many logs on Dask and follow each vehicle's
parameters across its logs (docs/fleet.md). Needs the extra ``[fleet]``."""

from __future__ import annotations

import argparse
import re

from ..argtypes import nonnegative_int, positive_float, positive_int, writable_directory
from ..errors import BadInput
from ..progress import for_command


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``fleet`` subcommand."""
    from ..fleet.runner import DEFAULT_MEMORY_LIMIT, DEFAULT_RETRIES, DEFAULT_TIMEOUT_S

    p = sub.add_parser(
        "fleet",
        help="diagnose many logs on Dask, per-vehicle trends and a report to open in a browser",
        description="Diagnoses every log (files, folders searched recursively, globs) on "
        "Dask's distributed scheduler, one task per log, and follows each vehicle's "
        "parameters across its logs: the drift test, the first log beyond a limit, and the "
        "ranked units to look at. Writes DIR/logs.jsonl (one record per log, as each "
        "completes), DIR/logs.parquet, DIR/fleet.json and DIR/report.html; a run started "
        "again on the same DIR skips the logs already recorded (by content hash). Needs "
        "pip install 'imudiag[fleet]'.",
    )
    p.add_argument("paths", nargs="+", metavar="PATH", help="log files, folders or globs")
    p.add_argument(
        "--out", required=True, type=writable_directory, metavar="DIR", help="output folder"
    )
    p.add_argument(
        "--certificate",
        "-c",
        metavar="CERT",
        help="the certificate of every log, or 'auto': the bundled data-sheet certificate "
        "each log names (PX4 ULog, ArduPilot DataFlash: the flight-controller IMU class)",
    )
    p.add_argument(
        "--certificates",
        metavar="MAP",
        help="YAML mapping of vehicle to certificate file (else a certificate.yaml in the "
        "vehicle's folder, else the bundled one)",
    )
    p.add_argument(
        "--scheduler",
        metavar="URL",
        help="an existing Dask cluster (tcp://HOST:8786) that sees the same paths "
        "(default: a local cluster of this machine's cores)",
    )
    p.add_argument(
        "--workers",
        type=positive_int("workers"),
        metavar="N",
        help="local worker processes (default: this machine's cores)",
    )
    p.add_argument(
        "--memory-limit",
        default=DEFAULT_MEMORY_LIMIT,
        metavar="SIZE",
        help=f"memory of each local worker (default {DEFAULT_MEMORY_LIMIT}); a log that "
        "kills its worker is a row with the reason",
    )
    p.add_argument(
        "--timeout",
        type=positive_float("s"),
        default=DEFAULT_TIMEOUT_S,
        metavar="S",
        help=f"per-log time limit, s (default {DEFAULT_TIMEOUT_S:g})",
    )
    p.add_argument(
        "--retries",
        type=nonnegative_int("retries"),
        default=DEFAULT_RETRIES,
        metavar="N",
        help=f"times a log whose worker died is tried again (default {DEFAULT_RETRIES})",
    )
    p.add_argument("--dashboard", action="store_true", help="start Dask's dashboard (:8787)")
    p.add_argument(
        "--redo", action="store_true", help="diagnose every log again (ignore DIR/logs.jsonl)"
    )
    p.add_argument("--quiet", "-q", action="store_true", help="no progress bar")
    p.set_defaults(func=run, inputs=("certificate", "certificates"), outputs=())


#: ``--scheduler``: a Dask address, SCHEME://HOST:PORT (tcp, tls, ucx, inproc, ws, wss)
_ADDRESS = re.compile(r"^[a-z][a-z0-9+]*://[^\s:/]+:\d+$")


def check_options(args: argparse.Namespace) -> None:
    """``--memory-limit`` and ``--scheduler`` before any work; BadInput naming them."""
    from ..fleet.runner import memory_limit_bytes

    memory_limit_bytes(args.memory_limit, "--memory-limit")
    if args.scheduler and not _ADDRESS.match(args.scheduler):
        raise BadInput(
            f"--scheduler {args.scheduler!r}: expected an address such as tcp://HOST:8786"
        )


def run(args: argparse.Namespace) -> int:
    """Run the fleet and print where the results are."""
    from ..fleet.runner import REPORT, SUMMARY, require
    from ..fleet.runner import run as run_fleet
    from ..fleet.trends import label

    require()
    check_options(args)
    with for_command("fleet", args.quiet) as bar:
        records = run_fleet(
            args.paths,
            args.out,
            certificate=args.certificate,
            certificates=args.certificates,
            scheduler=args.scheduler,
            workers=args.workers,
            memory_limit=args.memory_limit,
            timeout_s=args.timeout,
            retries=args.retries,
            dashboard=args.dashboard,
            redo=args.redo,
            progress=lambda what, fraction, done: bar(what, fraction),
        )
    import json
    from pathlib import Path

    summary = json.loads((Path(args.out) / SUMMARY).read_text())
    errors = len(summary["errors"])
    print(f"{len(records)} logs, {len(records) - errors} diagnosed, {errors} errors")
    for kind in summary["error_kinds"]:  # why they failed, the commonest first
        print(f"  {kind['logs']} x {kind['reason']} (first: {kind['first']})")
    for v in summary["vehicles"]:
        if v["look_at"]:
            why = "; ".join(label(r) for r in v["reasons"])
            print(f"  LOOK AT {v['vehicle']}: {why}")
    print(f"{Path(args.out) / SUMMARY}\n{Path(args.out) / REPORT}")
    return 0

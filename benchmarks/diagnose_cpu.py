"""``python -m benchmarks.diagnose_cpu``: CPU of :func:`imudiag.diagnose` per 10^6 samples in a
warm process (imports and a first call paid before timing), on the library path users and the
fleet's per-log task run (issue 28: at most 1.0 s of CPU per 10^6 samples).

Cases (fixed seeds), each written once into a temporary folder:

- ``multiposition``: a simulated board turned through 12 attitudes (a flight of ``imudiag
  simulate fleet``), written as NPZ and diagnosed by the fleet's per-log task
  (:func:`imudiag.fleet.task.diagnose_log`, which calls :func:`imudiag.diagnose`);
- ``static``: the static cycle (8 attitudes), the same way;
- ``drive``: a moving-base drive (``urban``) with its GNSS track, the samples and the track
  passed to :func:`imudiag.diagnose` in memory (the report's ``moving_base`` section).

Options: ``--samples 1e5,1e6`` (sizes), ``--rates 100,1000`` (Hz), ``--cases`` (comma list),
``--runs CASE:RATE:SAMPLES,...`` (explicit runs instead of the product of the three;
``--runs fleet`` is issue 28's three: a 10^6-sample multi-position board log, a 20-min drive
with GNSS and a 5-min short log, all at 100 Hz),
``--kernels auto|plain|numba`` (the compiled kernels, :mod:`imudiag.kernels`: ``auto`` as a
fleet worker, the compiled ones where numba is installed), ``--repeat N`` (best of N,
default 1), ``--profile N`` (cProfile of the last run of each case, top N functions by
``--sort``, internal time).
Prints one line per case: CPU s, samples, CPU s per 10^6 samples. No assertion:
docs/benchmarks.md holds the figures.
"""

from __future__ import annotations

import argparse
import cProfile
import io
import os
import pstats
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

for _name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")  # as the command line and the fleet's workers

CASES = ("multiposition", "static", "drive")
#: ``--runs fleet``: (a) a 10^6-sample multi-position board log, (b) a 20-min moving-base drive
#: with its GNSS, (c) a 5-min short log (the fixed per-log cost), all at 100 Hz.
FLEET_RUNS = "multiposition:100:1e6,drive:100:1.2e5,multiposition:100:3e4"


def write_board_log(path: Path, kind: str, n: int, rate_hz: float, seed: int) -> Path:
    """``n`` samples of the simulated board in scenario ``kind`` at ``rate_hz``, as a log
    (one flight of ``imudiag simulate fleet``: 12 holds, or 8 for ``static``)."""
    from imudiag.certificate import load_default
    from imudiag.fleet.simulate import write_flight

    meta = {"sample_rate": rate_hz}
    write_flight(path, load_default(), kind, n / rate_hz, rate_hz, [], seed, meta)
    return path


def drive_case(n: int, rate_hz: float, seed: int) -> tuple[Any, Any]:
    """(samples, GNSS track) of a simulated urban drive of ``n`` samples at ``rate_hz``."""
    from imudiag.aiding.tpv import parse_tpv, track_from_reports
    from imudiag.certificate import load_default
    from imudiag.sim.drive import simulate_drive

    res, reports, _ = simulate_drive("urban", n / rate_hz, load_default(), seed, rate_hz)
    return res.samples, track_from_reports([parse_tpv(r) for r in reports])


def run_once(case: str, data: Any) -> tuple[float, int, dict[str, Any]]:
    """(CPU s of this thread, samples, report) of one diagnosis of ``data``."""
    import imudiag
    from imudiag.fleet.task import Job, diagnose_log

    cpu0 = time.thread_time()
    if case == "drive":
        samples, track = data
        report = imudiag.diagnose(samples, None, gnss=track)
        n = len(samples)
    else:
        st = data.stat()
        record = diagnose_log(Job(str(data), "-", st.st_size, st.st_mtime_ns, str(data.parent)))
        if record["status"] != "ok":
            raise SystemExit(f"{data}: {record['reason']}")
        report, n = record["report"], int(record["samples"])
    return time.thread_time() - cpu0, n, report


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", default="1e5,1e6", help="log sizes, comma-separated")
    ap.add_argument("--rates", default="100,1000", help="sample rates, Hz, comma-separated")
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--runs", default="", help="CASE:RATE:SAMPLES,... or 'fleet'")
    ap.add_argument("--repeat", type=int, default=1, help="best of N runs")
    ap.add_argument("--profile", type=int, default=0, help="print the top N of a cProfile")
    ap.add_argument(
        "--kernels",
        choices=("auto", "plain", "numba"),
        default="auto",
        help="compiled kernels: the fleet worker's choice (numba where installed), or forced",
    )
    ap.add_argument("--sort", default="tottime", help="cProfile order (tottime, cumulative)")
    ap.add_argument("--seed", type=int, default=5)
    args = ap.parse_args(argv)
    sizes = [int(float(s)) for s in args.samples.split(",")]
    rates = [float(r) for r in args.rates.split(",")]
    cases = args.cases.split(",")
    if args.runs:
        spec = FLEET_RUNS if args.runs == "fleet" else args.runs
        runs = [(c, float(r), int(float(n))) for c, r, n in (x.split(":") for x in spec.split(","))]
        cases = sorted({c for c, _, _ in runs})
    else:
        runs = [(c, r, n) for c in cases for r in rates for n in sizes]
    try:
        from imudiag.diagnosis import kernels
    except ImportError:  # a tree from before the kernels (a before/after comparison)
        if args.kernels == "numba":
            raise SystemExit(
                "--kernels numba: this tree has no imudiag.diagnosis.kernels"
            ) from None
        kernels = None
    if kernels is None:
        pass
    elif args.kernels == "plain":
        os.environ["IMUDIAG_KERNELS"] = "plain"  # what the fleet's warm-up reads
        kernels.enable(False)
    elif args.kernels == "numba" and not kernels.enable(True):
        raise SystemExit(f"--kernels numba: {kernels.status()}")
    elif args.kernels == "auto":  # as a fleet worker: loaded by its warm-up, used by its tasks
        from imudiag.fleet.task import _use_kernels, warm_up

        warm_up()
        kernels.enable(_use_kernels())
    print(
        f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f}, "
        f"kernels: {kernels.status() if kernels else 'plain (no kernels)'}",
        flush=True,
    )
    with tempfile.TemporaryDirectory() as tmp:
        # warm-up: imports and one small call of each path
        warm = write_board_log(Path(tmp) / "warm.npz", "multiposition", 20000, 100.0, 1)
        run_once("multiposition", warm)
        if "drive" in cases:
            run_once("drive", drive_case(20000, 100.0, 1))
        for case, rate, n in runs:
            if case == "drive":
                data: Any = drive_case(n, rate, args.seed)
            else:
                path = Path(tmp) / f"{case}-{n}-{rate:g}.npz"
                data = write_board_log(path, case, n, rate, args.seed)
            best = float("inf")
            for _ in range(max(1, args.repeat)):
                cpu, got, report = run_once(case, data)
                best = min(best, cpu)
            mb = report.get("moving_base") or {}
            print(
                f"{case:14s} {rate:6g} Hz {got:8d} samples: {best:7.3f} s CPU, "
                f"{best / got * 1e6:6.3f} s per 10^6 samples"
                + (f" (moving-base: {len(mb.get('windows') or [])} windows)" if mb else ""),
                flush=True,
            )
            if args.profile:
                prof = cProfile.Profile()
                prof.enable()
                run_once(case, data)
                prof.disable()
                s = io.StringIO()
                pstats.Stats(prof, stream=s).sort_stats(args.sort).print_stats(args.profile)
                print(s.getvalue(), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())

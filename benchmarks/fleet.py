"""Benchmark: ``imudiag fleet`` throughput on a simulated fleet, with 1 and 2 local workers.

Run: ``.venv/bin/python benchmarks/fleet.py [--logs 200] [--seconds 300:1800] [--rate 100]
[--workers 1,2] [--fleet DIR]``. Simulates ``--logs`` flights (``imudiag simulate
fleet``: 10 flights per vehicle, mixed formats and flight types, no corrupt file) of
``--seconds`` MIN:MAX each, or reuses ``--fleet DIR``, then runs
:func:`imudiag.fleet.run` on it once per worker count, each into a fresh folder, and
prints:

- logs per CPU-hour: logs / (CPU of this process, the scheduler in it and every worker
  process, from ``getrusage`` of self and reaped children), and logs per wall-hour;
- the 2-worker speed-up in wall time over 1 worker;
- per-log CPU in a warm worker per 10^6 samples: each task's own thread CPU (``cpu_s`` of
  the record) over its samples, median and total, the first task of each worker left out;
  and the median of those first tasks alone (each worker imports the diagnosis when it
  starts, :func:`imudiag.fleet.task.warm_up`, so they should cost what the others do);
- the workers' warm-up CPU (imports, the compiled kernels' load) and which window-fit loops
  the workers ran (``numba`` where the fleet extra's numba is installed, else ``plain``;
  ``IMUDIAG_KERNELS=plain`` keeps the plain ones).

Each task carries the log's path only: the worker reads the log (nothing is shipped from
the client but the path and its hash).

No assertion on any figure: docs/benchmarks.md holds the figures and the machine they
came from.
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any


def _cpu_s() -> float:
    total = 0.0
    for who in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN):
        r = resource.getrusage(who)
        total += r.ru_utime + r.ru_stime
    return total


def measure(fleet: Path, workers: int, out: Path) -> dict[str, Any]:
    """One run of the fleet on ``workers`` local workers; its figures."""
    import imudiag.fleet

    cpu0, wall0 = _cpu_s(), time.perf_counter()
    records = imudiag.fleet.run([str(fleet)], out, workers=workers, timeout_s=3600)
    wall, cpu = time.perf_counter() - wall0, _cpu_s() - cpu0
    ok = [r for r in records if r["status"] == "ok"]
    seen: set[int] = set()
    warm, first = [], []
    for r in ok:  # logs.jsonl is in completion order: each worker's first record apart
        (warm if r["worker_pid"] in seen else first).append(r)
        seen.add(r["worker_pid"])
    per_mega = [r["cpu_s"] / r["samples"] * 1e6 for r in warm if r.get("samples")]
    per_mega_first = [r["cpu_s"] / r["samples"] * 1e6 for r in first if r.get("samples")]
    samples = sum(r["samples"] for r in ok)
    return {
        "logs": len(records),
        "ok": len(ok),
        "samples": samples,
        "wall_s": wall,
        "cpu_s": cpu,
        "logs_per_cpu_hour": len(records) / cpu * 3600.0,
        "logs_per_wall_hour": len(records) / wall * 3600.0,
        "warm_cpu_per_1e6_median_s": statistics.median(per_mega) if per_mega else float("nan"),
        "first_cpu_per_1e6_median_s": (
            statistics.median(per_mega_first) if per_mega_first else float("nan")
        ),
        "warm_cpu_per_1e6_total_s": (
            sum(r["cpu_s"] for r in warm) / sum(r["samples"] for r in warm) * 1e6
            if warm
            else float("nan")
        ),
        "task_cpu_s": sum(r["cpu_s"] for r in ok),
        "warm_up_cpu_s": sum(r.get("warm_up_cpu_s") or 0.0 for r in ok),
        "kernels": ", ".join(sorted({str(r.get("kernels")) for r in ok})),
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--logs", type=int, default=200)
    p.add_argument("--seconds", default="300:1800", help="flight length range MIN:MAX, s")
    p.add_argument("--rate", type=float, default=100.0, help="sample rate, Hz")
    p.add_argument("--workers", default="1,2", help="worker counts to run, comma-separated")
    p.add_argument("--fleet", type=Path, help="reuse (or create) the simulated fleet here")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    lo, _, hi = args.seconds.partition(":")
    seconds = (float(lo), float(hi or lo))
    with tempfile.TemporaryDirectory() as tmp:
        fleet = args.fleet or Path(tmp) / "fleet"
        if not (fleet / "truth.json").exists():
            from imudiag.fleet.simulate import simulate_fleet

            flights = 10
            vehicles = max(1, -(-args.logs // flights))
            t0 = time.perf_counter()
            simulate_fleet(
                fleet,
                vehicles,
                flights,
                seed=args.seed,
                corrupt=0,
                seconds=seconds,
                rate_hz=args.rate,
            )
            print(f"simulated {vehicles * flights} logs in {time.perf_counter() - t0:.0f} s")
        print(f"fleet {fleet}: {os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f}")
        results = {}
        for n in (int(w) for w in args.workers.split(",")):
            r = measure(fleet, n, Path(tmp) / f"out-{n}")
            results[n] = r
            print(
                f"{n} worker(s): {r['logs']} logs ({r['ok']} ok, {r['samples'] / 1e6:.1f}e6 "
                f"samples), wall {r['wall_s']:.0f} s, CPU {r['cpu_s']:.0f} s "
                f"(tasks {r['task_cpu_s']:.0f} s): {r['logs_per_cpu_hour']:.0f} logs per "
                f"CPU-hour, {r['logs_per_wall_hour']:.0f} logs per wall-hour; warm worker "
                f"{r['warm_cpu_per_1e6_median_s']:.2f} s CPU per 10^6 samples (median; "
                f"{r['warm_cpu_per_1e6_total_s']:.2f} over all warm tasks; each worker's "
                f"first task {r['first_cpu_per_1e6_median_s']:.2f}); workers' warm-up "
                f"{r['warm_up_cpu_s']:.1f} s CPU; window-fit loops: {r['kernels']}",
                flush=True,
            )
        if 1 in results and 2 in results:
            print(f"2 workers / 1 worker, wall: {results[1]['wall_s'] / results[2]['wall_s']:.2f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())

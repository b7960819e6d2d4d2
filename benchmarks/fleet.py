"""Benchmark: ``imudiag fleet`` throughput on a simulated fleet, with 1 and 2 local workers.

Run: ``.venv/bin/python benchmarks/fleet.py [--logs 200] [--seconds 300:1800] [--rate 100]
[--workers 1,2] [--fleet DIR] [--repeat 3]``. Simulates ``--logs`` flights (``imudiag simulate
fleet``: 10 flights per vehicle, mixed formats and flight types, no corrupt file) of
``--seconds`` MIN:MAX each, or reuses ``--fleet DIR``, then runs ``imudiag fleet DIR --out
OUT --workers N --quiet`` on it ``--repeat`` times per worker count, each a fresh process
(as a user runs it: the interpreter's start and every import in each run's time) into a
fresh folder, and prints:

- logs per CPU-hour: logs / (CPU of the command, the Dask scheduler in it and every worker
  process and the forkserver they are forked from, from ``getrusage`` of reaped children,
  this process the reaper of their orphans), and logs per wall-hour;
- the 2-worker speed-up in wall time over 1 worker, of each pair of runs and over
  ``--repeat`` pairs (default 3; the counts alternated: a shared VM's pace drifts by 5 %
  between minutes);
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
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any


def _adopt_orphans() -> bool:
    """Make this process the reaper of its descendants' orphans (Linux's
    ``PR_SET_CHILD_SUBREAPER``): the forkserver a run's workers are forked from outlives the
    command by a moment, and its CPU (with its workers') then reaches this process's
    ``RUSAGE_CHILDREN`` once :func:`_reap_orphans` has waited for it; whether it took."""
    import ctypes
    import ctypes.util

    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        return libc.prctl(36, 1, 0, 0, 0) == 0  # PR_SET_CHILD_SUBREAPER
    except (OSError, AttributeError):
        return False


def _reap_orphans() -> None:
    """Wait for every descendant left after a command (each exits once the command's end
    closes its pipe)."""
    while True:
        try:
            os.waitpid(-1, 0)
        except ChildProcessError:
            return


def _children_cpu_s() -> float:
    """CPU of the reaped child processes and theirs (the command, its workers), s."""
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def measure(fleet: Path, workers: int, out: Path) -> dict[str, Any]:
    """One run of ``imudiag fleet`` on ``workers`` local workers, a process of its own; its
    figures."""
    from imudiag.fleet.records import read_records

    cmd = [sys.executable, "-m", "imudiag", "fleet", str(fleet), "--out", str(out)]
    cmd += ["--workers", str(workers), "--timeout", "3600", "--quiet"]
    cpu0, wall0 = _children_cpu_s(), time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True, check=False)
    wall = time.perf_counter() - wall0
    _reap_orphans()
    cpu = _children_cpu_s() - cpu0
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)}: exit {done.returncode}\n{done.stderr}")
    records = read_records(out)
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
    p.add_argument("--repeat", type=int, default=3, help="runs of each worker count, alternated")
    args = p.parse_args(argv)
    if not _adopt_orphans():
        print("(no PR_SET_CHILD_SUBREAPER here: the CPU figures miss the forked workers')")
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
        counts = [int(w) for w in args.workers.split(",")]
        walls: dict[int, list[float]] = {n: [] for n in counts}
        for rep in range(args.repeat):  # the worker counts alternated, each run fresh
            for n in counts:
                out = Path(tmp) / f"out-{n}-{rep}"
                r = measure(fleet, n, out)
                shutil.rmtree(out)
                walls[n].append(r["wall_s"])
                print(
                    f"{n} worker(s): {r['logs']} logs ({r['ok']} ok, {r['samples'] / 1e6:.1f}e6 "
                    f"samples), wall {r['wall_s']:.1f} s, CPU {r['cpu_s']:.1f} s "
                    f"(tasks {r['task_cpu_s']:.1f} s): {r['logs_per_cpu_hour']:.0f} logs per "
                    f"CPU-hour, {r['logs_per_wall_hour']:.0f} logs per wall-hour; warm worker "
                    f"{r['warm_cpu_per_1e6_median_s']:.2f} s CPU per 10^6 samples (median; "
                    f"{r['warm_cpu_per_1e6_total_s']:.2f} over all warm tasks; each worker's "
                    f"first task {r['first_cpu_per_1e6_median_s']:.2f}); workers' warm-up "
                    f"{r['warm_up_cpu_s']:.1f} s CPU; window-fit loops: {r['kernels']}",
                    flush=True,
                )
            if 1 in walls and 2 in walls:
                print(f"  2 workers / 1 worker, wall: {walls[1][-1] / walls[2][-1]:.2f}x")
        if 1 in walls and 2 in walls and args.repeat > 1:
            ratios = sorted(a / b for a, b in zip(walls[1], walls[2], strict=True))
            print(
                f"2 workers / 1 worker over {args.repeat} pairs: median "
                f"{statistics.median(ratios):.2f}x (from {ratios[0]:.2f}x to {ratios[-1]:.2f}x); "
                f"median walls {statistics.median(walls[1]):.1f} s / "
                f"{statistics.median(walls[2]):.1f} s: "
                f"{statistics.median(walls[1]) / statistics.median(walls[2]):.2f}x"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())

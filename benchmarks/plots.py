"""``python -m benchmarks.plots``: CPU of the three commands that draw figures (``--plots``),
with and without their figures, each run a fresh ``python -m imudiag`` process as a user
runs it (CPU: the child's user + system time; a first run warms matplotlib's font cache).
In one warm process the figures would look cheaper than they are: matplotlib keeps parsed
mathtext labels between figures.

Cases:

- ``model-check``: a simulated 300 s, 100 Hz session (3x10^4 samples; the session of
  tests/test_modelcheck.py's command-line test: the bundled board, a warm-up temperature
  profile, a temperature bias of 5 on ay), ``--seed 3``, the bundled certificate: 17 figures;
- ``diagnose``: the real Xsens MTi session (tests/data/real/xsens-mti-multiposition) with
  tests/data/diagnosis/like-xsens.yaml: 3 figures;
- ``calibrate``: the same session and ``--like`` certificate: 2 figures.

Options: ``--cases`` (comma list), ``--repeat N`` (least of N, default 3), ``--before REV``
(also the package of git revision REV, ``git archive`` into a temporary folder, its runs
interleaved with this tree's: a before/after on a machine whose load changes), ``--profile N``
(cProfile of one more run with figures, top N functions by cumulative time), ``--keep DIR``
(leave the figures of the last run in DIR/<case>/ to look at).
Prints, per case: the least CPU of the command with ``--plots``, of the command without,
and their difference (the figures, matplotlib's import included). ``--profile`` runs the
command in this process. No assertion: docs/benchmarks.md holds the figures.
"""

from __future__ import annotations

import argparse
import contextlib
import cProfile
import io
import os
import pstats
import resource
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

for _name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")  # as the command line

ROOT = Path(__file__).resolve().parent.parent
XSENS = ROOT / "tests" / "data" / "real" / "xsens-mti-multiposition" / "session.csv.gz"
LIKE = ROOT / "tests" / "data" / "diagnosis" / "like-xsens.yaml"
CASES = ("model-check", "diagnose", "calibrate")


def write_modelcheck_session(path: Path) -> Path:
    """The 300 s, 100 Hz session of tests/test_modelcheck.py's command-line test (seed 4)."""
    from imudiag.certificate import load_default
    from imudiag.logs import write_log
    from imudiag.sim import Effects, TemperatureProfile, simulate
    from imudiag.sim.trajectories import multi_position_motion

    cert = load_default()
    temp = TemperatureProfile(22.0, 12.0, 150.0, swing_c=2.5, swing_period_s=110.0)
    effects = Effects.board(temperature=temp, temperature_bias={"ay": 5.0})
    traj = multi_position_motion(14, 16.0, 2.0, seed=4, cyclic=True).sample(100.0, n=30_000)
    write_log(path, simulate(cert, traj, seed=4, effects=effects).samples)
    return path


def command(case: str, work: Path, plots: Path | None) -> list[str]:
    """The command line of ``case`` (outputs in ``work``; ``--plots plots`` when given)."""
    if case == "model-check":
        args = ["model-check", str(work / "session.csv.gz"), "--certificate",
                str(ROOT / "config" / "default-certificate.yaml"), "--seed", "3"]  # fmt: skip
    elif case == "diagnose":
        args = ["diagnose", str(XSENS), "--certificate", str(LIKE)]
    else:
        args = ["calibrate", str(XSENS), "--like", str(LIKE), "--out", str(work / "cal.yaml")]
    args += ["--json", str(work / f"{case}.json")]
    if plots is not None:
        args += ["--plots", str(plots)]
    return args


def run_once(args: list[str], code: Path = ROOT) -> float:
    """CPU seconds (user + system) of ``python -m imudiag ARGS`` in a child process, the
    package imported from ``code``."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    proc = subprocess.run(
        [sys.executable, "-m", "imudiag", *args, "-q"], cwd=code, capture_output=True, text=True
    )
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise SystemExit(f"imudiag {' '.join(args)}: exit {proc.returncode}: {proc.stderr}")
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def run_in_process(args: list[str]) -> None:
    """``imudiag ARGS`` in this process (its stdout discarded), for the profile."""
    from imudiag.cli import main

    with contextlib.redirect_stdout(io.StringIO()):
        main(args)


def main(argv: list[str] | None = None) -> int:
    """Entry point; prints one line per case."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--profile", type=int, default=0)
    ap.add_argument("--keep", type=Path)
    ap.add_argument("--before")
    opts = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        write_modelcheck_session(work / "session.csv.gz")
        trees = {"this tree": ROOT}
        if opts.before:
            old = work / "before"
            old.mkdir()
            archive = subprocess.run(["git", "archive", opts.before, "imudiag"], cwd=ROOT,
                                     capture_output=True, check=True).stdout  # fmt: skip
            subprocess.run(["tar", "-x", "-C", str(old)], input=archive, check=True)
            trees = {opts.before: old, **trees}
        for case in opts.cases.split(","):
            plots = work / f"plots-{case}"
            run_once(command(case, work, plots))  # warm: imports, font cache, first figures
            shutil.rmtree(plots)
            with_plots: dict[str, list[float]] = {name: [] for name in trees}
            without = []
            for _ in range(opts.repeat):
                for name, code in trees.items():
                    with_plots[name].append(run_once(command(case, work, plots), code))
                    n_files = len(list(plots.glob("*.png")))
                    if opts.keep:
                        dest = opts.keep / name.replace(" ", "-") / case
                        shutil.rmtree(dest, ignore_errors=True)
                        shutil.copytree(plots, dest)
                    shutil.rmtree(plots)
                without.append(run_once(command(case, work, None)))
            bare = min(without)
            for name, runs in with_plots.items():
                best = min(runs)
                print(
                    f"{case:12s} {name:10s} {n_files:2d} figures: with --plots {best:.3f} s "
                    f"CPU, without {bare:.3f} s, figures {best - bare:.3f} s "
                    f"({(best - bare) / n_files:.3f} s per figure; least of {opts.repeat})"
                )
            if opts.profile:
                prof = cProfile.Profile()
                prof.enable()
                run_in_process(command(case, work, plots))
                prof.disable()
                shutil.rmtree(plots)
                out = io.StringIO()
                pstats.Stats(prof, stream=out).sort_stats("cumulative").print_stats(opts.profile)
                print(out.getvalue())
            sys.stdout.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())

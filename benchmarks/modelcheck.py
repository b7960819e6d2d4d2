"""Benchmark: model-check time for a 30-minute 100 Hz session.

Run: ``.venv/bin/python benchmarks/modelcheck.py [--duration 1800] [--rate 100] [--effect SPEC]``.
A cyclic multi-position session of the bundled board (14 attitudes, 16 s dwells, 2 s
turns) with a warm-up temperature profile and one hidden effect (``--effect``, default a
temperature bias on gx) is simulated and written to a ``.csv.gz`` log; the model check
then runs on the *file*, streaming (three passes over the log), as ``imudiag
model-check`` would. Prints the wall time of the model check, its peak memory
(tracemalloc, in a second run) and what it named.
"""

from __future__ import annotations

import argparse
import tempfile
import time
import tracemalloc
from pathlib import Path

from imudiag.certificate import load_default
from imudiag.logs import open_writer
from imudiag.modelcheck import model_check
from imudiag.sim import Effects, Simulator, TemperatureProfile
from imudiag.sim.scenarios import apply_effect
from imudiag.sim.trajectories import multi_position_motion


def write_session(path: Path, duration_s: float, rate_hz: float, effect: str, seed: int) -> int:
    """Simulate the session in 60 s chunks straight into ``path``; returns the sample count."""
    cert = load_default()
    temp = TemperatureProfile(22.0, 12.0, 600.0, swing_c=2.0, swing_period_s=300.0)
    effects = apply_effect(Effects.board(temperature=temp), effect)
    motion = multi_position_motion(14, 16.0, 2.0, seed=seed, cyclic=True)
    sim = Simulator(cert, effects, seed=seed, meta={"sample_rate": rate_hz})
    total = int(round(duration_s * rate_hz))
    chunk = int(round(60.0 * rate_hz))
    with open_writer(path, meta={"sample_rate": rate_hz}) as w:
        for start in range(0, total, chunk):
            w.write(sim.step(motion.sample(rate_hz, start, min(chunk, total - start))))
    return total


def run(duration_s: float, rate_hz: float, effect: str, seed: int = 0) -> dict:
    """Simulate, then time the model check of the log file."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "session.csv.gz"
        n = write_session(path, duration_s, rate_hz, effect, seed)
        cert = load_default()
        start = time.perf_counter()
        result = model_check(path, cert, seed=seed)
        wall = time.perf_counter() - start
        tracemalloc.start()  # a second run for the memory (tracing slows it down)
        model_check(path, cert, seed=seed)
        _cur, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
    return {
        "samples": n,
        "wall_s": wall,
        "peak_mb": peak / 1e6,
        "effects": result.report["effects"],
        "gain": result.report["gain"],
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--duration", type=float, default=1800.0, help="session length, s")
    p.add_argument("--rate", type=float, default=100.0, help="sample rate, Hz")
    p.add_argument(
        "--effect",
        default="temperature_bias:gx:2.0",
        help="hidden effect, as `imudiag simulate --effect` (default %(default)s)",
    )
    p.add_argument("--seed", type=int, default=0)
    a = p.parse_args()
    r = run(a.duration, a.rate, a.effect, a.seed)
    print(
        f"model check of a {a.duration:g} s {a.rate:g} Hz session ({r['samples']} samples, "
        f"hidden {a.effect}): {r['wall_s']:.2f} s wall, peak traced memory "
        f"{r['peak_mb']:.0f} MB"
    )
    for e in r["effects"]:
        print(
            f"  named {e['name']} {e['sensor']}: {e['value']} {e['unit']} (z={e['significance']})"
        )
    print(f"  gain: {r['gain']}")


if __name__ == "__main__":
    main()

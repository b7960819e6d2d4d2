"""Benchmark: simulated samples per second for a one-hour 1 kHz session, every effect on.

Run: ``.venv/bin/python benchmarks/simulate.py [--duration 3600] [--rate 1000] [--chunk 60]``.
The session (the endless ``static`` scenario: a few attitudes with slow turns) is
simulated in chunks of ``--chunk`` seconds through the streaming simulator, with
every effect of :meth:`imudiag.sim.Effects.all_on` and two faults. Prints the
samples per second and the ratio of simulated time to wall time.
"""

from __future__ import annotations

import argparse
import time

from imudiag.certificate import load_default
from imudiag.sim import Effects, Fault
from imudiag.sim.scenarios import scenario_motion
from imudiag.sim.simulator import Simulator


def run(duration_s: float, rate_hz: float, chunk_s: float, seed: int = 0) -> dict[str, float]:
    """Simulate and time; returns samples, wall seconds, samples/s and the real-time ratio."""
    cert = load_default()
    motion = scenario_motion("static", seed)
    faults = [Fault("bias", "ax", duration_s / 2, 150.0), Fault("noise", "gz", duration_s / 3, 3.0)]
    sim = Simulator(cert, Effects.all_on(), faults, seed)
    total = int(round(duration_s * rate_hz))
    chunk = max(1, int(round(chunk_s * rate_hz)))
    start = time.perf_counter()
    done = 0
    while done < total:
        n = min(chunk, total - done)
        sim.step(motion.sample(rate_hz, done, n))
        done += n
    wall = time.perf_counter() - start
    return {
        "samples": float(total),
        "wall_s": wall,
        "samples_per_s": total / wall,
        "real_time_ratio": duration_s / wall,
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--duration", type=float, default=3600.0, help="session length, s")
    p.add_argument("--rate", type=float, default=1000.0, help="sample rate, Hz")
    p.add_argument("--chunk", type=float, default=60.0, help="seconds per simulated chunk")
    a = p.parse_args()
    r = run(a.duration, a.rate, a.chunk)
    print(f"simulated {r['samples']:.0f} samples ({a.duration:g} s at {a.rate:g} Hz, all effects)")
    print(
        f"wall time {r['wall_s']:.2f} s: {r['samples_per_s']:.3g} samples/s, "
        f"{r['real_time_ratio']:.0f}x faster than real time"
    )


if __name__ == "__main__":
    main()

"""Wall-clock figures of the real-time paths, printed (never asserted by the tests).

The real-time test tier judges pacing, outages and a stuck status receiver on events and
sample time (README "Tests"); how fast they happen on this machine is measured here:

- ``pace``: wall time to deliver 2 s of samples from ``replay://...?speed=8`` and
  ``sim://...?speed=20`` (ideal 0.25 s and 0.10 s);
- ``publish``: the slowest ``SerialStatusSink.publish`` with a pty nobody reads (the write
  timeout 0.5 s: a publish that waited for the port would take that long), and how long
  ``close`` takes to give up on the stuck receiver;
- ``bench``: the bundled ``transport`` scenario's unplug (no_data after the pull, samples
  again after the replug, wall s; bounds 1.5 s and 2 s in the scenario) and the longest
  wall delay from a board write to a status line showing its samples.

Usage: ``python -m benchmarks.realtime [--only pace|publish|bench]``; add ``uptime``'s load
to any figure you quote.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path


def pace() -> None:
    """Wall time of paced sources against their ideal."""
    import numpy as np

    from imudiag.drivers import EndOfStream, open_source
    from imudiag.drivers.wire import encode_samples

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "capture.bin"
        n = 400  # 2 s at 200 Hz
        raw = np.random.default_rng(0).integers(20000, 45000, (n, 6))
        path.write_bytes(encode_samples(0, 5000 * np.arange(n), raw))
        for url, ideal in (
            (f"replay://{path}?speed=8", 0.25),
            ("sim://vehicle?speed=20&duration=2&seed=4", 0.1),
        ):
            start = time.monotonic()
            src = open_source(url)
            got = 0
            with src:
                try:
                    while True:
                        got += len(src.read(0.02))
                except EndOfStream:
                    pass
            took = time.monotonic() - start
            print(
                f"pace: {url.split('?')[0]}: {got} samples in {took:.3f} s wall (ideal {ideal} s)"
            )


def publish() -> None:
    """The slowest publish to a stuck pty and the time close takes to give up."""
    from imudiag.service.nmea import SerialStatusSink

    counters = ("bytes", "frames", "crc_errors", "skipped_bytes", "lost", "duplicates")
    fault = {"triad": "accel", "sensor": "ax", "cause": "f0"}
    status = {
        "t": 1.0,
        "state": "fault",
        "faults": [fault] * 3,
        "counters": dict.fromkeys(counters, 0),
    }
    master, slave = os.openpty()
    try:
        sink = SerialStatusSink(os.ttyname(slave), rate_hz=10.0, queue_size=16, write_timeout_s=0.5)
        worst = 0.0
        start = time.perf_counter()
        for k in range(3000):
            t0 = time.perf_counter()
            sink.publish(status, now_s=k * 0.125)
            worst = max(worst, time.perf_counter() - t0)
        total = time.perf_counter() - start
        t_close = time.perf_counter()
        sink.close(timeout_s=0.5)
        close_s = time.perf_counter() - t_close
        print(
            f"publish: 3000 cycles to a stuck pty in {total:.3f} s wall, slowest "
            f"{worst * 1e3:.2f} ms (write timeout 500 ms); close gave up after "
            f"{close_s:.3f} s; dropped {sink.dropped}"
        )
    finally:
        os.close(master)
        os.close(slave)


def bench() -> None:
    """The transport scenario's outage figures (wall s)."""
    from imudiag.bench import load_bundled, run_bench

    report = run_bench(load_bundled("transport"), diagnosis=False, wall_bounds=False)
    for r in report["faults"]:
        if r.get("category") == "outage":
            print(
                f"bench: transport #{r['number']} {r['kind']}: no_data {r.get('wall_latency_s')} s "
                f"wall after the pull (bound {r['expected']['within_wall_s']} s), samples again "
                f"{r.get('recover_wall_s')} s after the replug (bound "
                f"{r['expected']['recover_within_wall_s']} s); over a bound: "
                f"{r.get('wall_over_bound') or 'none'}"
            )
    print(
        "bench: transport: longest write -> status delay "
        f"{report['max_status_delay_wall_s']} s wall"
    )


FIGURES = {"pace": pace, "publish": publish, "bench": bench}


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--only", choices=sorted(FIGURES), help="one figure")
    args = p.parse_args(argv)
    print(f"load: {' '.join(f'{x:.2f}' for x in os.getloadavg())} (1, 5, 15 min)")
    for name, fn in FIGURES.items():
        if args.only in (None, name):
            fn()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

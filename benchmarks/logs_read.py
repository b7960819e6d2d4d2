"""Read speed of the sample-log readers: samples/s for a 10^6-sample CSV, CSV.gz and NPZ.

Writes simulated raw ADC counts (float64, shortest round-trip text, like
``imudiag simulate`` output) to a temporary directory, then times one full
streaming read per format on one core (CPU time, and wall time).
Run: ``.venv/bin/python benchmarks/logs_read.py [N]``.
"""

from __future__ import annotations

import os
import sys
import tempfile
import time

import numpy as np

from imudiag.logs import open_log, open_writer
from imudiag.samples import SampleBlock


def make_block(n: int, seed: int = 0) -> SampleBlock:
    """n samples at 200 Hz: noisy 16-bit counts around the default certificate's biases."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 200.0
    gyro = 32768.0 + rng.normal(0.0, 6.55 * 10.0, (n, 3))
    accel = np.array([33078.0, 32518.0, 32888.0 + 4090.0]) + rng.normal(0.0, 0.82 * 10.0, (n, 3))
    temp = 25.0 + 0.01 * np.cumsum(rng.normal(size=n))
    return SampleBlock(t=t, gyro=gyro, accel=accel, temp=temp)


def main() -> None:
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 1_000_000
    block = make_block(n)
    with tempfile.TemporaryDirectory() as tmp:
        for ext in (".csv", ".csv.gz", ".npz"):
            path = os.path.join(tmp, "bench" + ext)
            t0 = time.perf_counter()
            with open_writer(path, meta={"sample_rate": "200"}) as w:
                for start in range(0, n, 65536):
                    w.write(block.slice(start, start + 65536))
            t_write = time.perf_counter() - t0
            t0, c0 = time.perf_counter(), time.process_time()
            count = 0
            with open_log(path) as reader:
                for b in reader:
                    count += len(b)
            t_read, c_read = time.perf_counter() - t0, time.process_time() - c0
            assert count == n
            size = os.path.getsize(path) / 1e6
            print(
                f"{ext:8s} {size:7.1f} MB  read {count / c_read:12,.0f} samples/s CPU "
                f"({count / t_read:12,.0f} wall)  write {n / t_write:11,.0f} samples/s wall"
            )


if __name__ == "__main__":
    main()

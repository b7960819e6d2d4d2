"""Decode + CRC + certificate-corrected F0 from a raw capture, beside a minimal numpy floor.

Builds a raw capture of 10^6 sample frames (``encode_samples``; the default
certificate's board at rest with gravity and Earth rate, white noise), then
times, on one core (BLAS threads pinned to 1, the process pinned to one CPU):

- product path: the wire :class:`Decoder` (resync scan, table CRC, seq/time
  accounting) then ``imudiag.scalar.f0_raw`` for both triads with the default
  certificate, fed in chunks like a live port or a replay;
- floor: a minimal numpy pass over the same bytes (``frombuffer`` with the
  frame dtype, the same table CRC, the raw norm of both triads).

Prints samples/s of each, the ratio, and the machine's core count. Run::

    .venv/bin/python benchmarks/decode_f0.py [N_FRAMES]
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # one core: set before numpy is imported

import platform  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402

import numpy as np  # noqa: E402

from imudiag.certificate import Certificate, load_default  # noqa: E402
from imudiag.drivers.crc import crc16_rows  # noqa: E402
from imudiag.drivers.wire import FRAME_DTYPE, SAMPLE_FRAME_SIZE, Decoder, encode_samples  # noqa: E402
from imudiag.scalar import f0_raw  # noqa: E402

TARGET_SAMPLES_PER_S = 5e6  #: decode + CRC + F0, one core
RATE_HZ = 200.0


def build_capture(n: int, cert: Certificate, seed: int = 0) -> bytes:
    """n sample frames of the default board at rest (counts), 200 Hz, seq from 0."""
    rng = np.random.default_rng(seed)
    g = np.array([0.0, 0.0, cert.gravity])  # m/s^2, specific force at rest, level
    w = np.array([cert.earth_rate * np.cos(np.radians(45)), 0.0,
                  -cert.earth_rate * np.sin(np.radians(45))])  # fmt: skip
    accel = cert.accel.forward_si(np.tile(g, (n, 1)))
    gyro = cert.gyro.forward_si(np.tile(w, (n, 1)))
    accel += rng.normal(0.0, cert.accel.noise_sigma(RATE_HZ), (n, 3))
    gyro += rng.normal(0.0, cert.gyro.noise_sigma(RATE_HZ), (n, 3))
    raw = np.rint(np.hstack([gyro, accel])).astype(np.int64)
    time_us = np.rint(np.arange(n) * (1e6 / RATE_HZ)).astype(np.int64)
    temp = 25.0 + 0.5 * np.sin(np.arange(n) / 1e5)
    return encode_samples(0, time_us, raw, temp, None)


def product_pass(data: bytes, chunk: int, cert: Certificate) -> tuple[int, float, float]:
    """Decoder + F0 of both triads; returns samples, mean F0 accel, mean F0 gyro."""
    dec = Decoder()
    n = 0
    sa = sg = 0.0
    for i in range(0, len(data), chunk):
        b = dec.feed(data[i : i + chunk])
        fa = f0_raw(cert.accel, b.accel, cert.magnitude_si("accel"))
        fg = f0_raw(cert.gyro, b.gyro, cert.magnitude_si("gyro"))
        n += len(b)
        sa += float(fa.sum())
        sg += float(fg.sum())
    if dec.counters.crc_errors or dec.counters.lost or dec.resync_steps:
        raise RuntimeError(f"clean capture decoded with errors: {dec.counters}")
    return n, sa / n, sg / n


def floor_frames(chunk: bytes) -> int:
    """The floor over one chunk of whole frames: frombuffer structured + table CRC + norm of
    both triads; returns the good frames."""
    frames = np.frombuffer(chunk, FRAME_DTYPE)
    rows = frames.view(np.uint8).reshape(-1, SAMPLE_FRAME_SIZE)
    ok = crc16_rows(rows[:, 2:38]) == frames["crc"]
    raw = frames["raw"][ok].astype(np.float64)
    np.sqrt(np.einsum("ij,ij->i", raw[:, :3], raw[:, :3]))
    np.sqrt(np.einsum("ij,ij->i", raw[:, 3:], raw[:, 3:]))
    return int(np.count_nonzero(ok))


def floor_pass(data: bytes, chunk: int) -> int:
    """The floor over ``data`` in chunks of ``chunk`` bytes; good frames."""
    return sum(floor_frames(data[i : i + chunk]) for i in range(0, len(data), chunk))


def best_of(repeat: int, fn: Callable[[], object]) -> tuple[float, object]:
    """Shortest wall time of ``repeat`` runs, seconds, and the last result."""
    best, result = float("inf"), None
    for _ in range(repeat):
        t0 = time.perf_counter()
        result = fn()
        best = min(best, time.perf_counter() - t0)
    return best, result


def main() -> None:
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 1_000_000
    cores = os.cpu_count()
    usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else cores
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    cert = load_default()
    t0 = time.perf_counter()
    data = build_capture(n, cert)
    t_build = time.perf_counter() - t0
    print(f"machine: {platform.processor() or platform.machine()}, {cores} cores "
          f"({usable} usable), timing on 1 core; numpy {np.__version__}")  # fmt: skip
    print(f"capture: {n} frames, {len(data) / 1e6:.1f} MB, encoded in {t_build:.2f} s "
          f"({n / t_build:.3g} frames/s)")  # fmt: skip
    floor_pass(data, len(data))  # warm-up: tables, page faults
    for label, chunk_frames in (("one buffer", n), ("64 KiB chunks", 65536 // 40),
                                ("1 MiB chunks", (1 << 20) // 40)):  # fmt: skip
        chunk = chunk_frames * SAMPLE_FRAME_SIZE
        t_floor, good = best_of(3, lambda c=chunk: floor_pass(data, c))
        t_prod, res = best_of(3, lambda c=chunk: product_pass(data, c, cert))
        k, fa, fg = res  # type: ignore[misc]
        if good != n or k != n:
            raise RuntimeError(f"samples lost: floor {good}, decoder {k} of {n}")
        rate = n / t_prod
        verdict = "meets" if rate >= TARGET_SAMPLES_PER_S else "BELOW"
        print(f"[{label}] decode+CRC+F0: {rate:.3g} samples/s ({t_prod * 1e3:.0f} ms), "
              f"floor {n / t_floor:.3g} samples/s ({t_floor * 1e3:.0f} ms), "
              f"ratio {t_prod / t_floor:.2f}x floor; target {TARGET_SAMPLES_PER_S:.0e}: "
              f"{verdict}")  # fmt: skip
    print(
        f"sanity: mean F0 accel {fa:+.2e} (at rest: near 0); gyro {fg:+.2e} (per-sample "
        "noise, ~1 deg/s, dwarfs Earth rate, 0.004 deg/s: only averages make it meaningful)"
    )


if __name__ == "__main__":
    main()

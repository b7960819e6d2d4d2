"""The quasi-static detector alone: CPU per ``QuasiStaticDetector.update`` call (issue 14).

A still session of the bundled board at ``--rate`` (default 1 kHz, the certificate's
``sample_rate`` set to it, as the live benchmark does) is fed to the detector in blocks
of each ``--sizes`` (default 5, 250 and 500 samples: a daemon's read at 5 ms, the
monitor's 0.25 s batch and the diagnosis batch of 0.5 s) after a 10 s warm-up; the
figure is process CPU time per call (us) and as a share of one core at that rate. Three
detectors in the same run, alternated ``--repeat`` times (the least of each is kept):
the shipped one, the shipped one with the drift tests off (``drift_f0_fraction=None``),
and, when the test tree is present, the frozen detector of
``tests/reference/drift_quasistatic.py`` (the code before this work, the reference
of ``tests/test_detector_equivalence.py``). Each run's flags must equal the first's.
BLAS is pinned to one thread, as ``imudiag`` pins it.

Run: ``.venv/bin/python -m benchmarks.detector [--rate 1000] [--sizes 5,250,500]
[--repeat 3]``.
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # one core, as the command line pins it: before numpy

import argparse  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable, Sequence  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

from imudiag.certificate import load_default  # noqa: E402
from imudiag.quasistatic import QuasiStaticDetector  # noqa: E402
from imudiag.samples import SampleBlock  # noqa: E402
from imudiag.sim import simulate, still  # noqa: E402

WARMUP_S = 10.0  #: s of samples fed before the timing starts


def _detectors() -> dict[str, Callable[..., Any]]:
    """Name -> constructor (certificate, rate) of each detector measured."""
    out: dict[str, Callable[..., Any]] = {
        "shipped": QuasiStaticDetector,
        "shipped, drift tests off": lambda cert, rate: QuasiStaticDetector(
            cert, rate, drift_f0_fraction=None
        ),
    }
    try:
        from tests.reference.drift_quasistatic import QuasiStaticDetector as Frozen
    except ImportError:  # an installed copy without the test tree
        return out
    out["frozen (before this work)"] = Frozen
    return out


def time_calls(
    make: Callable[..., Any], block: SampleBlock, rate: float, size: int
) -> tuple[float, np.ndarray]:
    """(CPU s per ``update`` call after the warm-up, the flags of every sample)."""
    cert = load_default()
    cert.sample_rate = rate
    det = make(cert, rate)
    parts = [block.slice(i, i + size) for i in range(0, len(block), size)]
    warm = max(1, int(WARMUP_S * rate) // size)
    flags = [det.update(p) for p in parts[:warm]]
    t0 = time.process_time()
    flags += [det.update(p) for p in parts[warm:]]
    return (time.process_time() - t0) / max(1, len(parts) - warm), np.concatenate(flags)


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rate", type=float, default=1000.0, help="sample rate, Hz")
    p.add_argument("--duration", type=float, default=60.0, help="session length, s")
    p.add_argument("--sizes", default="5,250,500", help="block sizes, samples")
    p.add_argument("--repeat", type=int, default=3, help="alternated runs of each")
    a = p.parse_args(argv)
    cert = load_default()
    cert.sample_rate = a.rate
    traj = still(a.duration, rate_hz=a.rate, attitude_rpy_deg=(10.0, -20.0, 30.0))
    block = simulate(cert, traj, seed=3).samples
    makers = _detectors()
    print(f"load average {os.getloadavg()[0]:.2f}; {len(block)} samples at {a.rate:g} Hz")
    for size in (int(s) for s in a.sizes.split(",")):
        best: dict[str, float] = {}
        reference = None
        for _ in range(a.repeat):
            for name, make in makers.items():
                per_call, flags = time_calls(make, block, a.rate, size)
                if reference is None:
                    reference = flags
                elif "drift tests off" not in name and not np.array_equal(flags, reference):
                    raise SystemExit(f"{name}: flags differ from the shipped detector's")
                best[name] = min(best.get(name, np.inf), per_call)
        calls_per_s = a.rate / size
        print(
            f"{size:4d}-sample blocks: "
            + "; ".join(
                f"{name} {1e6 * s:.0f} us per call ({100 * s * calls_per_s:.3f} % of a core)"
                for name, s in best.items()
            ),
            flush=True,
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

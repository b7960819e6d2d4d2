"""The project's simulator as the sample source of the fake devices (:mod:`.fake_isensor`,
:mod:`.fake_witmotion`, :mod:`.fake_iio`): blocks of true outputs in a certificate's units
(a data-sheet certificate gives deg/s and g or m/s^2), which each fake quantises and
encodes in its own protocol."""

from __future__ import annotations

from collections.abc import Iterable, Iterator

from imudiag.certificate import Certificate
from imudiag.samples import SampleBlock
from imudiag.sim import Effects, Fault, Simulator
from imudiag.sim.trajectories import Motion


def simulated_blocks(
    cert: Certificate,
    motion: Motion,
    rate_hz: float,
    seed: int = 0,
    faults: Iterable[Fault] = (),
    effects: Effects | None = None,
    chunk_s: float = 0.05,
    duration_s: float | None = None,
) -> Iterator[SampleBlock]:
    """Consecutive blocks of ``chunk_s`` seconds of simulated outputs (``cert``'s output
    units, not rounded: the device's LSB is the fake's business) until the motion or
    ``duration_s`` ends (an endless motion without a duration never ends)."""
    sim = Simulator(cert, effects if effects is not None else Effects(), tuple(faults), seed)
    total = motion.n_samples(rate_hz)
    if duration_s is not None:
        cap = int(round(duration_s * rate_hz))
        total = cap if total is None else min(total, cap)
    step = max(1, int(round(chunk_s * rate_hz)))
    start = 0
    while total is None or start < total:
        n = step if total is None else min(step, total - start)
        yield sim.step(motion.sample(rate_hz, start, n))
        start += n

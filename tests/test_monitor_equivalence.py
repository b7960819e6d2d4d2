"""The monitor's cheaper per-read path gives the verdicts and counters of the previous one.

``tests/reference/old_*.py`` are the monitor, trailing sums and still detector as they
were before the per-read cost work (issue 14), kept as the reference. Both run on the same
seeded streams, cut into the same blocks (daemon-sized reads and odd sizes), and after
every block their fault lists, F0 counters, persistence raises and static flags must be
identical; the F0 sums and noise ratios agree to rounding (running sums round differently).
"""

from __future__ import annotations

import numpy as np
import pytest

from imudiag.certificate import load_default
from imudiag.monitor import Monitor
from imudiag.samples import FLAG_ACCEL_SATURATED, SampleBlock
from imudiag.sim import Effects, Fault, multi_position, simulate, still
from tests.reference.old_monitor import Monitor as OldMonitor

CERT = load_default()
RATE = CERT.sample_rate

CASES = {
    "still, clean": ([], Effects(), "still"),
    "still, az bias 3 limits": ([Fault("bias", "az", 4.0, 600.0)], Effects(), "still"),
    "turns, gy bias": ([Fault("bias", "gy", 5.0, 200.0)], Effects(quantize=True), "turns"),
    "turns, ax noise x4": ([Fault("noise", "ax", 6.0, 4.0)], Effects(quantize=True), "turns"),
    "still, gz stuck": ([Fault("stuck", "gz", 3.0, None)], Effects(), "still"),
    "turns, adc errors": ([], Effects(quantize=True, adc_error_rate=0.002), "turns"),
}


def _stream(case: str, seed: int) -> SampleBlock:
    faults, effects, motion = CASES[case]
    if motion == "still":
        traj = still(14.0, rate_hz=RATE, attitude_rpy_deg=(10.0, -20.0, 30.0))
    else:
        traj = multi_position(n_attitudes=5, dwell_s=2.0, turn_s=1.0, rate_hz=RATE, seed=seed)
    block = simulate(CERT, traj, seed=seed, faults=faults, effects=effects).samples
    if case == "still, clean":  # and saturation flags for a while
        flags = np.zeros(len(block), dtype=np.uint16)
        flags[2000:2600] |= FLAG_ACCEL_SATURATED
        block.flags = flags if block.flags is None else block.flags | flags
    return block


def _snapshot(m: Monitor | OldMonitor) -> tuple:
    exact = (
        # the frozen reference predates the always-present sensor key (null for a triad's F0)
        [dict(f, sensor=f.get("sensor")) for f in m.active_faults],
        m.f0_checked,
        m.f0_failed,
        m.adc_errors,
        m.static,
        m.f0_faults() and [{k: v for k, v in f.items() if k != "estimate"} for f in m.f0_faults()],
        {
            name: (
                st.persistence.raised,
                st.saturation.raised,
                [p.raised for p in st.noise],
                [p.raised for p in st.noise_gross],
                st.worst_axis,
                list(st.stuck_active),
            )
            for name, st in m.state.items()
        },
    )
    close = [
        np.array([st.sum_f0_sq, st.last_f0, *st.noise_ratio_last], dtype=float)
        for st in m.state.values()
    ]
    return exact, np.concatenate(close)


@pytest.mark.parametrize("case", sorted(CASES))
def test_new_path_matches_the_reference_block_by_block(case):
    seed = 1 + sorted(CASES).index(case)
    block = _stream(case, seed)
    rng = np.random.default_rng(seed)
    # daemon-sized reads (1 kHz at 5 ms is 5 frames; 200 Hz at 20 ms is 4) and odd sizes
    sizes = rng.choice([1, 2, 4, 5, 7, 20, 64, 333], size=len(block))
    new, old = Monitor(CERT), OldMonitor(CERT)
    start = blocks = 0
    while start < len(block):
        part = block.slice(start, min(len(block), start + int(sizes[blocks])))
        new.update(part)
        old.update(part)
        a, b = _snapshot(new), _snapshot(old)
        assert a[0] == b[0], f"{case}: block {blocks} (samples {start}..) differs"
        np.testing.assert_allclose(a[1], b[1], rtol=1e-9, atol=1e-12, equal_nan=True)
        start += len(part)
        blocks += 1
    # the cases exercise what they name
    faults = {(f["triad"], f.get("sensor"), f["cause"]) for f in new.active_faults}
    if "bias" in case or "stuck" in case or "noise" in case:
        assert faults, case
    if case == "still, clean":
        assert new.state["accel"].saturation.raised == 1
    if "adc" in case:
        assert new.adc_errors > 0

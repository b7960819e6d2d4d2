"""The monitor's cheaper per-read path gives the verdicts and counters of the previous one.

``tests/reference/old_monitor.py`` and ``old_trailing.py`` are the monitor and its trailing
sums as they were before the per-read cost work (issue 14), kept as the reference (with
today's still detector, which ``tests/test_detector_equivalence.py`` holds to its own
reference, so the monitors alone are compared). Both run on the same
seeded streams, cut into the same blocks (daemon-sized reads and odd sizes), and after
every block their fault lists, F0 counters, persistence raises and static flags must be
identical; the F0 sums and noise ratios agree to rounding (running sums round differently).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from imudiag.certificate import load, load_default
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
#: cases of the gathered-reads test only (the frozen reference's noise ratios differ from
#: today's on windows holding a non-finite output, since before the detector work)
GATHERED_CASES = {
    # a few outputs not finite: the noise check's medians of the windows that hold them
    "still, non-finite outputs": ([], Effects(quantize=True), "still"),
}


def _stream(case: str, seed: int) -> SampleBlock:
    faults, effects, motion = {**CASES, **GATHERED_CASES}[case]
    if motion == "still":
        traj = still(14.0, rate_hz=RATE, attitude_rpy_deg=(10.0, -20.0, 30.0))
    else:
        traj = multi_position(n_attitudes=5, dwell_s=2.0, turn_s=1.0, rate_hz=RATE, seed=seed)
    block = simulate(CERT, traj, seed=seed, faults=faults, effects=effects).samples
    if case == "still, non-finite outputs":
        rng = np.random.default_rng(seed)
        rows = rng.integers(len(block) // 3, len(block), size=6)
        block.gyro[rows[:3], rng.integers(0, 3, size=3)] = np.nan
        block.accel[rows[3:5], 1] = np.inf
        block.accel[rows[5], 2] = np.nan
    if case == "still, clean":  # and saturation flags for a while
        flags = np.zeros(len(block), dtype=np.uint16)
        flags[2000:2600] |= FLAG_ACCEL_SATURATED
        block.flags = flags if block.flags is None else block.flags | flags
    return block


def _as_reference(faults: list[dict]) -> list[dict]:
    """Fault entries in the frozen reference's terms: it predates the always-present sensor
    key (null for a triad's F0) and the stuck fault's t_first (tests/test_monitor.py)."""
    return [
        {
            k: v
            for k, v in dict(f, sensor=f.get("sensor")).items()
            if not (k == "t_first" and f["cause"] == "stuck")
        }
        for f in faults
    ]


def _snapshot(m: Monitor | OldMonitor) -> tuple:
    exact = (
        _as_reference(m.active_faults),
        m.f0_checked,
        m.f0_failed,
        m.adc_errors,
        m.static,
        # (samples_per_check: a key the frozen reference predates; 1 for this certificate)
        m.f0_faults()
        and [
            {k: v for k, v in f.items() if k not in ("estimate", "samples_per_check")}
            for f in m.f0_faults()
        ],
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
    assert new.samples_per_check("accel") == 1  # the reference judges single samples too
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


def _f0_view(faults: list[dict], gyro_per_sample: bool) -> list[tuple]:
    """The faults of the per-sample F0 checks: the accelerometers', and the gyros' where
    they check Earth rate per sample (a MEMS gyro's rest-rate check is a slower one: a 1 s
    mean 0.5 s back, run once per batch)."""
    return [
        (f["triad"], f.get("sensor"), f.get("t_first"))
        for f in faults
        if f["cause"] == "f0" and (f["triad"] == "accel" or gyro_per_sample)
    ]


#: a navigation-grade gyro quiet enough for its F0 on Earth rate per sample (the other
#: per-sample check the gathered reads must never delay)
NAV = load(Path(__file__).parent / "data" / "diagnosis" / "nav-grade.yaml")
NAV.gyro.noise.density = NAV.gyro.noise.density * 0.1
NAV_CASES = {
    "nav still, clean": [],
    "nav still, gx bias 10 limits": [
        Fault("bias", "gx", 30.0, 10.0 * float(NAV.gyro.limits.bias[0]))
    ],
}


@pytest.mark.parametrize("case", sorted(CASES) + sorted(NAV_CASES) + sorted(GATHERED_CASES))
def test_gathered_reads_give_the_verdicts_of_checking_every_read(case):
    """The daemon's path: reads of 4-5 samples are gathered and checked once per batch
    unless a sample could change an F0 verdict. Without ever running the gathered checks
    (``faults_in_force``), the F0 faults after every read are the reference's; whenever a
    batch has run, every fault, counter and raise is; and most reads are only gathered."""
    seed = 11 + (sorted(CASES) + sorted(NAV_CASES) + sorted(GATHERED_CASES)).index(case)
    if case in NAV_CASES:
        cert = NAV
        traj = still(90.0, rate_hz=NAV.sample_rate, attitude_rpy_deg=(5.0, -10.0, 40.0))
        block = simulate(NAV, traj, seed=seed, faults=NAV_CASES[case]).samples
    else:
        cert = CERT
        block = _stream(case, seed)
    rng = np.random.default_rng(seed)
    sizes = rng.choice([4, 5], size=len(block))
    new, old = Monitor(cert), OldMonitor(cert)
    if case in NAV_CASES:
        assert new.gyro_mode == "earth_rate"
    stages = {"f0": 0}
    f0_stage = new._f0_stage

    def counting() -> None:
        stages["f0"] += 1
        f0_stage()

    new._f0_stage = counting
    start = reads = batches = 0
    while start < len(block):
        part = block.slice(start, min(len(block), start + int(sizes[reads])))
        new.update(part)
        old.update(part)
        where = f"{case}: read {reads} (samples {start}..)"
        per_sample = new.gyro_mode == "earth_rate"
        assert _f0_view(new.faults_in_force(), per_sample) == _f0_view(
            old.active_faults, per_sample
        ), where
        if new.pending_samples == 0:  # a batch has just run: everything agrees
            batches += 1
            got = _as_reference(new.faults_in_force())
            assert got == _as_reference(old.active_faults), where
        start += len(part)
        reads += 1
    assert batches >= len(block) // (new._batch + 5) - 1, "a batch ran every 50-54 samples"
    a, b = _snapshot(new), _snapshot(old)  # flushes what is left
    assert a[0] == b[0], case
    np.testing.assert_allclose(a[1], b[1], rtol=1e-9, atol=1e-12, equal_nan=True)
    if case in ("still, clean", "nav still, clean"):
        # a healthy unit at rest, F0 failures rare: most reads are only gathered
        assert stages["f0"] < 0.5 * reads, f"{case}: F0 checks on {stages['f0']} of {reads} reads"
    if "bias" in case:
        assert any(f["cause"] == "f0" for f in new.active_faults), f"{case}: the fault is raised"


#: ``imudiag diagnose`` feeds the monitor whole blocks of a log (62500 samples); the same
#: streams cut into blocks of 10^4 to 6 10^4 samples (and one block of everything)
BIG_BLOCKS = {
    "ten thousand": [10_000],
    "odd": [33_333, 12_345],
    "diagnose's": [62_500],
    "one block": [10**9],
}


def _long_session(seed: int, non_finite: bool) -> SampleBlock:
    """288 s with 24 turns, ADC errors, quantised outputs, excess noise on ax, a bias on az
    and gy stuck; ``non_finite``: and three outputs not finite."""
    traj = multi_position(n_attitudes=24, dwell_s=10.0, turn_s=2.0, rate_hz=RATE, seed=seed)
    faults = [
        Fault("bias", "az", 40.0, 600.0),
        Fault("stuck", "gy", 150.0, None),
        Fault("noise", "ax", 200.0, 4.0),
    ]
    effects = Effects(quantize=True, adc_error_rate=0.001)
    block = simulate(CERT, traj, seed=seed, faults=faults, effects=effects).samples
    if non_finite:
        rng = np.random.default_rng(seed)
        rows = rng.integers(len(block) // 3, len(block), size=3)
        block.gyro[rows[:2], rng.integers(0, 3, size=2)] = np.nan
        block.accel[rows[2], 1] = np.inf
    return block


def _feed(block: SampleBlock, sizes: list[int], *monitors: Monitor | OldMonitor):
    """Feed ``block`` cut into ``sizes`` (repeated) to every monitor; yields after each
    part (its index and first sample)."""
    start = k = 0
    while start < len(block):
        part = block.slice(start, start + sizes[k % len(sizes)])
        for m in monitors:
            m.update(part)
        yield k, start
        start += len(part)
        k += 1


def _long_faults(m: Monitor) -> None:
    causes = {(f["triad"], f.get("sensor"), f["cause"]) for f in m.active_faults}
    assert ("gyro", "gy", "stuck") in causes
    assert m.state["accel"].persistence.raised >= 1  # the az bias
    assert any(p.raised for p in m.state["accel"].noise)  # the ax noise
    assert m.adc_errors > 0


@pytest.mark.parametrize("sizes", sorted(BIG_BLOCKS))
def test_big_blocks_match_the_reference(sizes):
    """After every big block of a long faulty session the fault lists, counters and raises
    are the reference's (the reference's noise ratios differ on windows holding a
    non-finite output: those are the next test's)."""
    block = _long_session(21 + sorted(BIG_BLOCKS).index(sizes), non_finite=False)
    new, old = Monitor(CERT), OldMonitor(CERT)
    for k, start in _feed(block, BIG_BLOCKS[sizes], new, old):
        a, b = _snapshot(new), _snapshot(old)
        assert a[0] == b[0], f"{sizes}: block {k} (samples {start}..) differs"
        np.testing.assert_allclose(a[1], b[1], rtol=1e-9, atol=1e-12, equal_nan=True)
    _long_faults(new)


def test_big_blocks_give_what_daemon_reads_give():
    """The same session with outputs not finite too: fed in big blocks of every size above,
    or in the daemon's reads of 4-5 samples, the monitor ends with the same faults,
    counters and raises."""
    block = _long_session(31, non_finite=True)
    reads = Monitor(CERT)
    for _ in _feed(block, [4, 5], reads):
        pass
    want = _snapshot(reads)
    for sizes in sorted(BIG_BLOCKS):
        big = Monitor(CERT)
        for _ in _feed(block, BIG_BLOCKS[sizes], big):
            pass
        got = _snapshot(big)
        assert got[0] == want[0], sizes
        np.testing.assert_allclose(got[1], want[1], rtol=1e-9, atol=1e-12, equal_nan=True)
        _long_faults(big)

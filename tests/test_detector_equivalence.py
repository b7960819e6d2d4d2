"""The quasi-static detector's cheaper update gives the static flags of the frozen one.

``tests/reference/drift_quasistatic.py`` is the detector (with its prefix sums) as it was
when the moving-base drift tests were added (issue 15), before its per-call cost was cut
(issue 14): the reference implementation, kept in the test tree. Both detectors are fed
the same blocks, of random sizes 1..500 samples under fixed seeds, and their flags must
be equal sample for sample (and so the intervals made of them) on

- seeded simulated streams: still, multi-position (turns, hand re-orientations), with
  bias steps (the step test), ADC errors and saturation flags, non-finite samples, at
  200 Hz and 1 kHz; a certificate without noise figures (the estimate from the data);
  gyro-only on a turntable; the drift tests or the rate band off;
- the simulated car drives (urban, highway, hilly: the clean drives of
  ``tests/test_rest_without_aiding.py``, 600 s; ``IMUDIAG_EQUIV_DRIVE_S=3600`` runs the
  1 h drives of ``benchmarks/drive_hour.py``);
- the real recordings in ``tests/data/real`` (see each SOURCE.md) with the certificates
  the other tests use for them.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from imudiag.certificate import Certificate, Noise, load, load_default
from imudiag.logs import open_log
from imudiag.quasistatic import QuasiStaticDetector
from imudiag.samples import FLAG_ACCEL_SATURATED, FLAG_ADC_ERROR, SampleBlock
from imudiag.sim import Effects, Fault, multi_position, simulate, still, turntable
from imudiag.sim.scenarios import scenario_motion
from imudiag.sim.simulator import Simulator
from tests.reference.drift_quasistatic import QuasiStaticDetector as FrozenDetector

DATA = Path(__file__).parent / "data"
REAL = DATA / "real"
#: length of the simulated drives, s (the suite's: those of test_rest_without_aiding)
DRIVE_S = float(os.environ.get("IMUDIAG_EQUIV_DRIVE_S", "600"))


def _intervals(mask: np.ndarray) -> list[tuple[int, int]]:
    """The still runs of ``mask``: (first, end) sample indices."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(np.int8), [0]])))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True))


def _feed_both(
    block: SampleBlock,
    cert: Certificate,
    seed: int,
    rate: float | None,
    size: Callable[[np.random.Generator, int], int],
    options: dict[str, object],
) -> np.ndarray:
    """Feed ``block`` to the new and the frozen detector in the same blocks, of the sizes
    ``size(rng, calls)`` draws; the flags of every block and the noise figures at the end
    must be equal. Returns the whole mask."""
    new = QuasiStaticDetector(cert, rate, **options)  # type: ignore[arg-type]
    old = FrozenDetector(cert, rate, **options)  # type: ignore[arg-type]
    rng = np.random.default_rng(seed)
    n = len(block)
    out, start, calls = [], 0, 0
    while start < n:
        part = block.slice(start, min(n, start + size(rng, calls)))
        a, b = new.update(part), old.update(part)
        assert a.dtype == b.dtype == bool and a.shape == b.shape == (len(part),)
        if not np.array_equal(a, b):
            bad = np.flatnonzero(a != b)
            raise AssertionError(
                f"block {calls} (samples {start}..{start + len(part)}): flags differ at "
                f"{(start + bad[:10]).tolist()}"
            )
        out.append(a)
        start += len(part)
        calls += 1
    for name in ("gyro", "accel"):  # the noise figures (certificate or estimate) too
        s_new, s_old = new.noise_sigma(name), old.noise_sigma(name)
        assert (s_new is None) == (s_old is None)
        if s_new is not None:
            assert np.array_equal(s_new, s_old)
    return np.concatenate(out)


def _compare(
    block: SampleBlock, cert: Certificate, seed: int, rate: float | None = None, **options: object
) -> np.ndarray:
    """Feed ``block`` to both detectors in the same random blocks (1..500 samples); the
    flags of every block must be equal. Returns the whole mask."""

    def size(rng: np.random.Generator, calls: int) -> int:
        # mostly daemon-sized reads and the monitor's batches, and any size up to 500
        return int(rng.choice([rng.integers(1, 501), rng.integers(1, 21), 250]))

    return _feed_both(block, cert, seed, rate, size, options)


CERT = load_default()


def _khz() -> Certificate:
    cert = CERT.copy()
    cert.sample_rate = 1000.0
    return cert


SIM_CASES = {
    "still 200 Hz": lambda: (CERT, simulate(CERT, still(40.0, rate_hz=200), seed=1).samples),
    "still 1 kHz": lambda: (
        _khz(),
        simulate(_khz(), still(30.0, rate_hz=1000, attitude_rpy_deg=(10, -20, 30)), seed=2).samples,
    ),
    "multiposition 200 Hz": lambda: (
        CERT,
        simulate(
            CERT,
            multi_position(n_attitudes=12, dwell_s=3.0, turn_s=1.5, rate_hz=200, seed=4),
            seed=11,
            effects=Effects(quantize=True),
        ).samples,
    ),  # fmt: skip
    "multiposition 1 kHz, faults": lambda: (
        _khz(),
        simulate(
            _khz(),
            multi_position(n_attitudes=8, dwell_s=3.0, turn_s=1.0, rate_hz=1000, seed=5),
            seed=12,
            faults=[
                Fault("bias", "az", 6.0, 600.0),
                Fault("stuck", "gz", 15.0, None),
                Fault("noise", "ax", 20.0, 4.0),
            ],
        ).samples,
    ),  # fmt: skip
    "still, accel bias steps": lambda: (
        CERT,
        simulate(
            CERT,
            still(40.0, rate_hz=200, attitude_rpy_deg=(5, 10, 0)),
            seed=3,
            faults=[
                Fault("bias", "az", 10.0, 10.0 * float(CERT.accel.limits.bias[2])),
                Fault("bias", "ax", 25.0, -10.0 * float(CERT.accel.limits.bias[0])),
            ],
        ).samples,
    ),  # fmt: skip
    "multiposition, adc errors": lambda: (
        CERT,
        simulate(
            CERT,
            multi_position(n_attitudes=8, dwell_s=2.0, turn_s=1.0, rate_hz=200, seed=6),
            seed=13,
            effects=Effects(quantize=True, adc_error_rate=0.002),
        ).samples,
    ),  # fmt: skip
}


def _with_flags_and_gaps(block: SampleBlock, seed: int) -> SampleBlock:
    """Saturation flags for a while and a few non-finite outputs."""
    rng = np.random.default_rng(seed)
    flags = np.zeros(len(block), dtype=np.uint16) if block.flags is None else block.flags.copy()
    flags[2000:2600] |= FLAG_ACCEL_SATURATED
    flags[rng.integers(0, len(block), 5)] |= FLAG_ADC_ERROR
    gyro, accel = block.gyro.copy(), block.accel.copy()
    gyro[rng.integers(0, len(block), 4), rng.integers(0, 3, 4)] = np.nan
    accel[rng.integers(0, len(block), 3), 1] = np.inf
    return SampleBlock(t=block.t, gyro=gyro, accel=accel, flags=flags, temp=block.temp)


@pytest.mark.parametrize("case", sorted(SIM_CASES))
def test_simulated_streams(case):
    cert, block = SIM_CASES[case]()
    seed = sorted(SIM_CASES).index(case)
    mask = _compare(block, cert, seed)
    assert 0.2 * len(block) < mask.sum() < len(block)  # still and not still both seen
    if "multiposition" in case:
        _compare(_with_flags_and_gaps(block, seed), cert, seed + 100)


def test_noise_from_the_data_turntable_and_options():
    """Without the certificate's noise figures (the estimate per block), gyro-only on a
    turntable (the known-rate command's detector), the drift tests or the band off."""
    traj = multi_position(n_attitudes=10, dwell_s=3.0, turn_s=1.5, rate_hz=200, seed=7)
    block = simulate(CERT, traj, seed=14).samples
    bare = CERT.copy()
    bare.gyro.noise = None
    bare.accel.noise = None
    _compare(block, bare, 21)
    _compare(block, CERT, 22, certificate_noise=False)
    _compare(block, CERT, 23, drift_f0_fraction=None)
    _compare(block, CERT, 24, bias_margin=None)
    _compare(block, CERT, 25, window_s=0.3, drift_window_s=2.0, settle_s=0.2)
    table = turntable(6.0, axis="-z", duration_s=20.0, rate_hz=200)
    spun = simulate(CERT, table, seed=15).samples
    assert _compare(spun, CERT, 26, triads=("gyro",)).any()
    _compare(spun, CERT, 27)


def drive(scenario: str, seconds: float = DRIVE_S) -> SampleBlock:
    """A clean car drive of test_rest_without_aiding (seed 1, the bundled certificate's
    rate, ``seconds`` long), simulated in 10 s steps."""
    rate = float(CERT.sample_rate)
    motion = scenario_motion(scenario, 1, {"length": str(seconds)})
    total = motion.n_samples(rate)
    sim = Simulator(CERT, None, [], 1)
    chunk = int(10 * rate)
    return SampleBlock.concat([
        sim.step(motion.sample(rate, start, min(chunk, total - start)))
        for start in range(0, total, chunk)
    ])  # fmt: skip


@pytest.mark.parametrize("scenario", ["urban", "highway", "hilly"])
def test_simulated_drives(scenario):
    """The clean car drives of test_rest_without_aiding (seed 1, the certificate's rate)."""
    rate = float(CERT.sample_rate)
    mask = _compare(drive(scenario), CERT, 31 + len(scenario), rate)
    assert len(_intervals(mask)) > 5  # stops and cruises, turns and accelerations between


def _real(name: str) -> tuple[SampleBlock, Certificate]:
    like = {
        "xsens-mti-multiposition/session.csv.gz": DATA / "diagnosis" / "like-xsens.yaml",
        "imucal-ferraris/session.csv.gz": DATA / "diagnosis" / "like-imucal.yaml",
        "mpu6050/static.csv.gz": DATA / "diagnosis" / "like-mpu6050.yaml",
        "mpu6050/calibration.csv.gz": DATA / "diagnosis" / "like-mpu6050.yaml",
        "mpu6050/rot90x.csv.gz": DATA / "diagnosis" / "like-mpu6050.yaml",
        # g and deg/s, as the drive's nominal certificate
        "gnss-imu-drive/imu.csv.gz": REAL / "gnss-imu-drive" / "nominal-certificate.yaml",
        "firm-rocket-launch/flight.csv.gz": REAL / "gnss-imu-drive" / "nominal-certificate.yaml",
        # rad/s and m/s^2: the gyro turned into deg/s for the deg/s, m/s^2 certificate
        "px4-ulog/sample.ulg": DATA / "diagnosis" / "like-imucal.yaml",
        "px4-ulog/sample_log_small.ulg": DATA / "diagnosis" / "like-imucal.yaml",
        "ardupilot-dataflash/test.BIN": DATA / "diagnosis" / "like-imucal.yaml",
    }[name]
    with open_log(REAL / name) as reader:
        block = SampleBlock.concat(list(reader))
    if name.startswith(("px4", "ardupilot")):
        block = SampleBlock(t=block.t, gyro=np.degrees(block.gyro), accel=block.accel,
                            flags=block.flags, temp=block.temp)  # fmt: skip
    return block, load(like)


REAL_NAMES = [
    "xsens-mti-multiposition/session.csv.gz",
    "imucal-ferraris/session.csv.gz",
    "mpu6050/static.csv.gz",
    "mpu6050/calibration.csv.gz",
    "mpu6050/rot90x.csv.gz",
    "gnss-imu-drive/imu.csv.gz",
    "firm-rocket-launch/flight.csv.gz",
    "px4-ulog/sample.ulg",
    "px4-ulog/sample_log_small.ulg",
    "ardupilot-dataflash/test.BIN",
]


@pytest.mark.parametrize("name", REAL_NAMES)
def test_real_recordings(name):
    block, cert = _real(name)
    seed = 41 + REAL_NAMES.index(name)
    rate = cert.sample_rate
    _compare(block, cert, seed, rate)
    # with the noise figures the recording's own (the certificates above mostly have none)
    noisy = cert.copy()
    for triad in ("gyro", "accel"):
        x = block.gyro if triad == "gyro" else block.accel
        sigma = np.std(np.diff(x[: int(10 * rate)], axis=0), axis=0) / math.sqrt(2)
        noisy.triad(triad).noise = Noise(density=np.maximum(sigma, 1e-9) / math.sqrt(rate / 2))
    _compare(block, noisy, seed + 100, rate)


# -- big blocks (issue 14: ``imudiag diagnose`` feeds the detector 65536 samples at a time)


def test_prefix_sums_big_blocks_bit_for_bit():
    """The one-pass prefix sums of a block longer than the ring (``update_views``, and
    ``update`` built on it) equal the frozen chunked ones bit for bit, through the shift
    back to zero every 2^20 rows (the block that reaches it takes the chunked path)."""
    from imudiag.trailing import PrefixSums
    from tests.reference.drift_quasistatic import PrefixSums as FrozenPrefixSums

    rng = np.random.default_rng(61)
    n = (1 << 20) + 70_000
    x = rng.normal(3.0, 50.0, size=(n, 2))  # not whole numbers: roundings differ by order
    offsets = np.array([100, 2000, 200])
    new, views, old = PrefixSums(2, 2000), PrefixSums(2, 2000), FrozenPrefixSums(2, 2000)
    start, k = 0, 0
    while start < n:
        size = int(rng.choice([rng.integers(1, 300), rng.integers(10_000, 100_001)]))
        rows = x[start : start + size]
        a_now, a_back, a_idx = new.update(rows, offsets)
        v_now, v_backs, v_idx = views.update_views(rows, offsets)
        o_now, o_back, o_idx = old.update(rows, offsets)
        for got in (a_now, v_now):
            assert np.array_equal(got, o_now), f"block {k}: P differs"
        assert np.array_equal(a_idx, o_idx) and np.array_equal(v_idx, o_idx)
        assert np.array_equal(a_back, o_back), f"block {k}: P back differs"
        for j in range(len(offsets)):
            assert np.array_equal(v_backs[j], o_back[:, j]), f"block {k}: view {j} differs"
        start += len(rows)
        k += 1
    assert new._next_rebase > 1 << 20  # the shift happened


def _compare_big(block: SampleBlock, cert: Certificate, seed: int, rate: float | None = None,
                 **options: object) -> np.ndarray:  # fmt: skip
    """As :func:`_compare`, in blocks of 10^4..10^5 samples (a few daemon-sized reads
    between them, so the big blocks start anywhere in the rings; some streams start with a
    big block)."""

    def size(rng: np.random.Generator, calls: int) -> int:
        return int(rng.integers(10_000, 100_001) if (calls + seed) % 3 else rng.integers(1, 300))

    return _feed_both(block, cert, seed, rate, size, options)


@pytest.fixture(scope="module")
def drive_block() -> SampleBlock:
    """The clean urban drive of test_simulated_drives (seed 1, 600 s at the certificate's
    rate): stops, cruises, turns and re-starts."""
    return drive("urban")


def _long_multiposition() -> SampleBlock:
    traj = multi_position(n_attitudes=24, dwell_s=4.0, turn_s=1.5, rate_hz=1000, seed=8)
    return simulate(_khz(), traj, seed=16, effects=Effects(quantize=True)).samples


def test_big_blocks_simulated(drive_block):
    """Blocks of 10^4..10^5 samples: still, multi-position (with flags and non-finite
    samples), the urban drive; the certificate's noise and the estimate from the data."""
    still_1k = simulate(
        _khz(), still(150.0, rate_hz=1000, attitude_rpy_deg=(10, -20, 30)), seed=2
    ).samples
    mask = _compare_big(still_1k, _khz(), 71)
    assert 0.9 * len(still_1k) < mask.sum() < len(still_1k)
    multi = _long_multiposition()
    mask = _compare_big(multi, _khz(), 72)
    assert 0.3 * len(multi) < mask.sum() < 0.9 * len(multi)
    _compare_big(_with_flags_and_gaps(multi, 3), _khz(), 73)
    _compare_big(multi, _khz(), 74, certificate_noise=False)
    mask = _compare_big(drive_block, CERT, 75, float(CERT.sample_rate))
    assert len(_intervals(mask)) > 5
    _compare_big(drive_block, CERT, 76, float(CERT.sample_rate), certificate_noise=False)


def test_big_blocks_real_recording():
    """The real Xsens MTi multi-position session (tests/data/real/xsens-mti-multiposition)
    in big blocks, with its certificate's noise and with the estimate from the data."""
    block, cert = _real("xsens-mti-multiposition/session.csv.gz")
    mask = _compare_big(block, cert, 81, cert.sample_rate)
    assert mask.any() and not mask.all()
    _compare_big(block, cert, 82, cert.sample_rate, certificate_noise=False)

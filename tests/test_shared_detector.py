"""One still detector for two consumers of a stream (issue 14): ``imudiag diagnose`` feeds
every block to the monitor and to the interval collector, each with a still detector;
when the two would be built alike (the same certificate, rate, window, options and noise
figures) a :class:`~imudiag.quasistatic.DetectorPool` runs one and both read it.

Each reader's flags and noise figures must equal, block by block, those of a detector of
its own fed the same blocks, whatever the pace of the readers (one ahead by several
blocks, as the monitor gathers reads), with the noise fixed by the certificate or
estimated from the data (it changes as the stream goes, and each reader must see it as of
its own place), and when one reader cuts the stream differently (it goes on alone from the
detector as it was). Streams: seeded still, multi-position and car-drive sessions and the
real Xsens MTi recording (tests/data/real/xsens-mti-multiposition, see its SOURCE.md).
The end-to-end check: ``diagnose_recording`` with the shared detector writes the report
it writes with two detectors.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

import imudiag.diagnosis.session as session
from imudiag.certificate import Certificate, Noise, load_default
from imudiag.diagnosis.config import DiagnosisConfig
from imudiag.diagnosis.stream import StreamingDiagnoser
from imudiag.monitor import Monitor
from imudiag.quasistatic import DetectorPool, QuasiStaticDetector, SharedDetectorReader
from imudiag.samples import SampleBlock
from imudiag.sim import Effects, Fault, multi_position, simulate, still
from tests.test_detector_equivalence import _real, drive

CERT = load_default()


def _bare(cert: Certificate) -> Certificate:
    """The certificate without noise figures: both detectors estimate the noise."""
    out = cert.copy()
    out.gyro.noise = None
    out.accel.noise = None
    return out


STREAMS = {
    "still": lambda: simulate(CERT, still(60.0, rate_hz=200), seed=1).samples,
    "multiposition, faults": lambda: (
        simulate(
            CERT,
            multi_position(n_attitudes=16, dwell_s=3.0, turn_s=1.5, rate_hz=200, seed=4),
            seed=11,
            effects=Effects(quantize=True, adc_error_rate=0.001),
            faults=[Fault("bias", "az", 20.0, 10.0 * float(CERT.accel.limits.bias[2]))],
        ).samples
    ),
    "urban drive": lambda: drive("urban", 300.0),
}


def _cuts(n: int, rng: np.random.Generator, big: bool) -> list[int]:
    """Block sizes covering ``n`` samples: daemon-sized reads or diagnose-sized blocks."""
    sizes = []
    while sum(sizes) < n:
        sizes.append(int(rng.integers(5_000, 30_001) if big else rng.integers(1, 501)))
    return sizes


Readers = tuple[SharedDetectorReader, SharedDetectorReader]


def _check_readers(block: SampleBlock, cert: Certificate, seed: int, rate: float | None = None,
                   join_from: int | None = None, options_b: dict | None = None,
                   **options: object) -> Readers:  # fmt: skip
    """Two readers of one pool against two detectors of their own, same blocks. Reader A
    runs ahead by 0..3 blocks at times, B at others; from block ``join_from`` on B feeds two
    of A's blocks joined (the later of the two to get there must go on alone). B's detector
    has ``options_b`` when given (then only the window sums are shared). Returns the
    readers (A, B)."""
    opts_b = options if options_b is None else options_b
    pool = DetectorPool()
    a = pool.detector(cert, rate, **options)
    b = pool.detector(cert, rate, **opts_b)
    if options_b is None:
        assert a.shared is b.shared  # alike: one detector
    else:  # the noise differs: one run of window sums
        assert a.shared is not b.shared
        assert a.window_run is not None and a.window_run is b.window_run
    own_a = QuasiStaticDetector(cert, rate, **options)  # type: ignore[arg-type]
    own_b = QuasiStaticDetector(cert, rate, **opts_b)  # type: ignore[arg-type]
    rng = np.random.default_rng(seed)
    n = len(block)
    edges = np.cumsum([0] + _cuts(n, rng, big=seed % 2 == 0))
    parts = [block.slice(int(s), int(e)) for s, e in zip(edges[:-1], edges[1:], strict=False)]
    parts = [p for p in parts if len(p)]
    b_parts: list[SampleBlock] = []
    i = 0
    while i < len(parts):
        if join_from is not None and i >= join_from and i + 1 < len(parts):
            b_parts.append(SampleBlock.concat(parts[i : i + 2]))
            i += 2
        else:
            b_parts.append(parts[i])
            i += 1
    fed_a = fed_b = 0
    while fed_b < len(b_parts):
        lead = int(rng.integers(0, 4))  # A runs ahead by up to 3 blocks, then B catches up
        for _ in range(lead):
            if fed_a < len(parts):
                got, want = a.update(parts[fed_a]), own_a.update(parts[fed_a])
                assert np.array_equal(got, want), f"reader A, block {fed_a}"
                for triad in ("gyro", "accel"):
                    _same_sigma(a.noise_sigma(triad), own_a.noise_sigma(triad))
                fed_a += 1
        got, want = b.update(b_parts[fed_b]), own_b.update(b_parts[fed_b])
        assert np.array_equal(got, want), f"reader B, block {fed_b}"
        for triad in ("gyro", "accel"):
            _same_sigma(b.noise_sigma(triad), own_b.noise_sigma(triad))
        fed_b += 1
    for part in parts[fed_a:]:
        assert np.array_equal(a.update(part), own_a.update(part))
    return a, b


def _same_sigma(got: np.ndarray | None, want: np.ndarray | None) -> None:
    assert (got is None) == (want is None)
    if want is not None:
        assert np.array_equal(got, want)


@pytest.mark.parametrize("name", sorted(STREAMS))
def test_two_readers_equal_two_detectors(name):
    block = STREAMS[name]()
    seed = sorted(STREAMS).index(name)
    a, b = _check_readers(block, CERT, 2 * seed)  # diagnose-sized blocks
    assert not a.alone and not b.alone  # one run all along
    _check_readers(block, CERT, 2 * seed + 1)  # daemon-sized reads
    # the noise estimated from the data: it changes, each reader sees it at its own place
    _check_readers(block, _bare(CERT), 2 * seed + 10)
    _check_readers(block, CERT, 2 * seed + 20, certificate_noise=False)
    # the monitor's (the certificate's noise) and the collector's (the data's) in diagnose
    for s in (2 * seed + 30, 2 * seed + 31):
        a, b = _check_readers(block, CERT, s, options_b={"certificate_noise": False})
        assert not a.alone and not b.alone


def test_reader_cutting_differently_goes_on_alone():
    """Two blocks joined change the prefix sums' roundings (and the data's noise estimate,
    one quantile per block): that reader continues from a copy of the detector."""
    block = STREAMS["multiposition, faults"]()
    for cert, seed, join_from in ((CERT, 31, 3), (_bare(CERT), 33, 2)):  # small reads
        a, b = _check_readers(block, cert, seed, join_from=join_from)
        assert a.alone != b.alone  # one went alone
    # sharing the window sums only: one of the two stages went alone
    a, b = _check_readers(block, CERT, 35, join_from=3, options_b={"certificate_noise": False})
    run = a.window_run
    assert run is not None and sum(r.own is not None for r in run.readers) == 1


def test_real_recording():
    block, cert = _real("xsens-mti-multiposition/session.csv.gz")
    a, b = _check_readers(block, cert, 40, cert.sample_rate)
    assert not a.alone and not b.alone
    _check_readers(block, cert, 41, cert.sample_rate, certificate_noise=False)
    # with noise figures (the recording's own), the certificate's against the data's
    noisy = cert.copy()
    rate = float(cert.sample_rate)
    for triad in ("gyro", "accel"):
        x = block.gyro if triad == "gyro" else block.accel
        sigma = np.std(np.diff(x[: int(10 * rate)], axis=0), axis=0) / math.sqrt(2)
        noisy.triad(triad).noise = Noise(density=np.maximum(sigma, 1e-9) / math.sqrt(rate / 2))
    _check_readers(block, noisy, 42, rate, options_b={"certificate_noise": False})
    a, b = _check_readers(block, cert, 43, cert.sample_rate, join_from=4)
    assert a.alone != b.alone


def test_pool_shares_only_alike_detectors():
    """Different noise figures, window or certificate object: separate runs; the default
    arguments and explicit equal ones: one run. A reader asked for after the stream
    started gets a run of its own."""
    pool = DetectorPool()
    a = pool.detector(CERT, 200.0, window_s=0.5)
    assert pool.detector(CERT, None, window_s=0.5, k_sigma=4.0).shared is a.shared
    # the certificate's noise against the data's: different detectors
    assert pool.detector(CERT, 200.0, certificate_noise=False).shared is not a.shared
    assert pool.detector(CERT, 200.0, window_s=0.3).shared is not a.shared
    assert pool.detector(CERT.copy(), 200.0).shared is not a.shared
    # without noise figures the option changes nothing: alike
    bare = _bare(CERT)
    c = pool.detector(bare, 200.0)
    assert pool.detector(bare, 200.0, certificate_noise=False).shared is c.shared
    a.update(simulate(CERT, still(2.0, rate_hz=200), seed=1).samples)
    assert pool.detector(CERT, 200.0).shared is not a.shared


def test_monitor_alone_keeps_its_own_detector():
    """The daemon's monitor (no pool) builds the plain detector, as before."""
    assert type(Monitor(CERT).detector) is QuasiStaticDetector


def _report(path, monkeypatch, share: bool, **kw: object) -> str:
    if not share:  # no pool: the monitor and the collector build detectors of their own
        monkeypatch.setattr(session, "DetectorPool", lambda: None)
    report = session.diagnose_recording(path, CERT, DiagnosisConfig(), **kw)  # type: ignore[arg-type]
    monkeypatch.undo()
    return json.dumps(report, sort_keys=True)


def test_diagnose_report_unchanged_by_sharing(tmp_path, monkeypatch):
    """``diagnose_recording`` with the certificate's noise (the two detectors alike, so one
    runs) writes the report it writes with two detectors, byte for byte; also in blocks
    smaller than the monitor's batch (the monitor may join them: its reader goes alone);
    and on the default path (the monitor's detector trusts the certificate's noise, the
    collector's measures the data's: the window sums shared)."""
    from imudiag.logs import open_writer

    traj = multi_position(n_attitudes=14, dwell_s=3.0, turn_s=1.5, rate_hz=200, seed=9)
    faults = [Fault("bias", "ax", 0.0, 4 * CERT.accel.limits.bias[0])]
    sim = simulate(CERT, traj, seed=19, faults=faults)
    path = tmp_path / "session.npz"
    with open_writer(path, {"sample_rate": 200.0, "units": "gyro=count accel=count"}) as w:
        w.write(sim.samples)
    for kw in (
        {"certificate_noise": True},
        {"certificate_noise": True, "block_size": 20},
        {"certificate_noise": False},  # the default: the window sums shared
        {"certificate_noise": False, "block_size": 20},
    ):
        shared = _report(path, monkeypatch, True, **kw)
        alone = _report(path, monkeypatch, False, **kw)
        assert shared == alone, kw
        assert '"verdict"' in shared


def test_streaming_diagnoser_and_monitor_share(monkeypatch):
    """In the session's arrangement (the monitor first, then the diagnoser, both from one
    pool, every block to both) the two read one run of the detector."""
    pool = DetectorPool()
    mon = Monitor(CERT, rate_hz=200.0, detectors=pool)
    diag = StreamingDiagnoser(
        CERT, DiagnosisConfig(), rate_hz=200.0, certificate_noise=True, detectors=pool
    )
    assert isinstance(mon.detector, SharedDetectorReader)
    assert mon.detector.shared is diag.collector.detector.shared  # type: ignore[union-attr]
    block = simulate(CERT, still(20.0, rate_hz=200), seed=5).samples
    for i in range(0, len(block), 1000):
        mon.update(block.slice(i, i + 1000))
        diag.update(block.slice(i, i + 1000))
    assert not mon.detector.alone and not mon.detector.shared.entries
    # as diagnose builds them: the collector measures the noise, so only the sums are shared
    pool = DetectorPool()
    mon = Monitor(CERT, rate_hz=200.0, detectors=pool)
    diag = StreamingDiagnoser(
        CERT, DiagnosisConfig(), rate_hz=200.0, certificate_noise=False, detectors=pool
    )
    assert isinstance(mon.detector, SharedDetectorReader)
    assert mon.detector.window_run is not None
    assert mon.detector.window_run is diag.collector.detector.window_run  # type: ignore[union-attr]
    for i in range(0, len(block), 1000):
        mon.update(block.slice(i, i + 1000))
        diag.update(block.slice(i, i + 1000))
    assert not mon.detector.window_run.entries  # nothing kept once both passed
    assert math.isclose(diag.collector.static_samples, mon.f0_checked["accel"], rel_tol=0.01)

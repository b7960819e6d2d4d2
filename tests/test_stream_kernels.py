"""The stream passes compiled for the fleet (issue 28, numba from the ``fleet`` extra)
against the plain numpy they replace where the kernels are on, all equal bit for bit
(``==`` on the bytes, not a tolerance):

- the prefix sums (:class:`imudiag.trailing.PrefixSums`, the still detector's window sums
  and the monitor's gyro sums): :func:`imudiag.numba_kernels.chunked_cumsum` makes the same
  additions in the same order as the plain chunk-by-chunk ``np.cumsum`` then ``+= last``,
  and :func:`imudiag.numba_kernels.stack_backs` the same copies as ``np.stack``: the prefix
  sums, the sums ``offsets`` rows back and the carried state, on seeded random streams cut
  into random blocks (rows of 1 to 40 000: the chunked, the gathered and the one-pass ways,
  across the shift back to zero every 2^20 rows), with columns of very different sizes
  (where the order of a sum shows);
- the vibration meter's high-pass (:func:`imudiag.numba_kernels.highpass_squares`, and on a
  block as it is, :func:`imudiag.numba_kernels.highpass_parts`);
- the stuck check's scan and its episodes (:func:`imudiag.numba_kernels.stuck_scan`,
  :func:`imudiag.numba_kernels.stuck_episodes`);
- the monitor's turning flags (:func:`imudiag.numba_kernels.turning_rows`) and its MEMS
  rest-rate check (:func:`imudiag.numba_kernels.rest_rate_rows`), and a whole monitor's
  judgements with the kernels and without;
- the noise figures' clipping (:func:`imudiag.numba_kernels.clipped_sigmas`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("numba", reason="numba (the fleet extra) is not installed")

from imudiag import kernels  # noqa: E402
from imudiag.trailing import PrefixSums  # noqa: E402
from tests.helpers import random_blocks  # noqa: E402


def _blocks(rng: np.random.Generator, n: int) -> list[int]:
    """Block sizes summing to n: single rows, reads, and blocks beyond the buffer's span."""
    return random_blocks(rng, n, 3000, 40_000)


def _feed(on: bool, rows: np.ndarray, sizes: list[int], width: int, reach: int,
          offsets: np.ndarray, views: bool) -> list[np.ndarray]:  # fmt: skip
    """Every output of a PrefixSums fed ``rows`` in ``sizes`` with the kernels ``on``, and
    its state after each block."""
    out: list[np.ndarray] = []
    with kernels.switched(on) as got:
        assert got == on, kernels.status()
        ps = PrefixSums(width, reach)
        a = 0
        for size in sizes:
            block = rows[a : a + size]
            a += size
            if views:
                now, backs, idx = ps.update_views(block, offsets)
                out += [now, *backs, idx]
            else:
                now, back, idx = ps.update(block, offsets)
                out += [now, back, idx]
            out += [ps._p.copy(), ps._last.copy()]
    return out


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("views", [True, False])
def test_prefix_sums_bit_for_bit(seed: int, views: bool) -> None:
    rng = np.random.default_rng(1000 + seed)
    width = int(rng.choice([1, 5, 13]))
    reach = int(rng.integers(3, 600))
    n = 1_200_000 if seed == 0 else int(rng.integers(50_000, 200_000))  # seed 0: the rebase
    # values of very different sizes per column (ADC counts, squares, flags)
    scale = 10.0 ** rng.uniform(-6, 6, width)
    rows = rng.normal(0.0, 1.0, (n, width)) * scale + rng.normal(0.0, 1.0, width) * scale
    rows[:, -1] = rng.random(n) < 0.01  # a 0/1 column, as the bad-sample counts
    offsets = np.unique(rng.integers(1, reach + 1, 3)).astype(np.int64)
    sizes = _blocks(rng, n)
    plain = _feed(False, rows, sizes, width, reach, offsets, views)
    compiled = _feed(True, rows, sizes, width, reach, offsets, views)
    assert len(plain) == len(compiled)
    for p, c in zip(plain, compiled, strict=True):
        assert p.shape == c.shape
        assert p.tobytes() == c.tobytes()  # bit for bit (the sign of a zero included)


def test_compiled_pass_is_used() -> None:
    """The compiled pass runs on a block beyond the buffer's span (not only the plain one)."""
    with kernels.switched(True) as on:
        assert on, kernels.status()
        assert kernels.kernel("chunked_cumsum") is not None
        assert kernels.kernel("stack_backs") is not None
        ps = PrefixSums(2, 10)
        assert ps.whole(5000)
        rows = np.ones((5000, 2))
        now, back, _ = ps.update(rows, np.array([1, 10]))
        assert now[-1].tolist() == [5000.0, 5000.0]
        assert back[-1, 1].tolist() == [4990.0, 4990.0]


@pytest.mark.parametrize("seed", range(4))
def test_vibration_meter_bit_for_bit(seed: int) -> None:
    """The vibration meter's high-pass (:func:`imudiag.numba_kernels.highpass_squares`): the
    same operations in the same order, so every window level, the peak, the counts and the
    window being filled are equal bit for bit, on seeded raw streams (ADC counts of the
    default certificate, vibration, non-finite values) in random blocks (1 row to 40 000)."""
    from imudiag.certificate import load_default
    from imudiag.samples import SampleBlock
    from imudiag.vibration import VibrationMeter

    rng = np.random.default_rng(2000 + seed)
    rate = float(rng.choice([100.0, 400.0, 1000.0]))
    n = int(rng.integers(30_000, 150_000))
    raw = rng.normal(0.0, 30.0, (n, 6)) + rng.normal(0.0, 2000.0, 6)
    raw += 500.0 * np.sin(np.arange(n)[:, None] * rng.uniform(0.1, 2.0, 6))
    raw[rng.random((n, 6)) < 2e-4] = np.nan
    raw[rng.random(n) < 1e-4, 3] = np.inf
    t = np.arange(n) / rate
    sizes = _blocks(rng, n)
    states = []
    for on in (False, True):
        with kernels.switched(on) as got:
            assert got == on, kernels.status()
            meter = VibrationMeter(load_default(), rate)
            out = []
            a = 0
            for size in sizes:
                sl = slice(a, a + size)
                a += size
                meter.update(SampleBlock(t=t[sl], gyro=raw[sl, :3], accel=raw[sl, 3:]))
                last = meter.last if meter.last is not None else np.zeros(0)
                out += [last.tobytes(), meter.peak.tobytes(), meter._sumsq.tobytes(),
                        meter._tail.tobytes(), meter.windows, meter.high_windows]  # fmt: skip
            states.append(out)
    assert meter.windows > 10
    assert states[0] == states[1]


@pytest.mark.parametrize("seed", range(4))
def test_stuck_check_identical(seed: int) -> None:
    """The stuck check's scan (:func:`imudiag.numba_kernels.stuck_scan`): differences, minima
    and counts, so the runs, quantisation steps, repeat counts, times in force and the stuck
    channels are identical, on seeded streams of counts and of quantised and float physical
    outputs with stuck runs and non-finite values, fed as the monitor feeds it (a slice of a
    wider array after the noise history) in random blocks."""
    from imudiag.monitor.stuck import StuckCheck

    rng = np.random.default_rng(3000 + seed)
    n = int(rng.integers(20_000, 80_000))
    raw = np.round(rng.normal(0.0, 3.0, (6, n)))  # counts
    raw[1] = np.round(rng.normal(0.0, 0.4, n))  # counts with many repeats
    raw[4] = np.round(rng.normal(9.81, 0.02, n) / 0.0012) * 0.0012  # a quantised output
    raw[5] = rng.normal(0.0, 0.01, n)  # a float output
    raw[rng.random((6, n)) < 1e-4] = np.nan
    raw[rng.random((6, n)) < 2e-5] = np.inf
    for _ in range(12):  # stuck runs, short and long (over the non-finite values)
        j, a = int(rng.integers(0, 6)), int(rng.integers(0, n - 1))
        length = int(rng.choice([rng.integers(5, 100), rng.integers(100, 20_000)]))
        raw[j, a : a + length] = raw[j, a]
    t = np.arange(n) / 100.0
    sizes = _blocks(rng, n)
    counts = np.array([True, True, True, True, False, False])
    states = []
    for on in (False, True):
        with kernels.switched(on) as got:
            assert got == on, kernels.status()
            check = StuckCheck((np.full(3, 3.0), np.full(3, 0.02)), 1.0, 50, counts, 200, 0.5)
            out = []
            a, seen = 0, 0
            for size in sizes:
                wide = np.empty((6, 7 + size))  # the monitor's slice after its history
                wide[:, 7:] = raw[:, a : a + size]
                active = check.update(wide[:, 7:], t[a : a + size])
                a += size
                seen += int(active.any())
                parts = (active, check.run, check.quantum, check.pairs, check.repeats,
                         check.t_first, check.last, check.enabled, check.raised,
                         check.t_first_raised)  # fmt: skip
                out += [p.tobytes() for p in parts]
            states.append(out)
    assert states[0] == states[1]
    assert seen > 0  # some blocks end stuck
    assert check.raised.sum() > 0  # and episodes were counted (also inside blocks)


@pytest.mark.parametrize("seed", range(3))
def test_turning_rows_bit_for_bit(seed: int) -> None:
    """The monitor's turning flags (:func:`imudiag.numba_kernels.turning_rows`) against the
    numpy path's operations (:meth:`imudiag.monitor.Monitor._slow_stage`), on seeded prefix
    sums of rates of very different sizes (where the order of the sum of squares shows), as
    views of a wider array and contiguous, with bad samples and without, at gates from
    always to never turning."""
    from imudiag.numba_kernels import turning_rows

    rng = np.random.default_rng(4000 + seed)
    n = 50_000
    rates = rng.normal(size=(n, 3)) * rng.uniform(1e-4, 1e3, size=(n, 3))
    wide = np.zeros((n + 30, 7))
    wide[30:, 1:4] = np.cumsum(rates, axis=0)
    wide[30:, 5] = np.cumsum(rng.random(n) < 1e-3)  # bad samples, counted
    now, b2, b3 = wide[30:, 1:6], wide[20:-10, 1:6], wide[15:-15, 1:6]
    m, per_s = 5, 100.0 / 5
    for gate in (0.0, 1.0, 50.0, np.inf):
        for bad in (False, True):
            d = np.multiply(2.0, b2[:, :3])
            np.subtract(now[:, :3], d, out=d)
            d += b3[:, :3]
            alpha = np.einsum("ij,ij->i", d, d)
            np.sqrt(alpha, out=alpha)
            alpha *= per_s
            alpha /= m
            if bad:
                alpha[now[:, 4] - b3[:, 4] > 0] = np.nan
            want = (~(alpha <= gate))[:, None].astype(float)
            for layout in ((now, b2, b3), (now.copy(), b2.copy(), b3.copy())):
                got = turning_rows(*layout, per_s, m, gate, bad)
                assert got.tobytes() == want.tobytes(), (gate, bad)


@pytest.mark.parametrize("seed", range(6))
def test_history_extremes_queues_equal_the_scan(seed: int) -> None:
    """The trailing spreads' history extremes by monotonic queues
    (:func:`imudiag.numba_kernels._history_extremes`) against the scan of each history they
    replace (:func:`imudiag.numba_kernels._history_extremes_scan`): equal bit for bit where
    finite (the same element: the earliest of equal values, so the sign of a zero too), nan
    at the same places, on seeded kept values with ties, signed zeros, infinities and nans,
    histories of 1 to 300 values, starts that restart forwards and (seed 0, 3) move back."""
    from imudiag import numba_kernels as nk

    rng = np.random.default_rng(4000 + seed)
    total, c = int(rng.integers(200, 3000)), int(rng.integers(1, 5))
    d_val = np.round(rng.normal(0.0, 2.0, (total, 2 * c)))  # many ties
    d_val[rng.random((total, 2 * c)) < 0.05] = -0.0
    d_val[rng.random((total, 2 * c)) < 0.01] = np.nan
    d_val[rng.random((total, 2 * c)) < 0.005] = np.inf
    d_val[rng.random((total, 2 * c)) < 0.005] = -np.inf
    step = int(rng.integers(1, 6))
    d_idx = np.arange(total, dtype=np.int64) * step
    restarts = np.where(rng.random(total) < 0.02, d_idx + step * rng.integers(0, 20, total), 0)
    d_start = np.maximum.accumulate(restarts).astype(np.int64)
    if seed % 3 == 0:  # starts that move back
        d_start = np.where(rng.random(total) < 0.05, d_start // 2, d_start).astype(np.int64)
    k = int(rng.integers(1, 300))
    for old in (0, int(rng.integers(1, total))):
        got = [np.full((total, c), 7.0) for _ in range(2)]
        want = [np.full((total, c), 7.0) for _ in range(2)]
        nk._history_extremes(d_idx, d_val, d_start, got[0], got[1], old, k, c)
        nk._history_extremes_scan(d_idx, d_val, d_start, want[0], want[1], old, k, c)
        for g, w in zip(got, want, strict=True):
            assert np.array_equal(np.isnan(g), np.isnan(w))
            fin = ~np.isnan(w)
            assert g[fin].tobytes() == w[fin].tobytes()


@pytest.mark.parametrize("seed", range(3))
def test_noise_second_differences_bit_for_bit(seed: int) -> None:
    """The noise judge's squared second differences
    (:func:`imudiag.numba_kernels.second_diff_squares`) against ``np.diff(n=2)`` squared, as
    the judge takes them, bit for bit: counts, physical outputs of very different sizes,
    non-finite values, a slice of a wider array and a row too short for a difference."""
    rng = np.random.default_rng(5000 + seed)
    m = int(rng.integers(3, 50_000))
    chan = rng.normal(0.0, 1.0, (6, m)) * 10.0 ** rng.uniform(-6, 6, (6, 1))
    chan[:3] = np.round(chan[:3] * 1e3)
    chan[rng.random((6, m)) < 1e-3] = np.nan
    chan[rng.random((6, m)) < 1e-4] = -np.inf
    compiled = kernels.load() and kernels._KERNELS["second_diff_squares"]
    assert compiled, kernels.status()
    for x in (chan, np.ascontiguousarray(chan[:, 1:]), chan[:, :2].copy()):
        want = np.diff(x, n=2, axis=1)
        np.square(want, out=want)
        got = compiled(x)
        assert got.shape == want.shape
        assert got.tobytes() == want.tobytes()


def test_the_warm_up_covers_what_diagnose_passes(tmp_path: Path) -> None:
    """After the kernels' warm-up (:func:`imudiag.numba_kernels.warm_up`, a fleet worker's)
    a diagnosis with the kernels on compiles nothing more: no kernel gets a specialisation
    (an array layout) the warm-up did not run, on a simulated board log (the fleet task's
    path) and a simulated drive with its GNSS track (the moving-base part; its epochs' mid
    rotations were an array of their own, compiled inside the first drive's task before)."""
    import imudiag
    from imudiag.aiding.tpv import parse_tpv, track_from_reports
    from imudiag.certificate import load_default
    from imudiag.fleet.simulate import write_flight
    from imudiag.fleet.task import Job, diagnose_log
    from imudiag.sim.drive import simulate_drive

    assert kernels.load(), kernels.status()
    compiled = {k: f for k, f in kernels._KERNELS.items() if hasattr(f, "signatures")}
    before = {k: len(f.signatures) for k, f in compiled.items()}
    cert = load_default()
    # a board log of one block, and CSV logs of a block and a short second one (whose
    # prefix sums are an array of their own beside the carried ones' views: a CSV log of
    # the simulated fleet compiled the monitor's kernels again for it)
    logs = [tmp_path / "board.npz", tmp_path / "board.csv", tmp_path / "longer.csv.gz"]
    for log, seconds in zip(logs, (600.0, 671.8, 700.0), strict=True):
        write_flight(log, cert, "multiposition", seconds, 100.0, [], 5, {"sample_rate": 100.0})
    res, reports, _ = simulate_drive("urban", 300.0, cert, 3, 100.0)
    track = track_from_reports([parse_tpv(r) for r in reports])
    with kernels.switched(True):
        for log in logs:
            st = log.stat()
            record = diagnose_log(Job(str(log), "-", st.st_size, st.st_mtime_ns, str(tmp_path)))
            assert record["status"] == "ok", record
        report = imudiag.diagnose(res.samples, None, gnss=track)
        assert report.get("moving_base")
    after = {k: len(f.signatures) for k, f in compiled.items()}
    assert after == before


@pytest.mark.parametrize("seed", range(2))
def test_the_monitor_judges_the_same_with_the_kernels(seed: int) -> None:
    """A whole monitor (:class:`imudiag.monitor.Monitor`: its turning flags, MEMS rest-rate
    check, stuck episodes, vibration and noise checks, compiled or not) fed the same seeded
    session in random blocks, with a gyro bias fault that fails the rest-rate check and a
    stuck accelerometer run: every counter, the last values, the worst axis, each check's
    values in the F0 trace and the faults equal, with the kernels and without."""
    from imudiag.certificate import load_default
    from imudiag.monitor import Monitor
    from imudiag.sim import Effects, Fault, multi_position, simulate

    cert = load_default()
    rng = np.random.default_rng(5000 + seed)
    traj = multi_position(n_attitudes=10, dwell_s=20.0, turn_s=2.0, rate_hz=100, seed=seed)
    faults = [Fault("bias", "gy", 3.0, 150.0), Fault("stuck", "ax", 80.0)]
    samples = simulate(cert, traj, seed=50 + seed, faults=faults, effects=Effects()).samples
    sizes = _blocks(rng, len(samples))
    results = []
    for on in (False, True):
        with kernels.switched(on) as got:
            assert got == on, kernels.status()
            monitor = Monitor(cert, rate_hz=100.0)
            trace = monitor.keep_f0_trace()
            a = 0
            for size in sizes:
                monitor.update(samples.slice(a, a + size))
                a += size
            monitor.flush()
            state = monitor.state
            out = []
            for name in ("gyro", "accel"):
                st = state[name]
                out += [st.checked, st.failed, st.last_f0, st.sum_f0_sq, st.worst_axis,
                        st.noise_judged, st.noise_not_at_rest, st.stuck_active.tobytes(),
                        st.noise_ratio_last.tobytes()]  # fmt: skip
                for part in (trace[name].passed, trace[name].failed):
                    out += [np.concatenate(part._t or [np.zeros(0)]).tobytes(),
                            np.concatenate(part._v or [np.zeros(0)]).tobytes()]  # fmt: skip
            out.append(repr(monitor.active_faults))
            out.append(repr(monitor.stuck_faults()))
            results.append(out)
    assert results[0] == results[1]
    gyro = results[0][:5]
    assert gyro[0] > 0 and gyro[1] > 0  # the rest-rate check ran, and failed on the fault
    assert "ax" in results[0][-1]  # and the stuck accelerometer was found


@pytest.mark.parametrize("seed", range(3))
def test_the_noise_figures_clipping_bit_for_bit(seed: int) -> None:
    """The noise figures' last steps (:func:`imudiag.numba_kernels.clipped_sigmas` behind
    :func:`imudiag.noise_estimate.second_difference_sigmas`): the same sigmas, bit for bit,
    on seeded chunks of white noise, with outliers beyond the clip, quantised outputs whose
    MAD is 0 (the RMS then), constant channels (nothing to clip) and values of very
    different sizes (where the order of the sums shows)."""
    from imudiag.noise_estimate import second_difference_sigmas

    rng = np.random.default_rng(6000 + seed)
    for trial in range(30):
        k, n = int(rng.integers(1, 300)), int(rng.choice([8, 100, 400]))
        chunks = rng.normal(size=(k, n, 6)) * 10.0 ** rng.uniform(-3, 4, size=6)
        chunks[rng.random((k, n, 6)) < 0.01] *= 50.0  # outliers
        if trial % 3 == 0:
            chunks[:, :, 1] = np.round(chunks[:, :, 1] / 1e6)  # mostly equal: MAD 0
            chunks[:, :, 2] = 7.0  # constant: nothing at all
            chunks[0, n // 2, 2] = 9.0  # one spike in a constant chunk
        got = []
        for on in (False, True):
            with kernels.switched(on) as active:
                assert active == on, kernels.status()
                got.append(second_difference_sigmas(chunks.copy()).tobytes())
        assert got[0] == got[1], trial

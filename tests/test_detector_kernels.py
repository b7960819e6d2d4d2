"""The still detector's compiled parts (issue 28, numba from the ``fleet`` extra) against the
plain numpy they replace where the kernels are on:

- the trailing spreads (:func:`imudiag.numba_kernels.trailing_spread` behind
  :class:`imudiag.quasistatic.spread.TrailingSpread`): max and min are exact, so the spreads
  are the same numbers (``==``: the sign of a zero aside), on seeded random streams
  (restarts, values that are not finite, blocks of 1 row to 20 000 rows: both of the plain
  path's ways);
- the histories' starts (:func:`imudiag.numba_kernels.history_starts`): the same integers;
- the data-noise estimate's quantile (:func:`imudiag.numba_kernels.masked_quantile`):
  numpy's, bit for bit;
- the jump test (:func:`imudiag.numba_kernels.jump_test`): the same element-wise operations
  and three-term sums in numpy's order, so the same flags, on random window sums with
  noise variances of very different sizes (where the order of a sum shows);
- the detector's static flags, identical on the real recordings of tests/data/real (fed in
  random blocks and in one block)."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("numba", reason="numba (the fleet extra) is not installed")

from imudiag import kernels  # noqa: E402
from imudiag.certificate import Certificate  # noqa: E402
from imudiag.quasistatic import QuasiStaticDetector, TrailingSpread  # noqa: E402
from imudiag.samples import SampleBlock  # noqa: E402
from tests.helpers import random_blocks  # noqa: E402
from tests.test_detector_equivalence import REAL_NAMES, _real  # noqa: E402


@pytest.fixture
def switch():
    """``switch(on)`` turns the kernels on or off; the process's choice restored after."""
    was = kernels.enabled()

    def turn(on: bool) -> None:
        assert kernels.enable(on) == on, kernels.status()

    yield turn
    kernels.enable(was)


def stream(seed: int, n: int, columns: int):
    """Values (n, C) with steps and non-finite rows, and monotone history starts (n,)."""
    rng = np.random.default_rng(seed)
    values = np.cumsum(rng.normal(0.0, 0.1, (n, columns)), axis=0)
    values[rng.random(n) < 0.002] = np.nan
    values[rng.random(n) < 0.001, 0] = np.inf
    rows = np.arange(n)
    span = int(rng.integers(20, 400))
    restarts = np.maximum.accumulate(np.where(rng.random(n) < 0.003, rows + 5, 0))
    return values, np.maximum(restarts, rows - span), span


def blocks(rng: np.random.Generator, n: int) -> list[int]:
    """Block sizes summing to n: small reads and big blocks (beyond the repeat threshold)."""
    return random_blocks(rng, n, 500, 20_000)


@pytest.mark.filterwarnings("ignore:invalid value:RuntimeWarning")  # inf - inf, plain path
@pytest.mark.parametrize("seed", range(8))
def test_trailing_spread_kernel_equals_plain(seed, switch):
    values, start, span = stream(seed, 60_000, 1 + seed % 4)
    step = 1 + seed % 5 * 3
    results, states = [], []
    for on in (False, True):
        switch(on)
        spread = TrailingSpread(values.shape[1], step, span)
        rng = np.random.default_rng(100 + seed)
        out, first = [], 0
        for size in blocks(rng, values.shape[0]):
            out.append(
                spread.update(first, values[first : first + size], start[first : first + size])
            )
            first += size
        results.append(np.concatenate(out))
        states.append((spread._idx, spread._val, spread._start, spread._max, spread._min))
    plain, fast = results
    assert np.any(plain > 0)
    np.testing.assert_array_equal(fast, plain)
    for a, b in zip(states[1], states[0], strict=True):
        np.testing.assert_array_equal(a, b)


def flags(block: SampleBlock, cert, sizes: list[int] | None) -> np.ndarray:
    det = QuasiStaticDetector(cert, rate_hz=cert.sample_rate)
    if sizes is None:
        return det.update(block)
    out, first = [], 0
    for size in sizes:
        out.append(det.update(block.slice(first, first + size)))
        first += size
    return np.concatenate(out)


@pytest.mark.parametrize("name", REAL_NAMES)
def test_detector_flags_with_the_kernel_equal_plain_on_real_recordings(name, switch):
    block, cert = _real(name)
    sizes = blocks(np.random.default_rng(7), len(block))
    for how in (sizes, None):
        switch(False)
        plain = flags(block, cert, how)
        switch(True)
        fast = flags(block, cert, how)
        np.testing.assert_array_equal(fast, plain)


@pytest.mark.parametrize("seed", range(4))
def test_jump_test_kernel_equals_plain(seed, switch):
    from imudiag.certificate import load_default

    det = QuasiStaticDetector(load_default(), rate_hz=100.0)
    w = det.window
    rng = np.random.default_rng(70 + seed)
    jumps = 0
    for case in range(100):
        m = int(rng.integers(1, 3000))
        sums = rng.normal(size=(m, 13)) * 10 ** rng.uniform(-3, 3) * w
        back_w = rng.normal(size=(m, 13)) * 10 ** rng.uniform(-3, 3) * w
        back_2w = back_w - rng.normal(size=(m, 13)) * w * rng.uniform(0.0, 3.0)
        back_w[:, 9:12] = back_2w[:, 9:12] + np.abs(rng.normal(size=(m, 3))) * w * rng.uniform(0, 5)
        if case % 5 == 0:
            sums[rng.integers(0, m)] = np.nan
        still = rng.random(m) < 0.8
        sigma2 = 10.0 ** rng.uniform(-8.0, 8.0, 3) if case % 2 else rng.uniform(0.1, 3.0, 3)
        first = int(rng.integers(0, 300))
        out = []
        for on in (False, True):
            switch(on)
            out.append(det._jump(first, sums, back_w, back_2w, still, sigma2))
        np.testing.assert_array_equal(out[1], out[0])
        jumps += int(out[0].sum())
    assert jumps > 1000


def test_window_moments_kernel_equals_plain(switch):
    """The windows' variances and means (:class:`imudiag.quasistatic.WindowStats`), compiled
    and plain, element for element, on a random stream with non-finite samples and whole
    ADC counts, in small and big blocks."""
    from imudiag.certificate import load_default

    cert = load_default()
    rng = np.random.default_rng(90)
    n = 70_000
    gyro = np.rint(rng.normal(0.0, 30.0, (n, 3)))
    accel = rng.normal(0.0, 1e-3, (n, 3)) + [0.0, 0.0, 1.0]
    accel[rng.random(n) < 0.001] = np.nan
    block = SampleBlock(t=np.arange(n) / 100.0, gyro=gyro, accel=accel)
    sizes = blocks(np.random.default_rng(91), n)
    got = [
        stage_outputs(block, cert, sizes, on, switch, lambda st: (st.var, st.mean))
        for on in (False, True)
    ]
    for a, b in zip(got[1], got[0], strict=True):
        np.testing.assert_array_equal(a, b)
    assert np.all(np.isfinite(got[0][0]))


def stage_outputs(block: SampleBlock, cert: Certificate, sizes: list[int], on: bool, switch,
                  pick) -> tuple[np.ndarray, ...]:  # fmt: skip
    """``pick(stage)``'s arrays of every block the detector's window stage ran on (the
    kernels ``on`` or off) fed ``block`` in ``sizes``, each concatenated over the blocks."""
    switch(on)
    stage = QuasiStaticDetector(cert, rate_hz=100.0)._stage
    parts, first = [], 0
    for size in sizes:
        st = stage.run(block.slice(first, first + size))
        first += size
        if st.skip < size:
            parts.append(pick(st))
    return tuple(np.concatenate(column) for column in zip(*parts, strict=True))


def random_board_stream(seed: int, n: int) -> SampleBlock:
    """A seeded board stream in the bundled certificate's counts: still holds, turns about
    random axes, values that are not finite and flagged samples (saturation, ADC errors)."""
    from imudiag.certificate import load_default
    from imudiag.sim import multi_position, simulate

    cert = load_default()
    traj = multi_position(n_attitudes=8, dwell_s=6.0, turn_s=2.0, rate_hz=100, seed=seed)
    block = simulate(cert, traj, seed=seed + 1).samples.slice(0, n)
    rng = np.random.default_rng(seed)
    gyro, accel = block.gyro.copy(), block.accel.copy()
    gyro[rng.random(len(block)) < 0.001, rng.integers(0, 3)] = np.nan
    accel[rng.random(len(block)) < 0.0005, 1] = np.inf
    flags = np.where(rng.random(len(block)) < 0.001, 1 << int(rng.integers(0, 4)), 0)
    return SampleBlock(t=block.t, gyro=gyro, accel=accel, flags=flags.astype(np.uint32))


@pytest.mark.parametrize("seed", range(3))
def test_window_rows_and_rates_kernels_equal_plain(seed, switch):
    """The block's rows (:func:`imudiag.numba_kernels.window_rows`: the same subtraction and
    product per element, so the window sums are the same numbers) and the windows' rates
    (:func:`imudiag.numba_kernels.window_rates`: the certificate's inverse and projections
    element by element, equal to rounding), in small and big blocks."""
    from imudiag.certificate import load_default

    cert = load_default()
    block = random_board_stream(seed, 30_000)
    sizes = blocks(np.random.default_rng(200 + seed), len(block))

    def rows_and_rates(st):
        sums = np.hstack([st.sums, st.long_sums, st.back_w, st.back_2w])
        return sums, np.column_stack(st.rates())

    got = [stage_outputs(block, cert, sizes, on, switch, rows_and_rates) for on in (False, True)]
    np.testing.assert_array_equal(got[1][0], got[0][0])
    plain, fast = got[0][1], got[1][1]
    scale = np.max(np.abs(plain), axis=0)
    np.testing.assert_array_equal(np.isnan(fast), np.isnan(plain))
    off = np.abs(fast - plain) > 1e-12 * np.abs(plain) + 1e-13 * scale
    assert not off.any(), (fast[off][:5], plain[off][:5], np.argwhere(off)[:5])


@pytest.mark.parametrize("seed", range(6))
def test_detector_flags_with_the_kernels_equal_plain_on_random_streams(seed, switch):
    """The static flags with every detector kernel on against the plain path on seeded
    streams with turns, restarts, non-finite and flagged samples: a rate-band or drift
    comparison could in principle flip on a rounding difference of the compiled rates; none
    does here (nor on the real recordings above)."""
    from imudiag.certificate import load_default

    cert = load_default()
    block = random_board_stream(10 + seed, 40_000)
    sizes = blocks(np.random.default_rng(300 + seed), len(block))
    for how in (sizes, None):
        switch(False)
        plain = flags(block, cert, how)
        switch(True)
        fast = flags(block, cert, how)
        assert plain.any() and not plain.all()
        np.testing.assert_array_equal(fast, plain)


@pytest.mark.parametrize("seed", range(3))
def test_variance_test_and_drift_norm_kernels_equal_numpy(seed):
    """The variance test's ratios (three-term sums one by one, as ``np.sum`` over an axis of
    3), its flags, the settle test and the drift norms (``np.einsum``'s three-term order on
    this machine, (0 + 2) + 1) compiled against the numpy expressions of the detector, on
    values of very different sizes (where the order of a sum shows): the same numbers."""
    from imudiag import numba_kernels as nk

    rng = np.random.default_rng(500 + seed)
    m = 50_000
    var = rng.uniform(0.0, 1.0, (m, 6)) * 10 ** rng.uniform(-6, 6, (m, 6))
    var_ref = 10 ** rng.uniform(-4, 4, 6)
    limit = float(np.median((var / var_ref).reshape(m, 2, 3).sum(axis=2)))
    to_si2 = 10 ** rng.uniform(-3, 3, 3)
    settle_var = float(np.median(np.sum(var[:, 3:6] * to_si2, axis=1)))
    for checked, missing in (((0, 1), False), ((1,), False), ((0, 1), True)):
        ok0 = rng.random(m) < 0.9
        ratio = (var / var_ref).reshape(m, 2, 3).sum(axis=2)
        still = ratio <= limit
        ok_plain = ok0 & ~missing
        for c in checked:
            ok_plain &= still[:, c]
        mask = np.zeros(2, dtype=bool)
        mask[list(checked)] = True
        ok = ok0.copy()
        r, s, settle = nk.variance_test(var, var_ref, limit, mask, missing, to_si2, settle_var, ok)
        np.testing.assert_array_equal(r, ratio)
        np.testing.assert_array_equal(s, still)
        np.testing.assert_array_equal(ok, ok_plain)
        np.testing.assert_array_equal(settle, np.sum(var[:, 3:6] * to_si2, axis=1) > settle_var)
    spread = rng.normal(size=(m, 3)) * 10 ** rng.uniform(-5, 5, (m, 3))
    spread[rng.random(m) < 0.01] = np.nan
    to_si = 10 ** rng.uniform(-2, 2, 3)
    s_si = spread * to_si
    norm = np.sqrt(np.einsum("ij,ij->i", s_si, s_si))
    drift_limit = float(np.nanmedian(norm))
    ok = np.ones(m, dtype=bool)
    nk.drift_within(spread, to_si, drift_limit, ok)
    np.testing.assert_array_equal(ok, norm <= drift_limit)


@pytest.mark.parametrize("seed", range(6))
def test_quantile_above_never_says_above_when_the_quantile_is_not(seed):
    """:func:`imudiag.numba_kernels.quantile_above` (the data-noise estimate's skip) against
    ``np.quantile`` itself on seeded columns (ties, nans, masked rows, thresholds at and
    around the quantile): whenever it says "certainly above", numpy's 5 % quantile over the
    kept rows is above the threshold; and it does say so well clear of it."""
    from imudiag.numba_kernels import quantile_above

    rng = np.random.default_rng(seed)
    said = 0
    for trial in range(300):
        n = int(rng.integers(5, 400))
        v = np.round(rng.gamma(2.0, 1.0, (n, 3)), int(rng.integers(0, 4)))  # ties when coarse
        if trial % 7 == 0:
            v[rng.integers(n), rng.integers(3)] = np.nan
        ok = rng.random(n) < 0.8
        kept = v[ok]
        q = np.quantile(kept, 0.05, axis=0) if kept.shape[0] else np.full(3, np.nan)
        factors = [0.5, 0.9, 0.999, 1.0, 1.001, 2.0]
        thr = q * (rng.choice(factors, size=3) if trial % 2 else rng.choice(factors))
        if quantile_above(v, ok, thr, 0.05):
            said += 1
            assert kept.shape[0] >= 10 and np.all(q > thr), (q, thr)
        if kept.shape[0] >= 40 and not np.isnan(kept).any():
            assert quantile_above(v, ok, 0.5 * np.min(kept, axis=0) - 1.0, 0.05)
    assert said > 10


@pytest.mark.parametrize("seed", range(3))
def test_history_starts_equal_plain(seed, switch):
    """The histories' starts (:meth:`QuasiStaticDetector._starts`, compiled as
    :func:`imudiag.numba_kernels.history_starts`) equal the numpy path's, row for row and
    in the restart carried to the next block, over seeded blocks of one to three marks
    (sparse, dense and no flags; lags 0 to 300 rows; spans shorter and longer than them)."""
    from imudiag.certificate import load_default

    rng = np.random.default_rng(seed)
    dets = {}
    for on in (False, True):
        switch(on)
        dets[on] = QuasiStaticDetector(load_default())
    row = 0
    for _trial in range(60):
        m = int(rng.integers(1, 3000))
        idx = np.arange(row, row + m, dtype=np.int64)
        row += m
        marks = [
            (rng.random(m) < rng.choice([0.0, 0.001, 0.3]), int(rng.integers(0, 300)))
            for _ in range(int(rng.integers(1, 4)))
        ]
        key = int(rng.integers(2))
        span = int(rng.integers(1, 2000))
        got = {}
        for on in (False, True):
            switch(on)
            got[on] = dets[on]._starts(key, idx, marks, span)
        np.testing.assert_array_equal(got[True], got[False])
        assert dets[True]._restart == dets[False]._restart


@pytest.mark.parametrize("seed", range(4))
def test_masked_quantile_is_numpys_bit_for_bit(seed):
    """:func:`imudiag.numba_kernels.masked_quantile` (the data-noise estimate's quantile)
    against ``np.quantile(v[ok], q, axis=0)`` on seeded columns: ties, a column of one
    value, infinities, values of very different sizes, sorted and reversed columns (the
    selection's worst orders), few and many rows, strided views, quantiles from 0 to 1.
    Equal bit for bit (nan where numpy's is); a nan among the kept values is said, not
    guessed."""
    from imudiag.numba_kernels import masked_quantile

    rng = np.random.default_rng(seed)
    for trial in range(400):
        m = int(rng.integers(1, 30)) if trial % 3 == 0 else int(rng.integers(30, 5000))
        kind = trial % 4
        if kind == 0:
            v = rng.gamma(2.0, 1.0, (m, 3))
        elif kind == 1:
            v = np.round(rng.random((m, 3)) * 5) / 5  # ties
        elif kind == 2:
            v = rng.exponential(size=(m, 3)) * 10.0 ** float(rng.integers(-30, 5))
        else:
            v = np.full((m, 3), 0.3)  # one value, a few others
            v[rng.random((m, 3)) < 0.3] = rng.random()
        if trial % 7 == 0:
            v = np.sort(v, axis=0)[::-1].copy()
        elif trial % 7 == 1:
            v = np.sort(v, axis=0)
        if trial % 11 == 0:
            v[rng.random((m, 3)) < 0.05] = np.inf
        ok = rng.random(m) < rng.random()
        ok[int(rng.integers(m))] = True
        wide = np.zeros((m, 13))
        wide[:, 3:6] = v
        for q in (0.05, 0.0, 0.5, 1.0, float(rng.random())):
            with np.errstate(invalid="ignore"):
                want = np.quantile(v[ok], q, axis=0)
            for layout in (v, wide[:, 3:6]):  # contiguous and strided (the detector's)
                got, exact = masked_quantile(layout, ok, q)
                assert exact
                same = (got.view(np.int64) == want.view(np.int64)) | (
                    np.isnan(got) & np.isnan(want)
                )
                assert same.all(), (trial, q, got, want)
    v = rng.random((50, 3))
    v[7, 1] = np.nan
    assert not masked_quantile(v, np.ones(50, dtype=bool), 0.05)[1]
    assert masked_quantile(v, np.arange(50) != 7, 0.05)[1]  # the nan not kept
    assert not masked_quantile(v, np.zeros(50, dtype=bool), 0.05)[1]


@pytest.mark.parametrize(
    "name", ["xsens-mti-multiposition/session.csv.gz", "mpu6050/calibration.csv.gz"]
)
def test_data_noise_figures_with_the_skip_equal_plain(name, switch):
    """The data-noise detector (the window diagnosis's: no certificate noise) keeps the same
    noise figures, block by block, with the kernels (which skip blocks whose quantile cannot
    lower the estimate) as without, on real recordings in random blocks and on a seeded
    stream whose second half is quieter (its estimate falls there)."""
    from imudiag.certificate import load_default
    from imudiag.sim import Effects, multi_position, simulate

    block, cert = _real(name)
    traj = multi_position(n_attitudes=12, dwell_s=40.0, turn_s=2.0, rate_hz=100, seed=21)
    loud = simulate(load_default(), traj, seed=22, effects=Effects(noise_scale=1.0)).samples
    soft = simulate(load_default(), traj, seed=23, effects=Effects(noise_scale=0.3)).samples
    half = len(loud) // 2  # the same motions, the noise 0.3 times as large from half on
    quiet = SampleBlock(
        t=loud.t,
        gyro=np.concatenate([loud.gyro[:half], soft.gyro[half:]]),
        accel=np.concatenate([loud.accel[:half], soft.accel[half:]]),
    )
    switch(True)
    real_above = kernels._KERNELS["quantile_above"]
    skipped = []

    def above(*args):
        out = real_above(*args)
        skipped.append(out)
        return out

    for blk, crt, seed, falls in ((block, cert, 8, False), (quiet, load_default(), 9, True)):
        sizes = blocks(np.random.default_rng(seed), len(blk))
        got = []
        for on in (False, True):
            switch(on)
            kernels._KERNELS["quantile_above"] = above if on else real_above
            det = QuasiStaticDetector(crt, certificate_noise=False)
            figures, first = [], 0
            for size in sizes:
                det.update(blk.slice(first, first + size))
                figures.append([det._noise_var[t] for t in ("gyro", "accel")])
                first += size
            got.append(figures)
        for fp, ff in zip(got[0], got[1], strict=True):
            for a, b in zip(fp, ff, strict=True):
                assert (a is None) == (b is None)
                if a is not None:
                    assert a.tobytes() == b.tobytes()
        kernels._KERNELS["quantile_above"] = real_above
        assert any(skipped) and not all(skipped), "blocks skipped, and blocks not"
        skipped.clear()
        if falls:  # the quieter half lowered the estimate after its first figure
            seen = [f for f in got[0] if f[0] is not None and f[1] is not None]
            assert any(
                not (np.array_equal(f[0], seen[-1][0]) and np.array_equal(f[1], seen[-1][1]))
                for f in seen
            ), "the estimate fell along the stream"

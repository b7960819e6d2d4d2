"""The still detector's speed machinery against plain definitions (issue 30 item 6).

:mod:`imudiag.quasistatic` keeps the algorithm (:mod:`.detector`) apart from the machinery
that makes it cheap per call: the window statistics from prefix sums carried across
blocks (:class:`~imudiag.quasistatic.WindowStage`) and the drift tests' trailing spreads
(:class:`~imudiag.quasistatic.TrailingSpread`). Each is fed random block cuts of seeded
random streams (ADC errors, non-finite samples, restarts) and of the real recordings in
``tests/data/real``, and must give what the plain definition gives, computed here window
by window: the spreads exactly (max and min are exact), the window means, variances and
rates to the rounding of a prefix sum, the bad-window flags exactly; and the whole
detector decides the same, sample for sample, on plain window sums as on prefix sums.

The whole detector's flags are still compared with the frozen code in
``tests/reference/drift_quasistatic.py`` (``tests/test_detector_equivalence.py``; the note
at its top says why it stays).
"""

from __future__ import annotations

import numpy as np
import pytest
from numpy.lib.stride_tricks import sliding_window_view

from imudiag.certificate import Certificate, load_default
from imudiag.quasistatic import (
    BAD_FLAGS,
    QuasiStaticDetector,
    TrailingSpread,
    WindowStage,
    WindowStats,
)
from imudiag.quasistatic.spread import plain_spread
from imudiag.samples import FLAG_ACCEL_SATURATED, FLAG_ADC_ERROR, SampleBlock
from imudiag.sim import Effects, Fault, multi_position, simulate
from tests.test_detector_equivalence import REAL_NAMES, _real

CERT = load_default()


def _cuts(rng: np.random.Generator, n: int, big: bool) -> list[tuple[int, int]]:
    """Random consecutive blocks over ``n`` rows: daemon reads (1..20), batches (up to 500)
    and, with ``big``, blocks beyond 4096 rows (the spread's repeat path)."""
    out, at = [], 0
    while at < n:
        choices = [rng.integers(1, 21), rng.integers(1, 501)]
        if big:
            choices.append(rng.integers(4096, 9000))
        size = int(rng.choice(choices))
        out.append((at, min(n, at + size)))
        at += size
    return out


def _starts(rng: np.random.Generator, n: int, span: int, p: float, lag: int) -> np.ndarray:
    """History starts (n,) as the detector makes them: ``span`` rows back at most, and
    restarts ``lag`` rows after random marks (a restart can lie ahead of its row)."""
    idx = np.arange(n)
    marks = np.where(rng.random(n) < p, idx + rng.integers(0, lag + 1, n), -(1 << 62))
    return np.maximum(np.maximum.accumulate(marks), idx - span)


def _check_spread(values: np.ndarray, start: np.ndarray, step: int, span: int, seed: int):
    rng = np.random.default_rng(seed)
    fast = TrailingSpread(values.shape[1], step, span)
    got = np.concatenate(
        [fast.update(a, values[a:b], start[a:b]) for a, b in _cuts(rng, len(values), True)]
    )
    want = plain_spread(np.arange(len(values)), values, start, step, span)
    assert np.array_equal(got, want)


@pytest.mark.parametrize("seed", range(6))
def test_trailing_spread_is_its_definition_on_random_streams(seed):
    rng = np.random.default_rng(100 + seed)
    n = int(rng.integers(3000, 12000))
    columns = int(rng.integers(1, 5))
    step = int(rng.integers(1, 30))
    span = int(rng.integers(step, 40 * step))
    values = np.cumsum(rng.normal(size=(n, columns)), axis=0)
    values[rng.random((n, columns)) < 0.002] = np.nan  # a spread that is not finite reads 0
    start = _starts(rng, n, span, float(rng.choice([0.0, 0.001, 0.02])), 3 * step)
    _check_spread(values, start, step, span, seed)


def _plain_windows(x: np.ndarray, bad: np.ndarray, w: int, long_w: int):
    """Plain window statistics of a whole stream ``x`` (N, 6), non-finite values read 0,
    for the rows with a whole window: means, variances (ddof 1), a bad sample in the
    window, in the last ``long_w`` rows, and the mean of the last ``long_w`` rows."""
    n = x.shape[0]
    mean = np.empty((n - w + 1, 6))
    var = np.empty((n - w + 1, 6))
    for c in range(6):  # one column at a time: (rows, w) views, not (rows, w, 6) copies
        windows = sliding_window_view(x[:, c], w)
        mean[:, c] = windows.mean(axis=1)
        var[:, c] = windows.var(axis=1, ddof=1)
    bad_w = sliding_window_view(bad, w).any(axis=1)
    rows = np.arange(w - 1, n)
    lo = np.maximum(rows - long_w + 1, 0)
    cum = np.concatenate([[0], np.cumsum(bad)])
    bad_long = cum[rows + 1] - cum[lo] > 0
    long_mean = np.array([x[a : r + 1, :3].mean(axis=0) for a, r in zip(lo, rows, strict=True)])
    return mean, var, bad_w, bad_long, long_mean


def _check_windows(block: SampleBlock, cert: Certificate, window: int, rate_window: int, seed):
    rng = np.random.default_rng(seed)
    n_inv_t = {name: cert.triad(name).n_inverse_t() for name in ("gyro", "accel")}
    stage = WindowStage(cert, window, rate_window, np.arange(6), n_inv_t)
    got: dict[str, list[np.ndarray]] = {k: [] for k in ("mean", "var", "bad", "long", "rates")}
    for a, b in _cuts(rng, len(block), False):
        st = stage.run(block.slice(a, b))
        if st.skip >= b - a:
            continue
        got["mean"].append(st.mean)
        got["var"].append(st.var)
        got["bad"].append(st.sums[:, 12] >= 0.5)
        got["long"].append(st.long_sums[:, 12] >= 0.5)
        got["rates"].append(np.column_stack(st.rates()))
    fast = {k: np.concatenate(v) for k, v in got.items()}

    x = np.concatenate([block.gyro, block.accel], axis=1)
    finite = np.isfinite(x)
    bad = ~finite.all(axis=1)
    if block.flags is not None:
        bad |= (block.flags.astype(np.int64) & BAD_FLAGS) != 0
    x = np.where(finite, x, 0.0)
    mean, var, bad_w, bad_long, long_mean = _plain_windows(x, bad, window, rate_window)
    assert np.array_equal(fast["bad"], bad_w)
    assert np.array_equal(fast["long"], bad_long)
    # a prefix sum rounds at the scale of the stream's excursion from its first sample
    scale = np.max(np.abs(x - x[0]), axis=0) + np.abs(x[0]) * 1e-3 + 1e-12
    np.testing.assert_allclose(fast["mean"], mean, rtol=0, atol=1e-9 * float(np.max(scale)))
    np.testing.assert_allclose(fast["var"], var, rtol=1e-6, atol=1e-9 * float(np.max(scale)) ** 2)
    # the rates about the vertical and the rate magnitude (gyro input units)
    rate = cert.gyro.inverse(mean[:, :3], n_inv_t=n_inv_t["gyro"])
    rate_long = cert.gyro.inverse(long_mean, n_inv_t=n_inv_t["gyro"])
    down = cert.accel.inverse(mean[:, 3:], n_inv_t=n_inv_t["accel"])
    norm = np.linalg.norm(down, axis=1)
    norm[norm == 0] = 1.0
    plain = np.column_stack(
        [
            np.sum(rate * down, axis=1) / norm,
            np.sum(rate_long * down, axis=1) / norm,
            np.linalg.norm(rate, axis=1),
        ]
    )
    rate_scale = float(np.max(np.abs(plain))) + 1e-12
    np.testing.assert_allclose(fast["rates"], plain, rtol=0, atol=1e-7 * rate_scale)


@pytest.mark.parametrize("seed", range(4))
def test_window_statistics_are_their_definition_on_random_streams(seed):
    rng = np.random.default_rng(200 + seed)
    traj = multi_position(n_attitudes=6, dwell_s=3.0, turn_s=1.5, rate_hz=200, seed=seed)
    block = simulate(CERT, traj, seed=300 + seed).samples
    n = len(block)
    gyro, accel = block.gyro.copy(), block.accel.copy()
    gyro[rng.random(n) < 0.002, int(rng.integers(0, 3))] = np.nan  # ADC errors
    flags = np.zeros(n, dtype=np.uint16)
    flags[rng.random(n) < 0.003] |= FLAG_ACCEL_SATURATED
    flags[rng.random(n) < 0.001] |= FLAG_ADC_ERROR
    noisy = SampleBlock(t=block.t, gyro=gyro, accel=accel, flags=flags, temp=block.temp)
    window = int(rng.integers(3, 150))
    _check_windows(noisy, CERT, window, window + int(rng.integers(0, 400)), seed)


@pytest.mark.parametrize("name", REAL_NAMES)
def test_fast_paths_are_their_definitions_on_the_real_recordings(name):
    """On each real recording (its first 40 000 samples): the window statistics at the
    detector's 0.5 s window and 2 s rate window, and the short drift test's spread of the
    accelerometer window means with restarts where the unit moved."""
    block, cert = _real(name)
    block = block.slice(0, min(len(block), 40_000))
    dt = np.diff(block.t)
    rate = 1.0 / float(np.median(dt[dt > 0]))
    window = max(3, round(0.5 * rate))
    seed = 400 + REAL_NAMES.index(name)
    _check_windows(block, cert, window, max(window, round(2.0 * rate)), seed)
    # the accelerometer window means as the drift test sees them, restarted after motion
    means = sliding_window_view(np.nan_to_num(block.accel, nan=0.0), window, axis=0).mean(axis=2)
    moving = sliding_window_view(block.gyro[:, 0], window).std(axis=1)
    moving = moving > np.nanmedian(moving) * 3
    idx = np.arange(len(means))
    step, span = max(1, round(0.1 * rate)), round(5.0 * rate)
    start = np.maximum(
        np.maximum.accumulate(np.where(moving, idx + window, -(1 << 62))), idx - span
    )
    _check_spread(means[:10_000], start[:10_000], step, span, seed)


class PlainWindowStage:
    """The window statistics by their definition: every window's sums added up from the
    stream's rows kept whole (centred on its first sample, as the detector's are), not
    from prefix sums. :class:`~imudiag.quasistatic.WindowStats` is built from them (the
    previous window's sums given as ``back_w``, zeros as ``back_2w``)."""

    def __init__(self, fast: WindowStage) -> None:
        self.certificate, self.n_inv_t, self.cols = fast.certificate, fast.n_inv_t, fast.cols
        self.window, self.rate_window = fast.window, fast.rate_window
        self.ref: np.ndarray | None = None
        self.rows = np.zeros((0, 13))

    def run(self, block: SampleBlock) -> WindowStats:
        n = len(block)
        x = np.concatenate([block.gyro, block.accel], axis=1)
        finite = np.isfinite(x)
        bad = ~np.all(finite[:, self.cols], axis=1)
        if block.flags is not None:
            bad |= (np.asarray(block.flags).astype(np.int64) & BAD_FLAGS) != 0
        x = np.where(finite, x, 0.0)
        if self.ref is None:
            self.ref = np.array(x[0], dtype=float)
        xc = x - self.ref
        self.rows = np.concatenate([self.rows, np.column_stack([xc, xc * xc, bad])])
        first = self.rows.shape[0] - n
        idx = np.arange(first, first + n)

        def window_sums(ends: np.ndarray, length: int) -> np.ndarray:
            return np.array([self.rows[max(0, e - length + 1) : e + 1].sum(axis=0) for e in ends])

        w = self.window
        sums = window_sums(idx, w)
        long_sums = window_sums(idx, self.rate_window)
        prev = np.array(
            [self.rows[max(0, e - 2 * w + 1) : max(0, e - w + 1)].sum(axis=0) for e in idx]
        ).reshape(n, 13)
        return WindowStats(self, n, idx, sums, long_sums, prev, np.zeros((n, 13)))  # type: ignore[arg-type]


@pytest.mark.parametrize("case", ["multiposition", "faults", "real mpu6050", "real xsens"])
def test_the_detector_on_plain_window_sums_gives_the_same_flags(case):
    """The whole detector (its variance, rate band, drift, restart and step tests, and the
    noise estimate from the data) decides the same on plain window sums as on prefix sums,
    fed the same random blocks."""
    if case.startswith("real"):
        name = {"real mpu6050": "mpu6050/calibration.csv.gz",
                "real xsens": "xsens-mti-multiposition/session.csv.gz"}[case]  # fmt: skip
        block, cert = _real(name)
        block = block.slice(0, min(len(block), 30_000))
    else:
        cert = CERT
        traj = multi_position(n_attitudes=8, dwell_s=4.0, turn_s=1.5, rate_hz=200, seed=7)
        faults = [Fault("bias", "gz", 12.0, 300.0)] if case == "faults" else []
        effects = Effects(quantize=True, adc_error_rate=0.001 if case == "faults" else 0.0)
        block = simulate(CERT, traj, seed=8, faults=faults, effects=effects).samples
    rng = np.random.default_rng(len(block))
    for noise in (True, False):  # the certificate's noise, and the estimate from the data
        fast = QuasiStaticDetector(cert, certificate_noise=noise)
        plain = QuasiStaticDetector(cert, certificate_noise=noise)
        assert isinstance(plain._stage, WindowStage)
        plain._stage = PlainWindowStage(plain._stage)  # type: ignore[assignment]
        for a, b in _cuts(rng, len(block), False):
            part = block.slice(a, b)
            assert np.array_equal(fast.update(part), plain.update(part)), f"samples {a}..{b}"
        assert fast.explain["static"] > 0

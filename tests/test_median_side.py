"""The monitor's noise check settles most windows by counts, not medians (issue 14).

:func:`imudiag.trailing.median_side` says where a window's median is certainly above or
certainly not above a threshold; the noise check takes the median only where neither
holds. Checked against ``np.median`` on data made to be hard: whole ADC counts (ties),
thresholds equal to data values and to the midpoint of the two middle values, NaN.
"""

from __future__ import annotations

import numpy as np
import pytest

from imudiag.trailing import MEDIAN_SIDE_MARGIN, median_side


def _windows(x: np.ndarray, ends: np.ndarray, w: int) -> np.ndarray:
    return np.stack([x[e - w : e] for e in ends])  # (P, w, C)


@pytest.mark.parametrize("w", [4, 5, 200, 201])
def test_never_wrong_and_rarely_undecided(w):
    """Squared second differences of whole counts (many ties): ``above`` implies the
    median is above the threshold, ``below`` that it is not; the thresholds include
    the windows' own medians, values in them and midpoints, where counts cannot decide."""
    rng = np.random.default_rng(w)
    raw = np.rint(rng.normal(scale=3.0, size=(4000, 3)))  # whole ADC counts
    x = np.diff(raw, n=2, axis=0) ** 2  # (R, 3) whole numbers, many equal
    ends = np.arange(w, x.shape[0] + 1, 7)
    med = np.median(_windows(x, ends, w), axis=1)  # (P, 3)
    picks = [
        np.full(3, float(np.median(med))),  # a typical median: ties at the threshold
        np.array([1.0, 4.0, 9.0]),  # data values
        np.array([2.5, 12.5, 20.5]),  # midpoints of two data values
        np.array([0.0, 1e9, 36.0]),
    ]
    thr = np.stack(picks)  # (4, 3)
    above, below = median_side(x, ends, w, thr)
    truth = med[:, None, :] > thr[None]
    assert not np.any(above & ~truth)
    assert not np.any(below & truth)
    assert not np.any(above & below)
    settled = (above | below).mean()
    assert settled > 0.7, settled  # the point: most checks need no median
    # a threshold far from every median settles every window
    far = np.stack([med.max(axis=0) * 10 + 1, np.full(3, -1.0)])
    a2, b2 = median_side(x, ends, w, far)
    assert b2[:, 0].all() and a2[:, 1].all()


def test_the_margin_leaves_near_ties_to_the_median():
    """A median within the margin of the threshold is left undecided, on either side."""
    w = 6
    x = np.array([1.0, 2.0, 3.0, 5.0, 8.0, 9.0])[:, None]  # median 4.0
    for thr in (4.0, 4.0 * (1 + MEDIAN_SIDE_MARGIN / 2), 4.0 * (1 - MEDIAN_SIDE_MARGIN / 2)):
        above, below = median_side(x, np.array([w]), w, np.array([[thr]]))
        assert not above.any() and not below.any()
    above, below = median_side(x, np.array([w]), w, np.array([[3.0], [5.0], [6.0]]))
    # 3.0: three of six values beyond it (5, 8, 9), the middle pair straddles it, and only
    # the median (4.0) says it is above; 5.0: a value at the threshold counts as beyond it
    # for ``below`` (undecided); 6.0: two beyond it, the median is certainly not above
    assert not (above | below)[0, :2, 0].any()
    assert below[0, 2, 0] and not above[0, 2, 0]


def test_a_window_with_nan_is_never_settled():
    x = np.ones((50, 2))
    x[20, 1] = np.nan
    ends = np.array([10, 25, 50])
    above, below = median_side(x, ends, 10, np.array([[0.5, 0.5], [2.0, 2.0]]))
    assert above[:, 0, 0].all() and below[:, 1, 0].all()  # column 0: no NaN
    undecided = ~(above | below)[:, :, 1]
    assert undecided[1].all() and not undecided[0].any() and not undecided[2].any()


def _noise_trace(monkeypatch, settle: bool) -> list:
    """The monitor's noise findings after every block of a seeded session whose noise
    faults sit below, near and beyond the 2x and 3x ratios; ``settle=False`` makes every
    check take its median (the check as it was before the counts)."""
    import imudiag.monitor as monitor_module
    import imudiag.monitor.noise as noise_module
    from imudiag.certificate import load_default
    from imudiag.sim import Fault, multi_position, simulate

    if not settle:

        def nothing_settled(x, ends, w, thresholds):
            shape = (len(ends), thresholds.shape[0], x.shape[1])
            return np.zeros(shape, dtype=bool), np.zeros(shape, dtype=bool)

        monkeypatch.setattr(noise_module, "median_side", nothing_settled)
    cert = load_default()
    traj = multi_position(n_attitudes=12, dwell_s=4.0, turn_s=1.5, rate_hz=200, seed=41)
    faults = [
        Fault("noise", "gx", 10.0, 1.75),
        Fault("noise", "ay", 20.0, 2.0),
        Fault("noise", "az", 30.0, 2.9),
        Fault("noise", "gz", 40.0, 4.0),
    ]
    samples = simulate(cert, traj, seed=42, faults=faults).samples
    mon = monitor_module.Monitor(cert, rate_hz=200.0)
    out = []
    for i in range(0, len(samples), 700):
        mon.update(samples.slice(i, i + 700))
        mon.flush()
        st = mon.state
        out.append(
            (
                [f for f in mon.active_faults if f["cause"] == "noise"],
                [st[t].noise_ratio_last.tolist() for t in ("gyro", "accel")],
                [[p.active for p in st[t].noise + st[t].noise_gross] for t in ("gyro", "accel")],
            )
        )
    return out


def test_the_noise_check_decides_as_with_every_median(monkeypatch):
    """Every noise finding, persistence state and kept ratio of the monitor equals the
    check's with a median taken at every check, block after block."""
    fast = _noise_trace(monkeypatch, settle=True)
    monkeypatch.undo()
    slow = _noise_trace(monkeypatch, settle=False)
    assert fast == slow
    assert any(f for f, _, _ in fast)  # the faults were seen
    assert not all(f for f, _, _ in fast)

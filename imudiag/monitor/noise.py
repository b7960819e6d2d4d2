"""The monitor's excess-noise check: per channel, the white-noise sigma from the median of
the squared second differences over a trailing window, against the certificate's
(:mod:`.checks` module doc). The median is taken only where counting the values beyond each
threshold cannot settle the comparison (:func:`imudiag.trailing.median_side`; the same
decisions)."""

from __future__ import annotations

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from ..certificate import TRIADS, Certificate
from ..kernels import kernel
from ..noise_estimate import medians
from ..rowwise import rows_where
from ..trailing import median_side
from .state import MonitorConfig, TriadState

#: triads in the ring's column order (raw gyro columns 1-3, accel 4-6): the certificate's
#: order of its triads, one definition
TRIADS_RING = TRIADS


class NoiseCheck:
    """Excess white noise per channel, judged every ``noise_check_s`` of samples on the
    trailing ``noise_window_s`` of second differences (settings from ``config``; ``rate``
    in Hz)."""

    def __init__(self, certificate: Certificate, config: MonitorConfig, rate: float) -> None:
        self.config = config
        self.window = max(4, int(round(config.noise_window_s * rate)))  #: samples
        self.step = max(1, int(round(config.noise_check_s * rate)))  #: samples between checks
        #: per triad, the white-noise sigma (output units) the check compares with: the
        #: certificate's at ``rate`` (whole counts add q^2/12); None: not checked
        self.sigma: dict[str, np.ndarray | None] = {}
        for name in TRIADS:
            tri = certificate.triad(name)
            sigma = tri.noise_sigma(rate)
            if sigma is not None and tri.output_unit == "count":
                sigma = np.sqrt(sigma**2 + 1.0 / 12.0)  # whole counts add q^2/12
            self.sigma[name] = sigma

    def positions(self, first: int, seen: int, calm: np.ndarray) -> np.ndarray:
        """Indexes into a block of ``N`` samples, the first of them stream sample ``first``
        and ``seen`` samples before it since the certificate was set, where the check runs:
        every ``step`` of the stream, once a window's ``w`` second differences (``w + 2``
        samples) are there, where ``calm`` (N,)."""
        w, step = self.window, self.step
        n = calm.shape[0]
        # check positions: samples whose index in the stream is a multiple of the step
        pos = np.arange((-first) % step, n, step)
        return pos[(seen + pos + 1 >= w + 2) & calm[pos]]

    def judge(
        self, t: np.ndarray, chan: np.ndarray, pos: np.ndarray, state: dict[str, TriadState]
    ) -> None:
        """Excess white noise per channel from second differences, carried across blocks in
        ``state`` (each triad's persistence, ratios and counters).

        Per channel, sigma from the median of the squared second differences over the
        trailing window (median of chi^2_1 = 0.4549; var(d2) = 6 sigma^2 for white noise):
        a burst over less than half the window (a hand grabbing the unit, a knock, a step)
        leaves the median alone, where a mean would call it noise.
        ``t`` (N,): the block's sample times (s); ``chan`` (6, h + N): raw outputs
        (output units) channel by channel, the ``h`` samples before the block first;
        ``pos``: the checks (:meth:`positions`: only windows that saw no turn, angular
        acceleration below ``noise_motion_gate``, are judged). Excess noise (beyond
        ``noise_ratio``) must persist 3 s; gross noise (beyond ``noise_gross_ratio``) is
        raised after 3 of 5 checks.
        """
        w = self.window
        back = chan.shape[1] - t.shape[0]
        # channel by channel, each channel's values contiguous: column c, row r ends at
        # chan column r + 2
        compiled = kernel("second_diff_squares")  # the same differences: bit for bit
        if compiled is not None:
            d2sq = compiled(np.ascontiguousarray(chan, dtype=float))
        else:
            d2sq = np.diff(chan, n=2, axis=1)
            np.square(d2sq, out=d2sq)
        ends = pos + back - 2 + 1  # d2sq rows end (exclusive) at each check sample
        # a check fails when sqrt(median / (0.4549 * 6)) / sigma exceeds a ratio: where the
        # counts of values beyond that median settle it (nearly everywhere), no median is
        # taken; the others, and the last check (its ratio is kept), get theirs
        limits = self.config.noise_ratio, self.config.noise_gross_ratio
        thr = np.full((2, 6), np.inf)
        for k, name in enumerate(TRIADS_RING):
            sigma = self.sigma[name]
            if sigma is not None:
                for j, r in enumerate(limits):
                    thr[j, 3 * k : 3 * k + 3] = (r * sigma) ** 2 * (0.4549 * 6.0)
        fails, settled = median_side(d2sq.T, ends, w, thr)
        settled |= fails
        exact = ~np.all(settled, axis=(1, 2))
        exact[-1] = True
        rows = np.flatnonzero(exact)
        # the medians of those windows in one call per group of checks (the group bounded
        # to about 2^20 values copied)
        windows = sliding_window_view(d2sq, w, axis=1)  # (6, rows, w), row i = d2sq[:, i:i+w]
        ratio6 = np.empty((rows.size, 6))
        group = max(1, (1 << 20) // (6 * w))
        for g in range(0, rows.size, group):
            # the gathered windows are a copy of our own: partitioned in place
            ratio6[g : g + group] = medians(windows[:, ends[rows[g : g + group]] - w]).T
        t = t[pos]
        ratios: dict[str, np.ndarray] = {}
        for k, name in enumerate(TRIADS_RING):
            sigma = self.sigma[name]
            if sigma is None:
                continue
            st = state[name]
            ratio = np.sqrt(ratio6[:, 3 * k : 3 * k + 3] / (0.4549 * 6.0)) / sigma
            st.noise_ratio_last = ratio[-1]
            ratios[name] = ratio
            for j, r in enumerate(limits):
                fails[rows, j, 3 * k : 3 * k + 3] = ratio > r
        self._persist(t, fails, rows, ratios, state)

    def _persist(
        self,
        t: np.ndarray,
        fails: np.ndarray,
        rows: np.ndarray,
        ratios: dict[str, np.ndarray],
        state: dict[str, TriadState],
    ) -> None:
        """The checks' verdicts into each triad's persistence: ``t`` (checks,) their times
        (s), ``fails`` (checks, 2, 6) beyond ``noise_ratio`` / ``noise_gross_ratio`` per
        channel, ``ratios`` per triad (rows, 3) the measured / certificate sigma of the
        checks ``rows`` whose medians were taken."""
        # vibration is not noise (issue 25): a triad's noise is judged only while the other
        # triad is at its own noise (no axis beyond ``noise_ratio``): a vehicle's vibration
        # shakes both triads, a sensor's own noise is its alone. Both beyond: the unit is not
        # at rest, and the excess is reported as vibration, never as a noise fault
        excess: np.ndarray = np.any(fails[:, 0, :].reshape(-1, 2, 3), axis=2)  # (checks, 2)
        for k, name in enumerate(TRIADS_RING):
            if name not in ratios:
                continue
            st = state[name]
            other = self.sigma[TRIADS_RING[1 - k]]
            judged = ~excess[:, 1 - k] if other is not None else np.ones(excess.shape[0], bool)
            st.noise_judged += int(np.count_nonzero(judged))
            st.noise_not_at_rest += int(judged.size - np.count_nonzero(judged))
            ex = judged[rows]
            if ex.any():
                kept = ratios[name][ex]
                beyond = kept[(kept > self.config.noise_ratio).any(axis=1)]
                if beyond.size and sum(a.shape[0] for a in st.noise_excess) < 100_000:
                    st.noise_excess.append(beyond)
            if not judged.any():
                continue
            tj = t if judged.all() else t[judged]
            for axis in range(3):
                col = 3 * k + axis
                st.noise[axis].update(rows_where(fails[:, 0, col], judged), tj)
                st.noise_gross[axis].update(rows_where(fails[:, 1, col], judged), tj)

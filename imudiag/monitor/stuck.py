"""The monitor's stuck-output check: a channel repeating the same raw value for
``stuck_samples`` samples where its noise makes that impossible."""

from __future__ import annotations

import numpy as np


class StuckCheck:
    """Run length of identical raw outputs per channel (6: gyro then accel), carried across
    blocks. ``sigma``: each triad's noise sigma (output units; None: no figure), checked
    only where at least ``min_sigma``; ``samples``: the run that means a stuck channel."""

    def __init__(
        self, sigma: tuple[np.ndarray | None, np.ndarray | None], min_sigma: float, samples: int
    ) -> None:
        enabled = [np.zeros(3, dtype=bool) if sig is None else sig >= min_sigma for sig in sigma]
        self.enabled = np.concatenate(enabled)
        self.samples = samples
        self.run = np.zeros(6, dtype=np.int64)  #: samples in each run, excluding its first
        self.last = np.full(6, np.nan)  #: the last raw output of each channel

    def update(self, raw: np.ndarray) -> np.ndarray:
        """The channels (6,) stuck after the block ``raw`` (6, N): its raw outputs (output
        units), gyro then accel, channel by channel."""
        n = raw.shape[1]
        same_prev = np.empty(raw.shape, dtype=bool)
        np.equal(raw[:, 0], self.last, out=same_prev[:, 0])
        np.equal(raw[:, 1:], raw[:, :-1], out=same_prev[:, 1:])
        if same_prev.all():  # no change in the block: every run grows by n
            run = self.run + n
        else:
            # index of the last change in this block per channel (-1: none)
            changed = ~same_prev
            last_change = n - 1 - np.argmax(changed[:, ::-1], axis=1)
            last_change[~changed.any(axis=1)] = -1
            run = np.where(last_change < 0, self.run + n, n - 1 - last_change)
        # samples in the current run of equal values, excluding its first
        self.run = run.astype(np.int64)
        self.last = raw[:, -1].astype(float)
        active: np.ndarray = self.enabled & (self.run >= self.samples - 1)
        return active

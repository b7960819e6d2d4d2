"""The monitor's stuck-output check: a channel repeating the same raw value for
``stuck_samples`` samples where its noise makes that impossible, in any output unit.

A channel is checked when its certificate noise sigma is at least ``min_sigma``
quantisation steps of its output: the step is 1 for counts, and otherwise the smallest
nonzero change between consecutive outputs seen (the LSB of a quantised physical output,
next to nothing for a float one; none known before the output first changed). A physical
output, which its device may filter (smoother than the certificate states), must also have
shown at most ``max_repeat`` identical consecutive pairs over ``history`` pairs."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..certificate import SENSOR_NAMES, TRIADS, Certificate
from ..kernels import kernel
from ..units import COUNT, canonical
from .state import MonitorConfig


class StuckCheck:
    """Run length of identical raw outputs per channel (6: gyro then accel), carried across
    blocks. ``sigma``: each triad's noise sigma (output units; None: no figure);
    ``min_sigma``: quantisation steps of noise a checked channel needs; ``samples``: the run
    that means a stuck channel; ``counts`` (6,): channels whose output is raw counts (step
    1; default all); ``history`` and ``max_repeat``: a physical output's own repeat rate
    (pairs seen, the share of them identical at most) before it is checked."""

    def __init__(
        self,
        sigma: tuple[np.ndarray | None, np.ndarray | None],
        min_sigma: float,
        samples: int,
        counts: np.ndarray | None = None,
        history: int = 200,
        max_repeat: float = 0.5,
    ) -> None:
        #: per channel the certificate's noise sigma (output units; NaN: none stated)
        self.sigma = np.concatenate(
            [
                np.full(3, np.nan) if sig is None else np.broadcast_to(sig, (3,)).astype(float)
                for sig in sigma
            ]
        )
        raw = np.ones(6, dtype=bool) if counts is None else np.asarray(counts, dtype=bool)
        #: per channel the output's quantisation step (output units): 1 for counts, else
        #: the smallest nonzero change between consecutive outputs seen (inf: none yet)
        self.quantum = np.where(raw, 1.0, np.inf)
        self.counts = raw
        self.min_sigma = min_sigma
        self.samples = samples
        self.history = history
        self.max_repeat = max_repeat
        self.pairs = np.zeros(6, dtype=np.int64)  #: consecutive output pairs seen
        self.repeats = np.zeros(6, dtype=np.int64)  #: ... of them identical
        self.enabled = self._enabled()
        self.run = np.zeros(6, dtype=np.int64)  #: samples in each run, excluding its first
        self.last = np.full(6, np.nan)  #: the last raw output of each channel
        self.t_first = np.full(6, np.nan)  #: s, when each stuck channel came in force
        self.raised = np.zeros(6, dtype=np.int64)  #: times each channel became stuck
        self.t_first_raised = np.full(6, np.nan)  #: s, when each first became stuck
        self._active = np.zeros(6, dtype=bool)  #: the channels stuck after the last block

    def update(self, raw: np.ndarray, t: np.ndarray | None = None) -> np.ndarray:
        """The channels (6,) stuck after the block ``raw`` (6, N): its raw outputs (output
        units), gyro then accel, channel by channel, at sample times ``t`` (s; None: the
        times in force are not kept)."""
        n = raw.shape[1]
        compiled = kernel("stuck_scan")  # the same differences, minima and counts: exact
        if compiled is not None:
            scan = compiled(np.asarray(raw, dtype=float), self.last)
            smallest, last_change, n_valid, n_same = scan
            if (smallest < self.quantum).any():
                np.minimum(self.quantum, smallest, out=self.quantum)
            run = np.where(last_change < 0, self.run + n, n - 1 - last_change)
            return self._runs(raw, t, run, n_valid, n_same)
        step = np.empty(raw.shape)
        np.subtract(raw[:, 0], self.last, out=step[:, 0])
        np.subtract(raw[:, 1:], raw[:, :-1], out=step[:, 1:])
        same_prev = step == 0.0
        valid = np.isfinite(step)
        # the quantisation step: the smallest nonzero change seen (never below the true
        # step, so a channel whose noise is finer than its step stays unchecked)
        np.abs(step, out=step)
        step[same_prev | ~valid] = np.inf
        smallest = step.min(axis=1)
        if (smallest < self.quantum).any():
            np.minimum(self.quantum, smallest, out=self.quantum)
        if same_prev.all():  # no change in the block: every run grows by n
            run = self.run + n
        else:
            # index of the last change in this block per channel (-1: none)
            changed = ~same_prev
            last_change = n - 1 - np.argmax(changed[:, ::-1], axis=1)
            last_change[~changed.any(axis=1)] = -1
            run = np.where(last_change < 0, self.run + n, n - 1 - last_change)
        return self._runs(
            raw,
            t,
            run,
            np.count_nonzero(valid, axis=1),
            np.count_nonzero(same_prev, axis=1),
        )

    def _runs(
        self,
        raw: np.ndarray,
        t: np.ndarray | None,
        run: np.ndarray,
        n_valid: np.ndarray,
        n_same: np.ndarray,
    ) -> np.ndarray:
        """The stuck channels (6,) after a block (:meth:`update`), from each channel's run
        (samples, excluding its first) and its finite and zero steps in the block."""
        n = raw.shape[1]
        self._episodes(raw, t, n_same)
        # samples in the current run of equal values, excluding its first
        self.run = run.astype(np.int64)
        self.last = raw[:, -1].astype(float)
        need = self.samples - 1
        active: np.ndarray = self.enabled & (self.run >= need)
        # the sample time each came in force: the sample whose run reached the count (or
        # the block's first, for a run long enough before the check was enabled)
        rising = active & np.isnan(self.t_first)
        if t is not None and rising.any():
            at = np.clip(n - 1 - (self.run[rising] - need), 0, n - 1)
            self.t_first[rising] = np.asarray(t, dtype=float)[at]
        self.t_first[~active] = np.nan
        self._active = active.copy()
        # the repeat rate of the channels not stuck now (a stuck run must not make the
        # channel look like one that repeats by nature, or its fault would clear)
        free = ~active
        self.pairs[free] += n_valid[free]
        self.repeats[free] += n_same[free]
        self.enabled = self._enabled()
        return active

    def _episodes(self, raw: np.ndarray, t: np.ndarray | None, n_same: np.ndarray) -> None:
        """Count the stuck episodes that begin in the block ``raw`` (6, N) (:attr:`raised`,
        :attr:`t_first_raised`): every run of one value reaching ``samples`` on a checked
        channel, also one that starts and ends inside the block, so that what the stream
        raised does not depend on how its reads were cut (the state in force is judged at
        each block's end). Runs before the block: :attr:`run` and :attr:`last` (not yet
        updated); a run already stuck at the last block's end is not a new episode."""
        need = self.samples - 1
        n = raw.shape[1]
        # a new episode needs need equal steps in the block, or fewer after a carried run
        maybe = self.enabled & (n_same + self.run >= need)
        # per channel the episodes begun in the block and the sample where the first one
        # reached ``need`` (-1: none)
        hits = np.zeros(raw.shape[0], dtype=np.int64)
        first = np.full(raw.shape[0], -1, dtype=np.int64)
        compiled = kernel("stuck_episodes") if maybe.any() else None
        if compiled is not None:  # the same runs, comparisons and counts in one pass
            hits, first = compiled(
                np.asarray(raw, dtype=float), np.asarray(self.last, dtype=float),
                np.asarray(self.run, dtype=np.int64), int(need), self._active, maybe,
            )  # fmt: skip
        else:
            for c in np.flatnonzero(maybe):
                x = raw[c]
                same = np.empty(n, dtype=bool)
                same[0] = x[0] == self.last[c]
                np.equal(x[1:], x[:-1], out=same[1:])
                edges = np.diff(np.concatenate(([0], same.view(np.int8), [0])))
                starts = np.flatnonzero(edges == 1)  # runs of equal steps [start, end)
                ends = np.flatnonzero(edges == -1)
                carried = np.where(starts == 0, self.run[c], 0)
                # the sample whose step completes ``need``: a run's first sample is the one
                # before its first equal step
                reach = starts + need - 1 - carried
                hit = ends - starts + carried >= need
                if starts.size and starts[0] == 0 and self._active[c]:
                    hit[0] = False  # the episode in force at the last block's end goes on
                if hit.any():
                    hits[c] = np.count_nonzero(hit)
                    first[c] = int(np.clip(reach[hit][0], 0, n - 1))
        for c in np.flatnonzero(hits):
            self.raised[c] += int(hits[c])
            if np.isnan(self.t_first_raised[c]) and t is not None:
                self.t_first_raised[c] = float(np.asarray(t, dtype=float)[first[c]])

    def _enabled(self) -> np.ndarray:
        """The channels (6,) checked: noise of at least ``min_sigma`` steps, and counts or a
        physical output whose own repeat rate is low over ``history`` pairs."""
        own = (self.pairs >= self.history) & (self.repeats <= self.max_repeat * self.pairs)
        checked: np.ndarray = (self.sigma >= self.min_sigma * self.quantum) & (self.counts | own)
        return checked


def monitor_stuck_check(
    certificate: Certificate, config: MonitorConfig, rate_hz: float
) -> StuckCheck:
    """The monitor's stuck check for ``certificate`` at ``rate_hz`` (Hz): the certificate's
    per-sample noise sigma at that rate, ``config``'s run, steps and repeat rate, raw
    counts where the output unit is counts (the daemon's, ``diagnose``'s and
    ``calibrate``'s: one definition)."""
    return StuckCheck(
        (certificate.gyro.noise_sigma(rate_hz), certificate.accel.noise_sigma(rate_hz)),
        config.stuck_min_sigma,
        config.stuck_samples,
        counts=np.array(
            [
                canonical(certificate.triad(name).output_unit) == COUNT
                for name in TRIADS
                for _ in range(3)
            ]
        ),
        history=config.stuck_history,
        max_repeat=config.stuck_max_repeat,
    )


def stuck_words(fault: dict[str, Any]) -> str:
    """What a fault of :func:`stuck_faults` says: ``one raw value for 50 samples or more
    from t = 20.24 s`` (sample time, s; left out where it is not known)."""
    since = "" if fault["t_first"] is None else f" from t = {fault['t_first']:.2f} s"
    return f"one raw value for {fault['samples']} samples or more{since}"


def stuck_faults(check: StuckCheck) -> list[dict[str, Any]]:
    """The stuck outputs ``check`` ever raised, per sensor (gyro then accel): ``t_first`` the
    sample time (s) each first came in force (None: not known), ``raised`` how many times,
    ``samples`` the run of one raw value that the check calls stuck."""
    out: list[dict[str, Any]] = []
    for k, name in enumerate(TRIADS):
        for axis in range(3):
            c = 3 * k + axis
            if check.raised[c] == 0:
                continue
            t_in = float(check.t_first_raised[c])
            out.append(
                {
                    "triad": name,
                    "sensor": SENSOR_NAMES[name][axis],
                    "cause": "stuck",
                    "t_first": t_in if math.isfinite(t_in) else None,
                    "raised": int(check.raised[c]),
                    "samples": int(check.samples),
                }
            )
    return out

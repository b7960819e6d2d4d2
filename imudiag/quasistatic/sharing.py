"""One stateful computation run once for several consumers of one stream: the first to
reach a block runs it, the others read the result; a consumer that cuts the stream
differently goes on alone from a copy, so each gets what a runner of its own would give.
Used by :mod:`imudiag.quasistatic.pool` for the still detectors of ``imudiag diagnose``."""

from __future__ import annotations

import weakref
from collections import deque
from typing import Generic, NamedTuple, Protocol, TypeVar

from ..samples import SampleBlock

R = TypeVar("R")


class Runner(Protocol[R]):
    """A stateful computation over a stream's blocks."""

    def run(self, block: SampleBlock) -> R: ...

    def copy(self) -> Runner[R]: ...


class _Entry(NamedTuple, Generic[R]):
    """A block a shared run has been through, kept until every reader has passed it."""

    start: int  #: stream index of its first sample
    n: int  #: samples
    t: tuple[float, float]  #: its first and last sample times, s (the same stream?)
    result: R
    before: Runner[R]  #: a copy of the runner before it


class SharedRun(Generic[R]):
    """One runner over one stream for readers that feed it the same blocks."""

    def __init__(self, runner: Runner[R]) -> None:
        self.runner = runner
        self.fed = 0  #: samples through the runner
        self.entries: deque[_Entry[R]] = deque()
        self.readers: weakref.WeakSet[RunReader[R]] = weakref.WeakSet()

    def prune(self) -> None:
        """Drop the blocks every attached reader has passed."""
        lowest = min((r.pos for r in self.readers if r.own is None), default=self.fed)
        while self.entries and self.entries[0].start + self.entries[0].n <= lowest:
            self.entries.popleft()


class RunReader(Generic[R]):
    """One consumer's place in a run shared through a
    :class:`~imudiag.quasistatic.DetectorPool`: :meth:`run` gives what the consumer's own runner
    would give on the same blocks.

    The first reader to reach a block runs the runner on it; the result waits for the
    others. A reader that feeds a block cut differently (say two blocks joined: the
    prefix sums' roundings depend on the cut) goes on alone from a copy of the runner as
    it was before that block, so its results are always those of a runner of its own.
    """

    def __init__(self, shared: SharedRun[R], pos: int = 0) -> None:
        self.shared = shared  #: the run it reads
        self.pos = pos  #: samples this reader has fed
        self.own: Runner[R] | None = None  #: its own runner, once it went alone
        shared.readers.add(self)

    def copy(self) -> RunReader[R]:
        """A reader at the same place (one that went alone: with a copy of its runner)."""
        new = RunReader(self.shared, self.pos)
        if self.own is not None:
            new.own = self.own.copy()
        return new

    def run(self, block: SampleBlock) -> R:
        """The result of the stream's next block (N >= 1 samples)."""
        if self.own is not None:
            return self.own.run(block)
        n = len(block)
        sh = self.shared
        t = (float(block.t[0]), float(block.t[-1]))
        if self.pos == sh.fed:  # the first here: run it
            others = any(r is not self and r.own is None for r in sh.readers)
            before = sh.runner.copy() if others else None
            result = sh.runner.run(block)
            sh.fed += n
            if before is not None:
                sh.entries.append(_Entry(self.pos, n, t, result, before))
            self.pos += n
            return result
        entry = next((e for e in sh.entries if e.start == self.pos), None)
        if entry is None:  # cannot happen: every block is kept while a reader is behind it
            raise RuntimeError("shared still detector: a reader lost its place in the stream")
        if entry.n == n and entry.t == t:
            self.pos += n
            sh.prune()
            return entry.result
        # cut differently: on alone from the runner as it was before that block
        self.own = entry.before.copy()
        sh.prune()
        return self.own.run(block)

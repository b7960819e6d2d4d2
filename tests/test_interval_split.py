"""Long still runs cut into intervals of at most ``max_interval_s`` (issue 28): the run is
joined once and cut from its start, instead of joined again after every cut (quadratic in
a long hold). The intervals, and the motion segments between them, are bit for bit those of
the former loop, whether the samples come in one block or in many (the simulated board,
static scenario, seeded; short intervals so every 20-s hold is cut ten times)."""

from __future__ import annotations

import numpy as np
import pytest

from imudiag.certificate import load_default
from imudiag.diagnosis.intervals import IntervalCollector, QuasiStaticInterval
from imudiag.samples import SampleBlock
from imudiag.sim.board import SimulatedBoard
from imudiag.sim.scenarios import scenario_motion

RATE_HZ = 200.0


class FormerCollector(IntervalCollector):
    """The former cutting loop, kept here as the reference."""

    def _split_long_run(self, out: list[QuasiStaticInterval]) -> None:
        while self._run_n >= self.max_n + self.trim_n + self.min_n:
            rows = np.concatenate(self._run)
            out.append(self._emit(rows[: self.max_n]))
            rest = rows[self.max_n :]
            self._run, self._run_n = [rest], rest.shape[0]
            self._gap = [rows[self.max_n - 1 : self.max_n]]
            self._gap_n = 1


@pytest.fixture(scope="module")
def session() -> SampleBlock:
    cert = load_default()
    board = SimulatedBoard(cert, scenario_motion("static", 0), RATE_HZ, 11, duration_s=100.0)
    blocks = []
    while not board.exhausted:
        blocks.append(board.generate(1 << 14)[1])
    return SampleBlock.concat(blocks)


def collect(kind: type[IntervalCollector], session: SampleBlock, block: int) -> list:
    col = kind(load_default(), RATE_HZ, max_interval_s=2.0)
    out = []
    for start in range(0, len(session), block):
        out += col.update(session.slice(start, min(start + block, len(session))))
    return out + col.flush()


def fields(iv: QuasiStaticInterval) -> list:
    b = iv.before
    motion = None if b is None else (b.t, b.gyro, b.usable, b.reason)
    return [iv.index, iv.t_start, iv.t_end, iv.n, iv.gyro_mean, iv.accel_mean, iv.gyro_cov,
            iv.accel_cov, iv.up, motion]  # fmt: skip


@pytest.mark.parametrize("block", [1 << 20, 1000, 137])
def test_cut_intervals_equal_the_former_loop(session, block):
    want = collect(FormerCollector, session, block)
    got = collect(IntervalCollector, session, block)
    assert len(want) >= 40, "every hold is cut into several intervals"
    assert len(got) == len(want)
    for a, b in zip(got, want, strict=True):
        for x, y in zip(fields(a), fields(b), strict=True):
            if isinstance(y, tuple):
                for u, v in zip(x, y, strict=True):
                    np.testing.assert_array_equal(u, v)
            else:
                np.testing.assert_array_equal(x, y)

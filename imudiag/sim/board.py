"""The simulated USB board: a motion through the simulator, out as wire-protocol bytes.

Frame numbering follows spec/wire-protocol.md: a device-info frame after
power-up (seq 0) and then every 1000 frames (seq 1000, 2000, ... as long as no
``INFO`` answer was inserted), sample frames in between. Sample i of the
simulation goes out with seq ``i + 1 + i // 999`` (plus one for every extra
info frame sent on request); a dropped frame leaves its seq unused, so the
receiver counts it as lost. Info frames carry the time of the last sample sent.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Iterator
from typing import Any

import numpy as np

from imudiag.certificate import Certificate
from imudiag.drivers.wire import encode_info, encode_samples
from imudiag.samples import SampleBlock

from .effects import Effects
from .faults import Fault
from .simulator import Simulator
from .trajectories import Motion

INFO_EVERY = 1000  #: frames between device-info frames


def wire_seq(sample_seq: np.ndarray) -> np.ndarray:
    """Wire seq (unwrapped) of simulation sample numbers, with info frames at multiples of 1000."""
    s = np.asarray(sample_seq, dtype=np.int64)
    return s + 1 + s // (INFO_EVERY - 1)


class SimulatedBoard:
    """Generates the byte stream of the simulated board chunk by chunk.

    ``effects`` default to :meth:`Effects.board`; outputs are always whole counts
    (the wire carries integers). ``duration_s`` limits an endless motion.
    """

    def __init__(
        self,
        certificate: Certificate,
        motion: Motion,
        rate_hz: float | None = None,
        seed: int = 0,
        effects: Effects | None = None,
        faults: Iterable[Fault] = (),
        duration_s: float | None = None,
        info: dict[str, Any] | None = None,
    ) -> None:
        eff = effects if effects is not None else Effects.board()
        if not eff.quantize:
            eff = dataclasses.replace(eff, quantize=True)
        self.effects = eff
        self.motion = motion
        self.rate_hz = float(rate_hz if rate_hz is not None else certificate.sample_rate)
        if not (self.rate_hz > 0 and math.isfinite(self.rate_hz)):
            raise ValueError(f"sample rate must be > 0 Hz, got {self.rate_hz!r}")
        total = motion.n_samples(self.rate_hz)
        if duration_s is not None:
            cap = int(round(duration_s * self.rate_hz))
            total = cap if total is None else min(total, cap)
        self.total_samples = total  #: None when endless
        self.simulator = Simulator(certificate, eff, faults, seed)
        self.info = {
            "model": str(certificate.device.get("model", "simulated IMU")),
            "serial": str(certificate.device.get("serial", "0000")),
            "fw": "sim-1",
            "rate_hz": self.rate_hz if not self.rate_hz.is_integer() else int(self.rate_hz),
        }
        if info:
            self.info.update(info)
        self.next_index = 0  #: simulation samples generated so far
        self._extra = 0  # info frames sent on request (shift later seqs)
        self._last_ws = -1  # last wire seq used
        self._last_time_us = 0
        self._info_requested = False

    @property
    def exhausted(self) -> bool:
        """True when a finite session has produced all its samples."""
        return self.total_samples is not None and self.next_index >= self.total_samples

    def request_info(self) -> None:
        """Answer an ``INFO`` command: an info frame goes out before the next samples."""
        self._info_requested = True

    def generate(self, n: int) -> tuple[bytes, SampleBlock]:
        """The bytes of the next ``n`` simulated samples (fewer at the end) and the block
        as simulated (``seq`` = simulation sample number)."""
        if self.total_samples is not None:
            n = min(n, self.total_samples - self.next_index)
        n = max(int(n), 0)
        parts: list[bytes] = []
        if self._info_requested:
            self._last_ws += 1
            self._extra += 1
            parts.append(encode_info(self._last_ws, self._last_time_us, self.info))
            self._info_requested = False
        if n == 0:
            return b"".join(parts), SampleBlock.empty()
        traj = self.motion.sample(self.rate_hz, self.next_index, n)
        self.next_index += n
        block = self.simulator.step(traj)
        if len(block) == 0:
            return b"".join(parts), block
        # the simulator gives every sample its seq, temperature and flags
        assert block.seq is not None and block.temp is not None and block.flags is not None
        ws = wire_seq(block.seq) + self._extra
        time_us = np.rint(block.t * 1e6).astype(np.int64)
        raw = np.hstack([block.gyro, block.accel])
        # info frames due in (last_ws, ws[-1]]: wire seqs 1000 k + extra
        first_k = -((-(self._last_ws + 1 - self._extra)) // INFO_EVERY)
        info_seqs = np.arange(first_k * INFO_EVERY, ws[-1] - self._extra + 1, INFO_EVERY)
        info_seqs = info_seqs + self._extra
        info_pos = np.searchsorted(ws, info_seqs)
        cuts = np.union1d(np.flatnonzero(np.diff(ws) != 1) + 1, info_pos)
        bounds = np.concatenate([[0], cuts[(cuts > 0) & (cuts < len(ws))], [len(ws)]]).astype(int)
        k_info = 0
        for a, b in zip(bounds[:-1], bounds[1:], strict=True):
            while k_info < len(info_seqs) and info_pos[k_info] <= a:
                t_info = self._last_time_us if a == 0 else int(time_us[a - 1])
                parts.append(encode_info(int(info_seqs[k_info]), t_info, self.info))
                k_info += 1
            parts.append(
                encode_samples(
                    int(ws[a]), time_us[a:b], raw[a:b], block.temp[a:b], block.flags[a:b]
                )
            )
        while k_info < len(info_seqs):  # an info frame after the last sample of the chunk
            parts.append(encode_info(int(info_seqs[k_info]), int(time_us[-1]), self.info))
            k_info += 1
        self._last_ws = max(int(ws[-1]), int(info_seqs[-1]) if len(info_seqs) else -1)
        self._last_time_us = int(time_us[-1])
        return b"".join(parts), block

    def iter_bytes(self, chunk_s: float = 0.05) -> Iterator[bytes]:
        """Byte chunks of ``chunk_s`` seconds of samples until the session ends (endless
        motions never end): feed for :class:`imudiag.bench.pty.BoardWriter`."""
        n = max(1, int(round(chunk_s * self.rate_hz)))
        while not self.exhausted:
            data, _ = self.generate(n)
            if data:
                yield data

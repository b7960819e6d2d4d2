"""Blocks of IMU samples: the unit of data flowing from sources to the monitor.

Raw outputs are the paper's U in the certificate's output units (counts for
the wire protocol). Every array in a block has the same length N.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

#: Flag bits of the wire protocol (spec/wire-protocol.md).
FLAG_GYRO_SATURATED = 0x0001
FLAG_ACCEL_SATURATED = 0x0002
FLAG_ADC_ERROR = 0x0004
FLAG_SELF_TEST = 0x0008


_F64 = np.dtype(np.float64)


@dataclass
class SampleBlock:
    """N consecutive samples.

    t: (N,) seconds, strictly increasing. gyro, accel: (N, 3) raw outputs.
    temp: (N,) degC or None. flags: (N,) uint16 or None. seq: (N,) int or None.
    """

    t: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    temp: np.ndarray | None = None
    flags: np.ndarray | None = None
    seq: np.ndarray | None = None
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        # arrays already of the right kind (every reader's, the decoder's) are kept as they
        # are without a numpy call: a daemon builds a block on every read
        t = self.t
        if type(t) is not np.ndarray or t.dtype is not _F64 or t.ndim != 1:
            t = self.t = np.asarray(t, dtype=float)
        n = t.shape[0]
        for name in ("gyro", "accel"):
            a = getattr(self, name)
            if type(a) is not np.ndarray or a.dtype is not _F64 or a.ndim != 2 or a.shape[1] != 3:
                a = np.asarray(a, dtype=float).reshape(-1, 3)
                setattr(self, name, a)
            if a.shape[0] != n:
                raise ValueError(
                    f"sample block arrays differ in length: t {n}, gyro {self.gyro.shape[0]}, "
                    f"accel {self.accel.shape[0]}"
                )
        for name in ("temp", "flags", "seq"):
            v = getattr(self, name)
            if v is not None and len(v) != n:
                raise ValueError(f"sample block {name} has {len(v)} values, expected {n}")

    def __len__(self) -> int:
        return int(self.t.shape[0])

    def triad(self, name: str) -> np.ndarray:
        """The (N, 3) raw outputs of triad ``gyro`` or ``accel``."""
        return self.gyro if name == "gyro" else self.accel

    def slice(self, start: int, stop: int) -> SampleBlock:
        """Samples ``start:stop`` as a new block (views, no copy)."""
        return SampleBlock(
            t=self.t[start:stop],
            gyro=self.gyro[start:stop],
            accel=self.accel[start:stop],
            temp=None if self.temp is None else self.temp[start:stop],
            flags=None if self.flags is None else self.flags[start:stop],
            seq=None if self.seq is None else self.seq[start:stop],
            meta=self.meta,
        )

    def without_flags(self, bits: int) -> SampleBlock:
        """The samples whose flags carry none of ``bits`` (this block itself when no sample
        does, or without flags): how a consumer leaves flagged samples out."""
        if self.flags is None or not len(self):
            return self
        keep = (np.asarray(self.flags).astype(np.int64) & bits) == 0
        if keep.all():
            return self
        return SampleBlock(
            t=self.t[keep],
            gyro=self.gyro[keep],
            accel=self.accel[keep],
            temp=None if self.temp is None else self.temp[keep],
            flags=self.flags[keep],
            seq=None if self.seq is None else self.seq[keep],
            meta=self.meta,
        )

    @classmethod
    def empty(cls) -> SampleBlock:
        """A block of no samples."""
        return cls(t=np.zeros(0), gyro=np.zeros((0, 3)), accel=np.zeros((0, 3)))

    @classmethod
    def concat(cls, blocks: Iterable[SampleBlock]) -> SampleBlock:
        """Join blocks in order; optional columns are kept only if every block has them."""
        blocks = [b for b in blocks if len(b)]
        if not blocks:
            return cls.empty()

        def opt(name: str) -> np.ndarray | None:
            vals = [getattr(b, name) for b in blocks]
            return None if any(v is None for v in vals) else np.concatenate(vals)

        return cls(
            t=np.concatenate([b.t for b in blocks]),
            gyro=np.concatenate([b.gyro for b in blocks]),
            accel=np.concatenate([b.accel for b in blocks]),
            temp=opt("temp"),
            flags=opt("flags"),
            seq=opt("seq"),
            meta=blocks[0].meta,
        )

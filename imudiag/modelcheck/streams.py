"""Second pass: full-rate statistics of the quasi-static samples, for measured and simulated data.

The chunks of the first pass are grouped into *segments*: contiguous stretches
of one still run, within one half of the session (first / second in time), at
most ``max_segment_s`` long. Each segment's residual against a model (output
units) feeds

- the pooled overlapping Allan variance (sums of squared second differences of
  the cumulative sum per cluster size m, with the number of independent terms),
- the Welch PSD (Hann window, 50 % overlap, one-sided, output units^2/Hz),
- per-chunk sums (chunk means of the simulated data),
- accelerometer F0 = 1/2 (|x/g|^2 - 1) counts beyond the certificate's limit, per
  model and chunk parity (the held-out half of the two-fold split),

per half. Measured samples are streamed from the log (bounded memory: one
segment at a time); simulated segments are generated the same way.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

import numpy as np

from ..certificate import TriadModel
from ..noise_estimate import NoiseMeter
from ..samples import SampleBlock
from .rotations import MotionCollector
from .summaries import Chunks

#: bin edges of the F0 histograms (dimensionless): fine near 0, +-1 overall
F0_EDGES = np.concatenate([-np.geomspace(1.0, 1e-5, 200), [0.0], np.geomspace(1e-5, 1.0, 200)])

#: model prediction per sample: (t, temp|None, chunk index) -> (n, 6) raw outputs
Predictor = Callable[[np.ndarray, np.ndarray | None, np.ndarray], np.ndarray]


@dataclass
class Segments:
    """Segment of every chunk, and what each segment is."""

    of_chunk: np.ndarray  #: (C,) segment index
    half: np.ndarray  #: (S,) 0 first half, 1 second half
    run: np.ndarray  #: (S,) still run
    n: np.ndarray  #: (S,) samples
    t_half: float  #: s, time splitting the halves

    def __len__(self) -> int:
        return int(self.half.shape[0])


def make_segments(chunks: Chunks, t_half: float, max_samples: int) -> Segments:
    """Group chunks into segments: same run, same half, contiguous, at most ``max_samples``."""
    c = len(chunks)
    of_chunk = np.zeros(c, dtype=np.int64)
    half_list: list[int] = []
    run_list: list[int] = []
    n_list: list[int] = []
    half = (chunks.t_mid >= t_half).astype(np.int64)
    seg = -1
    for i in range(c):  # one step per chunk
        new = (
            seg < 0
            or chunks.run[i] != run_list[seg]
            or half[i] != half_list[seg]
            or n_list[seg] + int(chunks.n[i]) > max_samples
            or (
                i > 0
                and chunks.t_start[i] - chunks.t_end[i - 1]
                > 1.5 * (chunks.t_end[i] - chunks.t_start[i]) / max(int(chunks.n[i]) - 1, 1)
            )
        )
        if new:
            seg += 1
            half_list.append(int(half[i]))
            run_list.append(int(chunks.run[i]))
            n_list.append(0)
        of_chunk[i] = seg
        n_list[seg] += int(chunks.n[i])
    return Segments(
        of_chunk=of_chunk,
        half=np.array(half_list, dtype=np.int64),
        run=np.array(run_list, dtype=np.int64),
        n=np.array(n_list, dtype=np.int64),
        t_half=t_half,
    )


def allan_m_grid(max_len: int, points_per_decade: int) -> np.ndarray:
    """Cluster sizes 1 .. max_len // 2, log-spaced."""
    m_max = max(1, max_len // 2)
    k = int(math.ceil(math.log10(max(m_max, 1)) * points_per_decade)) + 1
    m = np.unique(np.round(np.logspace(0.0, math.log10(max(m_max, 1)), max(k, 1))).astype(int))
    return m[(m >= 1) & (m <= m_max)]


@dataclass
class F0Check:
    """Accelerometer F0 of one model on the samples of chunks with parity ``parity``."""

    name: str
    model: TriadModel
    parity: int | None  #: 0 / 1: only chunks of that parity; None: all
    steps: list[tuple[int, float, float]] = field(default_factory=list)  #: (column, t, size)
    checked: int = 0
    failed: int = 0
    #: histogram of F0 over ``F0_EDGES`` (dimensionless; outside them: the end bins)
    hist: np.ndarray = field(default_factory=lambda: np.zeros(F0_EDGES.shape[0] - 1))
    total: float = 0.0  #: sum of F0
    total_sq: float = 0.0  #: sum of F0^2

    def quantile(self, p: float) -> float:
        """Approximate quantile of F0 from the histogram (bin centre)."""
        cum = np.cumsum(self.hist)
        if cum[-1] <= 0:
            return math.nan
        k = int(np.searchsorted(cum, p * cum[-1]))
        return float(0.5 * (F0_EDGES[k] + F0_EDGES[k + 1]))


@dataclass
class SegmentStats:
    """Accumulated statistics (see the module docstring) of one data stream."""

    m: np.ndarray  #: Allan cluster sizes
    rate_hz: float
    nperseg: int  #: Welch segment length (0: no PSD)
    n_chunks: int
    predictors: dict[str, Predictor]  #: residual models by name ("baseline", "extended")
    f0_checks: list[F0Check] = field(default_factory=list)
    gravity_in: float = 1.0  #: gravity in accel input units
    f0_limit: float = 0.01
    allan_sum: dict = field(default_factory=dict)  #: (model, half) -> (M, 6)
    allan_terms: dict = field(default_factory=dict)  #: (model, half) -> (M,)
    allan_indep: dict = field(default_factory=dict)  #: (model, half) -> (M,)
    psd_sum: dict = field(default_factory=dict)  #: (model, half) -> (F, 6)
    psd_count: dict = field(default_factory=dict)
    chunk_sum: np.ndarray = field(default_factory=lambda: np.zeros((0, 6)))
    chunk_n: np.ndarray = field(default_factory=lambda: np.zeros(0))
    samples: int = 0
    noise: NoiseMeter | None = None  #: white noise, measured as every command measures it

    def __post_init__(self) -> None:
        self.chunk_sum = np.zeros((self.n_chunks, 6))
        self.chunk_n = np.zeros(self.n_chunks)
        if self.nperseg:
            k = np.arange(self.nperseg)
            self._window = 0.5 - 0.5 * np.cos(2.0 * math.pi * k / self.nperseg)
        self.noise = NoiseMeter(self.rate_hz)

    # -- one segment ----------------------------------------------------------------

    def add(
        self, t: np.ndarray, u: np.ndarray, temp: np.ndarray | None, chunk: np.ndarray, half: int
    ) -> None:
        """Accumulate one contiguous segment: t (n,) s, u (n, 6) raw outputs, chunk (n,)."""
        n = t.shape[0]
        if n == 0:
            return
        self.samples += n
        # chunk indices are non-decreasing within a segment: sum runs of equal index
        uniq, first = np.unique(chunk, return_index=True)
        self.chunk_sum[uniq] += np.add.reduceat(u, first, axis=0)
        self.chunk_n[uniq] += np.diff(np.concatenate([first, [n]]))
        assert self.noise is not None
        self.noise.update(u[:, :3], u[:, 3:])
        self.noise.gap()  # the next segment does not follow this one
        for name, predict in self.predictors.items():
            r = u - predict(t, temp, chunk)
            self._allan(name, half, r)
            if self.nperseg and n >= self.nperseg:
                self._psd(name, half, r)
        for chk in self.f0_checks:
            self._f0(chk, t, u, temp, chunk)

    def _allan(self, name: str, half: int, r: np.ndarray) -> None:
        key = (name, half)
        if key not in self.allan_sum:
            self.allan_sum[key] = np.zeros((self.m.shape[0], 6))
            self.allan_terms[key] = np.zeros(self.m.shape[0])
            self.allan_indep[key] = np.zeros(self.m.shape[0])
        n = r.shape[0]
        x = np.empty((n + 1, 6))
        x[0] = 0.0
        np.cumsum(r - r.mean(axis=0), axis=0, out=x[1:])
        for i, mj in enumerate(self.m.tolist()):  # one vectorised pass per cluster size
            if 2 * mj > n:
                break
            d = x[2 * mj :] - 2.0 * x[mj:-mj] + x[: -2 * mj]
            self.allan_sum[key][i] += np.einsum("ij,ij->j", d, d) / (mj * mj)
            self.allan_terms[key][i] += d.shape[0]
            self.allan_indep[key][i] += max(n // mj - 1, 0)

    def _psd(self, name: str, half: int, r: np.ndarray) -> None:
        p = self.nperseg
        key = (name, half)
        step = p // 2
        starts = np.arange(0, r.shape[0] - p + 1, step)
        if key not in self.psd_sum:
            self.psd_sum[key] = np.zeros((p // 2 + 1, 6))
            self.psd_count[key] = 0
        batch = max(1, (1 << 20) // (p * 6))
        k = np.arange(p)
        for b0 in range(0, starts.shape[0], batch):
            idx = starts[b0 : b0 + batch, None] + k[None, :]
            seg = r[idx]  # (B, p, 6)
            seg = seg - seg.mean(axis=1, keepdims=True)
            spec = np.fft.rfft(seg * self._window[None, :, None], axis=1)
            self.psd_sum[key] += np.sum(spec.real**2 + spec.imag**2, axis=0)
            self.psd_count[key] += idx.shape[0]

    def _f0(
        self, chk: F0Check, t: np.ndarray, u: np.ndarray, temp: np.ndarray | None, chunk: np.ndarray
    ) -> None:
        sel = np.ones(t.shape[0], dtype=bool) if chk.parity is None else (chunk % 2 == chk.parity)
        if not np.any(sel):
            return
        a = u[sel, 3:6].copy()
        for col, ts, size in chk.steps:
            a[:, col - 3] -= size * (t[sel] >= ts)
        x = chk.model.inverse(a, temp_c=None if temp is None else temp[sel])
        f0 = 0.5 * (np.sum(x * x, axis=1) / self.gravity_in**2 - 1.0)
        chk.checked += int(f0.shape[0])
        chk.failed += int(np.count_nonzero(np.abs(f0) > self.f0_limit))
        clipped = np.clip(f0, F0_EDGES[0], F0_EDGES[-1] - 1e-12)
        chk.hist += np.histogram(clipped, bins=F0_EDGES)[0]
        chk.total += float(np.sum(f0))
        chk.total_sq += float(np.sum(f0 * f0))

    # -- results ----------------------------------------------------------------------

    def allan(
        self, name: str, halves: Iterable[int] = (0, 1)
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(tau s, adev (M, 6) output units, independent terms (M,)) over the given halves."""
        tot = np.zeros((self.m.shape[0], 6))
        terms = np.zeros(self.m.shape[0])
        indep = np.zeros(self.m.shape[0])
        for h in halves:
            key = (name, h)
            if key in self.allan_sum:
                tot += self.allan_sum[key]
                terms += self.allan_terms[key]
                indep += self.allan_indep[key]
        ok = terms > 0
        avar = np.where(ok[:, None], tot / np.maximum(terms, 1)[:, None] / 2.0, np.nan)
        return self.m / self.rate_hz, np.sqrt(avar), indep

    def psd(self, name: str, half: int) -> tuple[np.ndarray, np.ndarray, int]:
        """(frequency Hz, one-sided PSD (F, 6) output units^2/Hz, segments averaged)."""
        key = (name, half)
        if not self.nperseg or key not in self.psd_sum or self.psd_count[key] == 0:
            return np.zeros(0), np.zeros((0, 6)), 0
        p = self.nperseg
        scale = 1.0 / (self.rate_hz * float(np.sum(self._window**2)))
        dens = self.psd_sum[key] / self.psd_count[key] * scale
        dens[1:-1] *= 2.0
        return np.fft.rfftfreq(p, 1.0 / self.rate_hz), dens, int(self.psd_count[key])

    def chunk_means(self) -> np.ndarray:
        """(C, 6) mean outputs of every chunk seen (NaN for chunks without samples)."""
        with np.errstate(invalid="ignore", divide="ignore"):
            return self.chunk_sum / self.chunk_n[:, None]

    def sample_sigma(self) -> np.ndarray:
        """(6,) per-sample white noise, output units (:mod:`imudiag.noise_estimate`; NaN for a
        stream without a whole 1 s still chunk)."""
        assert self.noise is not None
        return self.noise.sample_sigma()


def stream_measured(
    blocks: Iterable[SampleBlock],
    chunks: Chunks,
    segments: Segments,
    stats: SegmentStats,
    motion: MotionCollector | None = None,
) -> None:
    """Feed the quasi-static samples of a measured log, one segment at a time (and every
    block to ``motion``, a :class:`~.rotations.MotionCollector`, when given)."""
    buf: list[tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray]] = []
    current = -1

    def flush() -> None:
        if not buf:
            return
        t = np.concatenate([b[0] for b in buf])
        u = np.concatenate([b[1] for b in buf])
        temp = None if buf[0][2] is None else np.concatenate([b[2] for b in buf])
        ch = np.concatenate([b[3] for b in buf])
        stats.add(t, u, temp, ch, int(segments.half[current]))
        buf.clear()

    if len(chunks) == 0:
        return
    for block in blocks:
        if len(block) == 0:
            continue
        if motion is not None:
            motion.add(block.t, block.gyro, block.accel, block.temp)
        t = block.t
        idx = np.searchsorted(chunks.t_start, t, side="right") - 1
        inside = (idx >= 0) & (t <= chunks.t_end[np.maximum(idx, 0)])
        if not np.any(inside):
            continue
        rows = np.flatnonzero(inside)
        seg = segments.of_chunk[idx[rows]]
        cut = np.flatnonzero(np.diff(seg) != 0) + 1
        starts = np.concatenate([[0], cut])
        stops = np.concatenate([cut, [rows.shape[0]]])
        u = np.concatenate([block.gyro, block.accel], axis=1)
        for s0, s1 in zip(starts.tolist(), stops.tolist(), strict=True):  # few per block
            sid = int(seg[s0])
            if sid != current:
                flush()
                current = sid
            r = rows[s0:s1]
            buf.append((t[r], u[r], None if block.temp is None else block.temp[r], idx[r]))
    flush()
    if motion is not None:
        motion.finish()


__all__ = [
    "F0Check",
    "Predictor",
    "SegmentStats",
    "Segments",
    "allan_m_grid",
    "make_segments",
    "stream_measured",
]

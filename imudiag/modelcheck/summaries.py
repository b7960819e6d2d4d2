"""First pass over a session: quasi-static chunks, streamed block by block.

Still stretches (the project's :class:`~imudiag.quasistatic.QuasiStaticDetector`)
are cut into *chunks* of ``chunk_s`` seconds. A chunk keeps only summaries:
time span, sample count, mean raw outputs of both triads, the means of its two
halves (their difference measures the noise of a chunk mean, colour included),
mean temperature and the still run it belongs to. Memory grows with the number
of chunks, not samples: a log larger than memory is summarised in bounded
memory per block. The last ``trim_s`` of every still run is dropped (the
detector's trailing window notices a motion a few samples late), and runs are
broken at time gaps.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..certificate import Certificate, Noise
from ..logs import open_log
from ..quasistatic import BAD_FLAGS, QuasiStaticDetector
from ..samples import SampleBlock
from .config import ModelCheckConfig

#: A re-startable source of sample blocks (each call starts the session anew).
BlockSource = Callable[[], Iterable[SampleBlock]]

# columns of the buffered rows
_T, _G, _A, _TEMP = 0, slice(1, 4), slice(4, 7), 7
_NCOL = 8
#: sub-blocks per chunk for the noise of a chunk mean
SUB_BLOCKS = 8
_ROW = 31


#: samples per block read from a log: the working set of every pass scales with it
DEFAULT_BLOCK_SIZE = 8192


#: Told how far a pass over the log has got: (which pass, fraction read 0..1 or None when
#: unknown, samples read).
ProgressCallback = Callable[[str, float | None, int], None]


def block_source(
    log: str | Path | SampleBlock | BlockSource,
    block_size: int = DEFAULT_BLOCK_SIZE,
    progress: ProgressCallback | None = None,
) -> tuple[BlockSource, dict[str, Any]]:
    """A re-startable block source and the log's metadata, from a path, a block or a callable;
    ``progress`` (a path or a block) is told how far each pass has got."""
    passes = [0]
    if isinstance(log, SampleBlock):
        whole = log

        def from_block() -> Iterator[SampleBlock]:
            passes[0] += 1
            n = len(whole)
            for i in range(0, n, block_size):
                yield whole.slice(i, min(i + block_size, n))
                if progress is not None:
                    done = min(n, i + block_size)
                    progress(f"pass {passes[0]}", done / n, done)

        return from_block, dict(whole.meta)
    if callable(log):
        return log, {}
    path = Path(log)
    with open_log(path, block_size=block_size) as reader:
        meta = dict(reader.meta)

    def from_file() -> Iterator[SampleBlock]:
        passes[0] += 1
        with open_log(path, block_size=block_size) as r:
            for block in r:
                yield block
                if progress is not None:
                    progress(f"pass {passes[0]}", r.fraction_read(), r.samples_read)

    return from_file, meta


@dataclass
class Chunks:
    """Quasi-static chunks (arrays of length C) of one session.

    t_start, t_end: s. n: samples. gyro, accel (C, 3): mean raw outputs.
    gyro_half, accel_half (C, 2, 3): means of the first and second half.
    n_half (C, 2). sub_var (C, 6): variance of the means of ``SUB_BLOCKS`` equal sub-blocks
    times their length (a per-sample-equivalent white variance, output units^2, that
    includes noise colour up to a sub-block). temp (C,): mean degC (NaN without a
    temperature column).
    run (C,): index of the still run.
    """

    t_start: np.ndarray
    t_end: np.ndarray
    n: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    gyro_half: np.ndarray
    accel_half: np.ndarray
    n_half: np.ndarray
    sub_var: np.ndarray
    temp: np.ndarray
    run: np.ndarray

    def __len__(self) -> int:
        return int(self.t_start.shape[0])

    @property
    def t_mid(self) -> np.ndarray:
        """Chunk mid times, s."""
        return 0.5 * (self.t_start + self.t_end)

    def triad(self, name: str) -> np.ndarray:
        """Mean raw outputs (C, 3) of ``gyro`` or ``accel``."""
        return self.gyro if name == "gyro" else self.accel

    def half(self, name: str) -> np.ndarray:
        """Half means (C, 2, 3) of ``gyro`` or ``accel``."""
        return self.gyro_half if name == "gyro" else self.accel_half


@dataclass
class Session:
    """What the first pass learnt about a session."""

    chunks: Chunks
    rate_hz: float  #: Hz
    samples: int  #: samples in the log
    static_samples: int  #: samples in chunks
    t_first: float  #: s
    t_last: float  #: s
    has_temp: bool  #: the log has a temperature column
    quantum: np.ndarray  #: (6,) output step of each sensor (0: not quantised)
    meta: dict[str, Any] = field(default_factory=dict)
    chunk_s: float = 1.0  #: s, the chunk length used

    @property
    def duration_s(self) -> float:
        """Session length, s."""
        return self.t_last - self.t_first

    @property
    def runs(self) -> np.ndarray:
        """Distinct still-run indices."""
        return np.unique(self.chunks.run)


def _estimate_rate(t: np.ndarray, meta: dict[str, Any], fallback: float) -> float:
    """Sample rate (Hz): the median time step of the data, else the metadata, else fallback."""
    if t.shape[0] >= 3:
        dt = float(np.median(np.diff(t)))
        if dt > 0 and math.isfinite(dt):
            return 1.0 / dt
    try:
        return float(meta.get("sample_rate"))  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return float(fallback)


class ChunkCollector:
    """Streaming first pass: feed blocks, then :meth:`finish` returns the :class:`Session`."""

    def __init__(
        self,
        certificate: Certificate,
        config: ModelCheckConfig | None = None,
        meta: dict[str, Any] | None = None,
        rate_hz: float | None = None,
        detection_sigma: np.ndarray | None = None,
    ) -> None:
        self.certificate = certificate
        self._rate_given = rate_hz
        self._detection_sigma = detection_sigma
        self.config = config or ModelCheckConfig()
        self.meta = dict(meta or {})
        self.rate_hz: float | None = None
        self.detector: QuasiStaticDetector | None = None
        self._run: list[np.ndarray] = []
        self._run_n = 0
        self._run_index = -1
        self._in_run = False
        self._last_t: float | None = None
        self._rows: list[np.ndarray] = []  # emitted chunk summaries
        self.samples = 0
        self.static_samples = 0
        self.t_first: float | None = None
        self.has_temp = True
        self._q_diffs: list[np.ndarray] = []
        self._q_count = 0
        self._pending: list[SampleBlock] = []

    # -- set-up on the first samples -----------------------------------------------

    def _start(self, block: SampleBlock) -> None:
        cfg = self.config
        self.rate_hz = self._rate_given or _estimate_rate(
            block.t, self.meta or block.meta, self.certificate.sample_rate
        )
        # the detector must not trust the noise figures being checked: it uses the noise
        # measured by :func:`detection_noise` (or estimates it itself, block-dependently)
        blind = copy.deepcopy(self.certificate)
        for k, tri in enumerate((blind.gyro, blind.accel)):
            tri.noise = None
            if self._detection_sigma is not None:
                sig = np.asarray(self._detection_sigma[3 * k : 3 * k + 3], dtype=float)
                if np.all(sig > 0) and np.all(np.isfinite(sig)):
                    tri.noise = Noise(density=sig / math.sqrt(self.rate_hz / 2.0))
        self.detector = QuasiStaticDetector(
            blind,
            self.rate_hz,
            window_s=cfg.detector_window_s,
            k_sigma=cfg.detector_k_sigma,
        )
        self.chunk_n = max(4, int(round(cfg.chunk_s * self.rate_hz)))
        self.min_chunk_n = max(4, int(round(cfg.min_chunk_s * self.rate_hz)))
        self.trim_n = max(0, int(round(cfg.trim_s * self.rate_hz)))
        self.max_step = 3.0 / self.rate_hz

    # -- chunks ----------------------------------------------------------------------

    def _emit(self, rows: np.ndarray) -> None:
        n = rows.shape[0]
        h = n // 2
        temp = rows[:, _TEMP]
        row = np.empty(_ROW)
        row[0], row[1], row[2] = rows[0, _T], rows[-1, _T], n
        row[3:9] = rows[:, 1:7].mean(axis=0)
        row[9:15] = rows[:h, 1:7].mean(axis=0)
        row[15:21] = rows[h:, 1:7].mean(axis=0)
        row[21], row[22] = h, n - h
        row[23] = float(np.mean(temp)) if np.all(np.isfinite(temp)) else math.nan
        row[24] = self._run_index
        m = n // SUB_BLOCKS
        sub = rows[: m * SUB_BLOCKS, 1:7].reshape(SUB_BLOCKS, m, 6).mean(axis=1)
        row[25:31] = sub.var(axis=0, ddof=1) * m
        self._rows.append(row)
        self.static_samples += n
        if self._q_count < 20_000:  # enough changes to see the output step
            d = np.abs(np.diff(rows[:, 1:7], axis=0))
            self._q_diffs.append(d)
            self._q_count += d.shape[0]

    def _drain(self, final: bool) -> None:
        """Emit whole chunks from the run buffer (keeping the trim reserve unless final)."""
        if not self._run:
            return
        reserve = 0 if final else self.trim_n
        if self._run_n < self.chunk_n + reserve and not final:
            return
        rows = np.concatenate(self._run)
        start = 0
        while rows.shape[0] - start >= self.chunk_n + reserve:
            self._emit(rows[start : start + self.chunk_n])
            start += self.chunk_n
        rest = rows[start:]
        self._run = [rest] if rest.shape[0] else []
        self._run_n = rest.shape[0]

    def _close_run(self) -> None:
        if self._in_run:
            self._drain(final=False)
            if self._run:
                rows = np.concatenate(self._run)
                keep = rows.shape[0] - self.trim_n
                if keep >= self.min_chunk_n:
                    self._emit(rows[:keep])
        self._run, self._run_n, self._in_run = [], 0, False

    def _open_run(self) -> None:
        self._run_index += 1
        self._in_run = True

    # -- streaming ---------------------------------------------------------------------

    def update(self, block: SampleBlock) -> None:
        """Feed the next block of the session."""
        n = len(block)
        if n == 0:
            return
        if self.detector is None:
            # wait for enough samples to estimate the rate
            self._pending.append(block)
            if sum(len(b) for b in self._pending) < 64:
                return
            block = SampleBlock.concat(self._pending)
            self._pending = []
            self._start(block)
            n = len(block)
        self._process(block)

    def _process(self, block: SampleBlock) -> None:
        n = len(block)
        assert self.detector is not None
        if self.t_first is None:
            self.t_first = float(block.t[0])
        self.samples += n
        if block.temp is None:
            self.has_temp = False
        mask = self.detector.update(block)
        if block.flags is not None:
            mask &= (np.asarray(block.flags).astype(np.int64) & BAD_FLAGS) == 0
        rows = np.empty((n, _NCOL))
        rows[:, _T] = block.t
        rows[:, _G] = block.gyro
        rows[:, _A] = block.accel
        rows[:, _TEMP] = np.nan if block.temp is None else block.temp
        t = block.t
        prev = np.concatenate([[self._last_t if self._last_t is not None else t[0]], t[:-1]])
        jump = (t - prev) > self.max_step
        self._last_t = float(t[-1])
        change = np.flatnonzero((np.diff(mask.astype(np.int8)) != 0) | jump[1:]) + 1
        starts = np.concatenate([[0], change])
        stops = np.concatenate([change, [n]])
        for s0, s1 in zip(starts.tolist(), stops.tolist(), strict=True):  # few segments
            if jump[s0]:
                self._close_run()
            if mask[s0]:
                if not self._in_run:
                    self._open_run()
                self._run.append(rows[s0:s1])
                self._run_n += s1 - s0
                self._drain(final=False)
            else:
                self._close_run()

    def _quantum(self) -> np.ndarray:
        """Output step per sensor: the smallest non-zero change, if all changes are multiples."""
        out = np.zeros(6)
        if not self._q_diffs:
            return out
        d = np.concatenate(self._q_diffs)
        for j in range(6):
            dj = d[:, j]
            pos = dj[dj > 0]
            if pos.shape[0] < 20:
                continue
            q = float(np.min(pos))
            k = pos / q
            if np.mean(np.abs(k - np.round(k)) < 0.02) > 0.98 and np.median(k) < 50:
                out[j] = q
        return out

    def finish(self) -> Session:
        """Close the stream and return the session's summaries."""
        if self._pending:
            block = SampleBlock.concat(self._pending)
            self._pending = []
            self._start(block)
            self._process(block)
        if self.detector is None:
            raise ValueError("the log holds no samples")
        self._close_run()
        if self._rows:
            a = np.vstack(self._rows)
        else:
            a = np.zeros((0, _ROW))
        c = a.shape[0]
        chunks = Chunks(
            t_start=a[:, 0],
            t_end=a[:, 1],
            n=a[:, 2].astype(np.int64),
            gyro=a[:, 3:6],
            accel=a[:, 6:9],
            gyro_half=np.stack([a[:, 9:12], a[:, 15:18]], axis=1),
            accel_half=np.stack([a[:, 12:15], a[:, 18:21]], axis=1),
            n_half=a[:, 21:23],
            sub_var=a[:, 25:31],
            temp=a[:, 23],
            run=a[:, 24].astype(np.int64),
        )
        if c and not self.has_temp:
            chunks.temp[:] = math.nan
        assert self.rate_hz is not None and self.t_first is not None
        return Session(
            chunks=chunks,
            rate_hz=self.rate_hz,
            samples=self.samples,
            static_samples=self.static_samples,
            t_first=self.t_first,
            t_last=float(self._last_t if self._last_t is not None else self.t_first),
            has_temp=self.has_temp and c > 0 and bool(np.all(np.isfinite(chunks.temp))),
            quantum=self._quantum(),
            meta=self.meta,
            chunk_s=self.config.chunk_s,
        )


def session_rate(source: BlockSource, meta: dict[str, Any], fallback: float) -> float:
    """Sample rate (Hz) from the median time step of the first 1000 samples."""
    got: list[np.ndarray] = []
    n = 0
    for block in source():
        got.append(block.t)
        n += len(block)
        if n >= 1000:
            break
    t = np.concatenate(got) if got else np.zeros(0)
    return _estimate_rate(t[:1000], meta, fallback)


def detection_noise(
    source: BlockSource, rate_hz: float, window_s: float, max_windows: int = 200_000
) -> tuple[np.ndarray, int]:
    """Per-sample noise (6,) output units for the quasi-static detector, from the data.

    The variance of every sensor in fixed, non-overlapping windows of ``window_s`` (aligned
    on the sample index, so independent of block boundaries); the 5 % quantile over the
    windows, divided by that quantile of chi2(W-1)/(W-1), is the noise of the quietest
    stretches (the unit still). At most ``max_windows`` windows are kept (evenly thinned).
    """
    from ..stats import chi2_ratio_quantile

    w = max(3, int(round(window_s * rate_hz)))
    carry = np.zeros((0, 6))
    parts: list[np.ndarray] = []
    kept = 0
    stride = 1
    total = 0
    for block in source():
        total += len(block)
        x = np.concatenate([carry, np.concatenate([block.gyro, block.accel], axis=1)])
        m = x.shape[0] // w
        if m:
            v = x[: m * w].reshape(m, w, 6).var(axis=1, ddof=1)
            parts.append(v[::stride])
            kept += parts[-1].shape[0]
            if kept > max_windows:
                stride *= 2
                parts = [np.concatenate(parts)[::2]]
                kept = parts[0].shape[0]
        carry = x[m * w :]
    if not parts:
        return np.full(6, np.nan), total
    v = np.concatenate(parts)
    ratio = chi2_ratio_quantile(w - 1, -1.6448536269514729)
    return np.sqrt(np.quantile(v, 0.05, axis=0) / ratio), total


def collect(
    source: BlockSource,
    certificate: Certificate,
    config: ModelCheckConfig | None = None,
    meta: dict[str, Any] | None = None,
) -> Session:
    """Run the first pass over ``source`` (after a look at its rate and noise)."""
    cfg = copy.copy(config or ModelCheckConfig())
    meta = dict(meta or {})
    rate = session_rate(source, meta, certificate.sample_rate)
    sigma, total = detection_noise(source, rate, cfg.detector_window_s)
    # long sessions: longer chunks, so the number of chunks (memory, time) stays bounded
    cfg.chunk_s = max(cfg.chunk_s, total / rate / max(cfg.max_chunks, 1))
    cfg.min_chunk_s = max(cfg.min_chunk_s, 0.5 * cfg.chunk_s)
    col = ChunkCollector(certificate, cfg, meta, rate_hz=rate, detection_sigma=sigma)
    for block in source():
        col.update(block)
    return col.finish()


__all__ = [
    "BlockSource",
    "ChunkCollector",
    "DEFAULT_BLOCK_SIZE",
    "Chunks",
    "Session",
    "ProgressCallback",
    "block_source",
    "collect",
    "detection_noise",
    "session_rate",
]

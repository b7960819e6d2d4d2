"""Common ground of the log formats: the error, the column rules, reader and writer bases.

Every format module (one per file format) builds on :class:`LogReader` and
:class:`LogWriter` and checks values with :func:`first_violation`.
"""

from __future__ import annotations

import io
import json
import os
import re
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

import numpy as np

from ..errors import BadInput
from ..samples import SampleBlock
from .gnss_fixes import GnssFixes


class LogError(BadInput):
    """A log that breaks a rule of spec/sample-log.md; names file, line and reason."""

    def __init__(self, path: str, reason: str, line: int | None = None) -> None:
        self.path = path
        self.line = line
        self.reason = reason
        where = f"{path}:{line}" if line is not None else str(path)
        super().__init__(f"{where}: {reason}")


#: Required columns, in the order a :class:`SampleBlock` holds them.
REQUIRED_COLUMNS = ("t", "gx", "gy", "gz", "ax", "ay", "az")
#: Optional columns: temp (degC), seq (frame counter), flags (wire-protocol bits).
OPTIONAL_COLUMNS = ("temp", "seq", "flags")
DEFAULT_BLOCK_SIZE = 65536  #: samples per block

META_KEY = re.compile(r"[A-Za-z_][A-Za-z0-9_.\-]*")
_INT_LIMITS = {"seq": (0, 2**63 - 1), "flags": (0, 0xFFFF)}


def parse_meta_value(value: str) -> Any:
    """A metadata value: JSON objects and arrays are parsed, everything else stays text."""
    if value[:1] in ("{", "["):
        try:
            return json.loads(value)
        except ValueError:
            pass
    return value


def make_block(cols: dict[str, np.ndarray], meta: dict[str, Any]) -> SampleBlock:
    """A SampleBlock from validated float columns (seq, flags converted to integers; absent
    accelerometer columns, of a gyro-only log, as NaN)."""
    nan = np.full(len(cols["t"]), np.nan)  # a gyro-only log (LogOptions.gyro_only)
    return SampleBlock(
        t=cols["t"],
        gyro=np.column_stack([cols["gx"], cols["gy"], cols["gz"]]),
        accel=np.column_stack([cols.get("ax", nan), cols.get("ay", nan), cols.get("az", nan)]),
        temp=cols.get("temp"),
        seq=None if "seq" not in cols else cols["seq"].astype(np.int64),
        flags=None if "flags" not in cols else cols["flags"].astype(np.uint16),
        meta=meta,
    )


#: Largest sensor output accepted in any unit (a 32-bit ADC gives 4.3e9 counts).
ABSURD = 1e10


def first_violation(cols: dict[str, np.ndarray], last_t: float | None) -> tuple[int, str] | None:
    """Index and reason of the first sample breaking a value rule, or None (vectorised).

    Rules: every value finite; sensor outputs within :data:`ABSURD` (no ADC,
    no SI reading comes near it: 1e300 is a corrupt value, not a sample); ``t``
    strictly increasing, also after ``last_t`` (the previous block's last
    time); ``seq`` and ``flags`` integers in range.
    """
    n = len(cols["t"])
    first = n
    reason = ""
    for name, v in cols.items():
        bad = np.flatnonzero(~np.isfinite(v[:first]))
        if bad.size:
            first = int(bad[0])
            reason = f"column {name!r}: non-finite value {float(v[first])!r}"
    for name in ("gx", "gy", "gz", "ax", "ay", "az"):
        if name not in cols:
            continue
        v = cols[name][:first]
        bad = np.flatnonzero(np.abs(v) > ABSURD)
        if bad.size and bad[0] < first:
            first = int(bad[0])
            reason = (
                f"column {name!r}: absurd value {float(v[first])!r} (beyond "
                f"{ABSURD:g}, no sensor output comes near it)"
            )
    for name, (lo, hi) in _INT_LIMITS.items():
        if name in cols:
            v = cols[name][:first]
            bad = np.flatnonzero((v != np.floor(v)) | (v < lo) | (v > hi))
            if bad.size and bad[0] < first:
                first = int(bad[0])
                got = float(v[first])
                reason = f"column {name!r}: expected an integer {lo}..{hi}, got {got!r}"
    t = cols["t"][: first + 1] if first < n else cols["t"]
    prev = np.concatenate(([-np.inf if last_t is None else last_t], t[:-1]))
    bad = np.flatnonzero(~(t > prev))
    if bad.size and bad[0] <= first and not (bad[0] == first and reason):
        first = int(bad[0])
        reason = f"t not increasing: {float(t[first])!r} s after {float(prev[first])!r} s"
    return (first, reason) if reason else None


class LogReader:
    """A sample log opened for streaming; iterate to get :class:`SampleBlock` s in order.

    ``meta`` holds the log's metadata, ``path`` its file name. Blocks hold at
    most ``block_size`` samples and share the ``meta`` dict. Iterating again
    starts over from the first sample. A rule violation raises
    :class:`LogError` when its block is reached: do not report on a log until
    iteration has finished.
    """

    format = ""

    def __init__(self, path: str | Path, block_size: int = DEFAULT_BLOCK_SIZE) -> None:
        if int(block_size) < 1:
            raise ValueError(f"block_size must be >= 1, got {block_size}")
        self.path = str(path)
        self.block_size = int(block_size)
        self.meta: dict[str, Any] = {}
        self.samples_read = 0  #: samples yielded by the current or last iteration
        self._handles: list[IO[bytes]] = []

    def __iter__(self) -> Iterator[SampleBlock]:
        self.samples_read = 0
        total = 0
        for block in self._blocks():
            total += len(block)
            self.samples_read = total
            yield block
        if total == 0:
            raise LogError(self.path, "empty log: no samples")

    def _blocks(self) -> Iterator[SampleBlock]:
        raise NotImplementedError

    def _total_samples(self) -> int | None:
        """Samples in the log when the format knows before reading them (None: it does not)."""
        return None

    def gnss(self) -> GnssFixes | None:
        """The GNSS fixes the log itself carries, in the samples' clock (None: the format
        carries none, or this log holds none)."""
        return None

    def fraction_read(self) -> float | None:
        """How far the current iteration has got, 0..1 (for progress bars): samples read of
        the log's samples where the format knows them, else the position in the file (the
        compressed file for a .gz); None when neither can be told."""
        total = self._total_samples()
        if total:
            return min(1.0, self.samples_read / total)
        try:
            size = os.path.getsize(self.path)
        except OSError:
            return None
        for fh in self._handles:
            try:
                pos = os.lseek(fh.fileno(), 0, os.SEEK_CUR)
            except (OSError, AttributeError, ValueError, io.UnsupportedOperation):
                continue
            return min(1.0, pos / size) if size > 0 else None
        return None

    def _open(self, opener: Any, *args: Any) -> Any:
        try:
            fh = opener(*args)
        except OSError as exc:
            raise LogError(self.path, f"cannot read: {exc.strerror or exc}") from None
        self._handles.append(fh)
        return fh

    def _read_head(self, n: int) -> bytes:
        """The first ``n`` bytes of the file (for a format's magic test); LogError if unreadable."""
        fh = self._open(open, self.path, "rb")
        try:
            return bytes(fh.read(n))
        finally:
            self._release(fh)

    def _release(self, fh: Any) -> None:
        fh.close()
        if fh in self._handles:
            self._handles.remove(fh)

    def close(self) -> None:
        """Close any open file handles; safe to call twice."""
        while self._handles:
            self._handles.pop().close()

    def __enter__(self) -> LogReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class ColumnsReader(LogReader):
    """A reader whose format is parsed whole into columns (``self._cols``, set by the
    subclass), then handed out in blocks, each checked by :func:`first_violation`;
    ``_where(i)`` names sample ``i`` (0-based) in the file's own terms for errors."""

    _cols: dict[str, np.ndarray]

    def _where(self, index: int) -> str:
        return f"sample {index + 1}"

    def _total_samples(self) -> int | None:
        return len(self._cols["t"]) if hasattr(self, "_cols") else None

    def _blocks(self) -> Iterator[SampleBlock]:
        n = len(self._cols["t"])
        last_t: float | None = None
        for start in range(0, n, self.block_size):
            cols = {k: v[start : start + self.block_size] for k, v in self._cols.items()}
            bad = first_violation(cols, last_t)
            if bad is not None:
                raise LogError(self.path, f"{self._where(start + bad[0])}: {bad[1]}")
            last_t = float(cols["t"][-1])
            yield make_block(cols, self.meta)


def format_float(values: np.ndarray) -> list[str]:
    """Shortest text that reads back to the same float64, per value."""
    return list(map(repr, values.tolist()))


class LogWriter:
    """Writes blocks to a new log; the file appears under its name on :meth:`close`.

    Data goes to a unique temporary ``.NAME.XXXXXXXX.part`` beside it first,
    so a log cut short by an error is never mistaken for a whole one (leaving
    the ``with`` block by an exception removes it). Every block must have the
    same optional columns as the first; values must be finite and ``t``
    strictly increasing across blocks.
    """

    def __init__(self, path: str | Path, meta: dict[str, Any] | None = None) -> None:
        self.path = str(path)
        self.meta = dict(meta or {})
        self.samples_written = 0
        self._part_path: str | None = None  # the unique temporary, made on first use
        self._columns: list[str] | None = None
        self._last_t: float | None = None
        self._closed = False

    def write(self, block: SampleBlock) -> None:
        """Append the samples of ``block``."""
        if self._closed:
            raise ValueError(f"{self.path}: writer is closed")
        cols = {
            "t": block.t,
            "gx": block.gyro[:, 0],
            "gy": block.gyro[:, 1],
            "gz": block.gyro[:, 2],
            "ax": block.accel[:, 0],
            "ay": block.accel[:, 1],
            "az": block.accel[:, 2],
        }
        for name in OPTIONAL_COLUMNS:
            v = getattr(block, name)
            if v is not None:
                cols[name] = np.asarray(v)
        names = list(cols)
        if self._columns is None:
            self._columns = names
            self._start(names)
        elif names != self._columns:
            raise LogError(self.path, f"block has columns {names}, the log has {self._columns}")
        if not len(block):
            return
        bad = first_violation({k: v.astype(float) for k, v in cols.items()}, self._last_t)
        if bad is not None:
            raise LogError(
                self.path, f"cannot write sample {self.samples_written + bad[0]}: {bad[1]}"
            )
        self._write(cols, len(block))
        self._last_t = float(block.t[-1])
        self.samples_written += len(block)

    @property
    def _part(self) -> str:
        """The temporary file beside the log (unique, ``.NAME.XXXXXXXX.part``)."""
        if self._part_path is None:
            from .. import atomic

            try:
                self._part_path = atomic.temp_path(self.path)
            except OSError as exc:
                raise LogError(self.path, f"cannot write: {exc.strerror or exc}") from None
        return self._part_path

    def _start(self, columns: list[str]) -> None:
        """Called with the column names before the first block is written."""

    def _write(self, cols: dict[str, np.ndarray], n: int) -> None:
        raise NotImplementedError

    def _finish(self) -> None:
        """Flush and close the ``.part`` file."""

    def close(self) -> None:
        """Finish the file and give it its name."""
        if self._closed:
            return
        if self._columns is None:
            self._columns = list(REQUIRED_COLUMNS)
            self._start(self._columns)
        self._finish()
        self._closed = True
        from .. import atomic

        atomic.commit(self._part, self.path)

    def abort(self) -> None:
        """Stop writing and remove the partial file."""
        if self._closed:
            return
        self._closed = True
        try:
            self._finish()
        finally:
            if self._part_path is not None:
                from .. import atomic

                atomic.discard(self._part_path)

    def __enter__(self) -> LogWriter:
        return self

    def __exit__(self, exc_type: object, *exc: object) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

"""Sample logs (spec/sample-log.md): streaming readers and writers for CSV, NPZ, raw capture.

Formats, chosen by file name:

- ``.csv`` / ``.csv.gz``: ``#`` comment lines; ``# key: value`` comments before
  the header are metadata. The header names the columns, in any order:
  required ``t`` (s, strictly increasing) ``gx gy gz ax ay az`` (raw outputs
  in the certificate's output units), optional ``temp`` (degC), ``seq``,
  ``flags``. Columns with other names are ignored (their content is not
  checked, only the number of fields per row). Empty lines are skipped.
- ``.npz``: 1-D arrays named like the columns, plus an optional ``meta`` array
  holding a JSON object. Other arrays are ignored. Read as a stream straight
  from the zip members (stored or deflated), never loading a whole array.
- ``.bin``: the raw byte stream of spec/wire-protocol.md, decoded by
  :class:`imudiag.drivers.wire.Decoder`; ``t`` is the device clock, outputs
  are integer ADC counts, the latest device-info frame is the metadata.

Every rule violation raises :class:`LogError` naming the file, the line (CSV)
and the reason: a missing or duplicate column, a non-numeric or non-finite
value, a non-increasing ``t`` (also across block boundaries), a ragged row, a
log with no samples. Readers stream in blocks of at most ``block_size``
samples, so the error may come after earlier blocks were yielded:
**consumers must not report on a log until iteration has completed**.
"""

from __future__ import annotations

import gzip
import io
import itertools
import json
import lzma
import os
import re
import shutil
import tempfile
import tokenize
import zipfile
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

import numpy as np

from ..samples import SampleBlock


class LogError(ValueError):
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
#: File name endings the readers and writers know, longest first.
FORMATS = (".csv.gz", ".csv", ".npz", ".bin")
DEFAULT_BLOCK_SIZE = 65536  #: samples per block

_META_KEY = re.compile(r"[A-Za-z_][A-Za-z0-9_.\-]*")
_INT_LIMITS = {"seq": (0, 2**63 - 1), "flags": (0, 0xFFFF)}
#: What zipfile and its decompressors raise on a damaged archive (found by fuzz/).
_ZIP_ERRORS = (zipfile.BadZipFile, zlib.error, EOFError, NotImplementedError, RuntimeError,
               ValueError, OSError, lzma.LZMAError)


def log_format(path: str | Path) -> str:
    """The format of ``path`` from its name: ``.csv``, ``.csv.gz``, ``.npz`` or ``.bin``."""
    name = str(path).lower()
    for ext in FORMATS:
        if name.endswith(ext):
            return ext
    raise LogError(str(path), "unknown log format (expected .csv, .csv.gz, .npz or .bin)")


def _parse_meta_value(value: str) -> Any:
    """A metadata value: JSON objects and arrays are parsed, everything else stays text."""
    if value[:1] in ("{", "["):
        try:
            return json.loads(value)
        except ValueError:
            pass
    return value


def _make_block(cols: dict[str, np.ndarray], meta: dict[str, Any]) -> SampleBlock:
    """A SampleBlock from validated float columns (seq, flags converted to integers)."""
    return SampleBlock(
        t=cols["t"],
        gyro=np.column_stack([cols["gx"], cols["gy"], cols["gz"]]),
        accel=np.column_stack([cols["ax"], cols["ay"], cols["az"]]),
        temp=cols.get("temp"),
        seq=None if "seq" not in cols else cols["seq"].astype(np.int64),
        flags=None if "flags" not in cols else cols["flags"].astype(np.uint16),
        meta=meta,
    )


#: Largest sensor output accepted in any unit (a 32-bit ADC gives 4.3e9 counts).
ABSURD = 1e10


def _first_violation(
    cols: dict[str, np.ndarray], last_t: float | None
) -> tuple[int, str] | None:
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
            reason = (f"column {name!r}: absurd value {float(v[first])!r} (beyond "
                      f"{ABSURD:g}, no sensor output comes near it)")
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


# ---------------------------------------------------------------------------
# readers


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

    def _open(self, opener: Any, *args: Any) -> Any:
        try:
            fh = opener(*args)
        except OSError as exc:
            raise LogError(self.path, f"cannot read: {exc.strerror or exc}") from None
        self._handles.append(fh)
        return fh

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


class CsvReader(LogReader):
    """Streaming reader of ``.csv`` and ``.csv.gz`` logs (parsing vectorised per block)."""

    def __init__(self, path: str | Path, block_size: int = DEFAULT_BLOCK_SIZE) -> None:
        super().__init__(path, block_size)
        self.gzip = self.path.lower().endswith(".gz")
        self.format = ".csv.gz" if self.gzip else ".csv"
        self.columns: list[str] = []  #: header column names in file order
        self._header_line = 0
        self._data_offset = 0
        fh = self._file()
        try:
            self._read_header(fh)
        finally:
            self._release(fh)

    def _file(self) -> IO[bytes]:
        if not self.gzip:
            return self._open(open, self.path, "rb")
        # a C-level buffered reader over the gzip stream: line iteration without
        # a Python call per line
        return self._open(lambda p: io.BufferedReader(gzip.GzipFile(p, "rb"), 1 << 18), self.path)

    def _read_header(self, fh: IO[bytes]) -> None:
        offset = 0
        for lineno, raw in enumerate(self._guard(iter(fh)), start=1):
            offset += len(raw)
            if lineno == 1:
                raw = raw.removeprefix(b"\xef\xbb\xbf")  # a UTF-8 byte-order mark
            try:
                line = raw.decode("utf-8").rstrip("\r\n")
            except UnicodeDecodeError:
                raise LogError(self.path, "not UTF-8 text", lineno) from None
            if line.startswith("#"):
                key, sep, value = line[1:].partition(":")
                key = key.strip()
                if sep and _META_KEY.fullmatch(key):
                    self.meta[key] = _parse_meta_value(value.strip())
                continue
            if not line.strip():
                continue
            self._header_line, self._data_offset = lineno, offset
            self._set_columns([c.strip() for c in line.split(",")])
            return
        raise LogError(self.path, "no header line (and no samples)")

    def _set_columns(self, names: list[str]) -> None:
        line = self._header_line
        seen: set[str] = set()
        for i, name in enumerate(names):
            if not name:
                raise LogError(self.path, f"empty column name (column {i + 1})", line)
            if name in seen:
                raise LogError(self.path, f"duplicate column {name!r}", line)
            seen.add(name)
        for name in REQUIRED_COLUMNS:
            if name not in seen:
                raise LogError(self.path, f"missing column {name!r}", line)
        self.columns = names
        self._used = [n for n in REQUIRED_COLUMNS + OPTIONAL_COLUMNS if n in seen]
        self._used_idx = np.array([names.index(n) for n in self._used])

    def _guard(self, it: Iterator[bytes]) -> Iterator[bytes]:
        """Lines of ``it``, turning a corrupt gzip stream into a LogError."""
        try:
            yield from it
        except (EOFError, gzip.BadGzipFile, zlib.error) as exc:
            raise LogError(self.path, f"corrupt gzip data: {exc}") from None

    def _blocks(self) -> Iterator[SampleBlock]:
        fh = self._file()
        try:
            fh.seek(self._data_offset)
            lineno = self._header_line + 1
            last_t: float | None = None
            while True:
                try:
                    chunk = list(itertools.islice(fh, self.block_size))
                except (EOFError, gzip.BadGzipFile, zlib.error) as exc:
                    raise LogError(self.path, f"corrupt gzip data: {exc}") from None
                if not chunk:
                    return
                cols = self._parse(chunk, lineno, last_t)
                lineno += len(chunk)
                if cols is not None:
                    last_t = float(cols["t"][-1])
                    yield _make_block(cols, self.meta)
        finally:
            self._release(fh)

    def _parse(
        self, lines: list[bytes], first_line: int, last_t: float | None
    ) -> dict[str, np.ndarray] | None:
        """Validated columns of a chunk of lines starting at file line ``first_line``."""
        text = b"".join(lines)
        if not text.endswith(b"\n"):
            text += b"\n"
        if b"\r" in text:  # after the final newline: a last line "\r" is empty (fuzz/)
            text = text.replace(b"\r\n", b"\n")
        buf = np.frombuffer(text, dtype=np.uint8)
        ends = np.flatnonzero(buf == 10)  # one per line
        starts = np.r_[0, ends[:-1] + 1]
        linenos: np.ndarray | None = None  # file line of each data row, if not consecutive
        # comment or empty lines (a line of only "\r"s is empty too: found by fuzz/)
        if np.any((buf[starts] == 35) | (buf[starts] == 10) | (buf[starts] == 13)):
            keep = [
                (first_line + i, ln.rstrip(b"\r\n") + b"\n")
                for i, ln in enumerate(lines)
                if not ln.startswith(b"#") and ln.rstrip(b"\r\n")
            ]
            if not keep:
                return None
            linenos = np.array([k[0] for k in keep])
            text = b"".join(k[1] for k in keep)
            buf = np.frombuffer(text, dtype=np.uint8)
            ends = np.flatnonzero(buf == 10)

        def line_of(row: int) -> int:
            return int(linenos[row]) if linenos is not None else first_line + row

        ncols = len(self.columns)
        commas_before_end = np.searchsorted(np.flatnonzero(buf == 44), ends)
        fields = np.diff(commas_before_end, prepend=0) + 1
        ragged = np.flatnonzero(fields != ncols)
        n = int(ragged[0]) if ragged.size else len(ends)
        cols = self._convert(text[: int(ends[n - 1]) + 1] if n else b"", n, line_of)
        bad = _first_violation(cols, last_t) if n else None
        if bad is not None:
            raise LogError(self.path, bad[1], line_of(bad[0]))
        if ragged.size:
            k = int(fields[n])
            raise LogError(self.path, f"ragged row: {k} fields, header has {ncols}", line_of(n))
        return cols

    def _convert(self, text: bytes, n: int, line_of: Any) -> dict[str, np.ndarray]:
        """Columns of ``n`` rows of the right width as floats; a non-numeric field raises."""
        ncols = len(self.columns)
        if n == 0:
            return {name: np.zeros(0) for name in self._used}
        values: np.ndarray | None = None
        flat = text.replace(b"\n", b",")
        try:
            if len(self._used) == ncols:
                # numpy's own strict text parser: an empty field, trailing junk or a
                # missing separator raises; the count check catches a trailing comma
                values = np.fromstring(flat, dtype=float, sep=",")
                values = values.reshape(n, ncols)[:, self._used_idx]
            elif b"_" not in text:  # numpy, like float(), would accept 1_000
                values = np.array(flat.split(b",")[:-1]).reshape(n, ncols)
                values = values[:, self._used_idx].astype(float)
        except ValueError:
            values = None
        if values is None:
            values = self._convert_rows(text, line_of)
        return {name: values[:, j] for j, name in enumerate(self._used)}

    def _convert_rows(self, text: bytes, line_of: Any) -> np.ndarray:
        """Row by row conversion, only after the vectorised path failed: finds the bad line."""
        rows = []
        for r, line in enumerate(text[:-1].split(b"\n")):
            fields = line.split(b",")
            for j, idx in enumerate(self._used_idx):
                f = fields[idx]
                try:
                    if b"_" in f:
                        raise ValueError(f)
                    np.array([f], dtype=float)
                except ValueError:
                    shown = f.decode(errors="replace")
                    reason = f"column {self._used[j]!r}: not a number: {shown!r}"
                    raise LogError(self.path, reason, line_of(r)) from None
            rows.append(np.array([fields[i] for i in self._used_idx], dtype=float))
        return np.array(rows)


class NpzReader(LogReader):
    """Streaming reader of ``.npz`` logs: reads each array's zip member in blocks."""

    format = ".npz"

    def __init__(self, path: str | Path, block_size: int = DEFAULT_BLOCK_SIZE) -> None:
        super().__init__(path, block_size)
        zf = self._zip()
        try:
            members = {n[:-4]: n for n in zf.namelist() if n.endswith(".npy")}
            for name in REQUIRED_COLUMNS:
                if name not in members:
                    raise LogError(self.path, f"missing array {name!r}")
            self._used = [n for n in REQUIRED_COLUMNS + OPTIONAL_COLUMNS if n in members]
            self._members = {n: members[n] for n in self._used}
            self.length = -1  #: samples in the log
            for name in self._used:
                with zf.open(self._members[name]) as fp:
                    shape, dtype = self._header(fp, name)
                if self.length < 0:
                    self.length = shape[0]
                elif shape[0] != self.length:
                    raise LogError(
                        self.path, f"array {name!r} has {shape[0]} values, 't' has {self.length}"
                    )
            if "meta" in members:
                self.meta = self._read_meta(zf, members["meta"])
        except LogError:
            raise
        except _ZIP_ERRORS as exc:
            raise LogError(self.path, f"corrupt zip data: {exc}") from None
        finally:
            self._release(zf)

    def _zip(self) -> zipfile.ZipFile:
        try:
            return self._open(zipfile.ZipFile, self.path)
        except LogError:
            raise
        except _ZIP_ERRORS as exc:
            raise LogError(self.path, f"not an NPZ (zip) file: {exc}") from None

    def _header(self, fp: IO[bytes], name: str) -> tuple[tuple[int, ...], np.dtype]:
        fmt = np.lib.format
        try:
            major, minor = fmt.read_magic(fp)
            reader = {1: fmt.read_array_header_1_0, 2: fmt.read_array_header_2_0}[major]
            shape, fortran, dtype = reader(fp)
        except (ValueError, KeyError, SyntaxError, tokenize.TokenError) as exc:  # fuzz/
            reason = f"array {name!r}: not a readable .npy header: {exc}"
            raise LogError(self.path, reason) from None
        if len(shape) != 1:
            raise LogError(self.path, f"array {name!r} must be 1-D, has shape {shape}")
        if dtype.kind not in "biuf":
            raise LogError(self.path, f"array {name!r} is not numeric (dtype {dtype})")
        return shape, dtype

    def _read_meta(self, zf: zipfile.ZipFile, member: str) -> dict[str, Any]:
        try:
            with zf.open(member) as fp:
                arr = np.lib.format.read_array(fp, allow_pickle=False)
            text = arr.item() if arr.size == 1 else None
            if isinstance(text, bytes):
                text = text.decode("utf-8")
            meta = json.loads(text) if isinstance(text, str) else None
        except (ValueError, UnicodeDecodeError):
            meta = None
        if not isinstance(meta, dict):
            raise LogError(self.path, "array 'meta' is not a JSON object")
        return meta

    def _blocks(self) -> Iterator[SampleBlock]:
        zf = self._zip()
        try:
            streams = {}
            dtypes = {}
            for name in self._used:
                streams[name] = zf.open(self._members[name])
                _, dtypes[name] = self._header(streams[name], name)
            last_t: float | None = None
            start = 0
            while start < self.length:
                n = min(self.block_size, self.length - start)
                cols = {}
                for name in self._used:
                    nbytes = n * dtypes[name].itemsize
                    data = streams[name].read(nbytes)
                    if len(data) != nbytes:
                        raise LogError(self.path, f"array {name!r} is truncated")
                    cols[name] = np.frombuffer(data, dtype=dtypes[name]).astype(float)
                bad = _first_violation(cols, last_t)
                if bad is not None:
                    raise LogError(self.path, f"sample {start + bad[0]}: {bad[1]}")
                last_t = float(cols["t"][-1])
                start += n
                yield _make_block(cols, self.meta)
        except LogError:
            raise
        except _ZIP_ERRORS as exc:
            raise LogError(self.path, f"corrupt zip data: {exc}") from None
        finally:
            self._release(zf)


class BinReader(LogReader):
    """Reader of raw wire captures (``.bin``) through the live frame decoder.

    ``t`` is the unwrapped device clock (s); ``counters`` are the decoder's
    receiver counters (CRC errors, lost frames...) of the bytes read so far;
    ``meta`` is the latest device-info frame seen when the log was opened.
    """

    format = ".bin"

    def __init__(self, path: str | Path, block_size: int = DEFAULT_BLOCK_SIZE) -> None:
        super().__init__(path, block_size)
        from ..drivers.wire import SAMPLE_FRAME_SIZE

        self._chunk = self.block_size * SAMPLE_FRAME_SIZE
        decoder = self._decoder()
        fh = self._open(open, self.path, "rb")
        try:
            decoder.feed(fh.read(self._chunk))
        finally:
            self._release(fh)
        self.meta = dict(decoder.device_info)
        self.counters = decoder.counters

    @staticmethod
    def _decoder() -> Any:
        from ..drivers.wire import Decoder

        return Decoder()

    def _blocks(self) -> Iterator[SampleBlock]:
        decoder = self._decoder()
        self.counters = decoder.counters
        fh = self._open(open, self.path, "rb")
        try:
            last_t: float | None = None
            done = 0
            while True:
                data = fh.read(self._chunk)
                block = decoder.feed(data) if data else decoder.finish()
                if decoder.device_info:
                    self.meta.update(decoder.device_info)
                if len(block):
                    bad = _first_violation({"t": block.t}, last_t)
                    if bad is not None:
                        seq = "" if block.seq is None else f" (frame seq {block.seq[bad[0]]})"
                        raise LogError(self.path, f"sample {done + bad[0]}{seq}: {bad[1]}")
                    last_t = float(block.t[-1])
                    done += len(block)
                    block.meta = self.meta
                    for start in range(0, len(block), self.block_size):
                        yield block.slice(start, start + self.block_size)
                if not data:
                    return
        finally:
            self._release(fh)


_READERS: dict[str, type[LogReader]] = {
    ".csv": CsvReader,
    ".csv.gz": CsvReader,
    ".npz": NpzReader,
    ".bin": BinReader,
}


def open_log(path: str | Path, block_size: int = DEFAULT_BLOCK_SIZE) -> LogReader:
    """Open a sample log for streaming (format from the file name).

    The header and metadata are read and checked now; the samples as the
    reader is iterated, in blocks of at most ``block_size`` samples. Raises
    :class:`LogError` for an unreadable file or a rule violation.
    """
    return _READERS[log_format(path)](path, block_size)


def read_log(path: str | Path) -> SampleBlock:
    """The whole log as one block (convenience for logs that fit in memory)."""
    with open_log(path) as reader:
        block = SampleBlock.concat(list(reader))
        block.meta = reader.meta
        return block


# ---------------------------------------------------------------------------
# writers


def _format_float(values: np.ndarray) -> list[str]:
    """Shortest text that reads back to the same float64, per value."""
    return list(map(repr, values.tolist()))


class LogWriter:
    """Writes blocks to a new log; the file appears under its name on :meth:`close`.

    Data goes to ``PATH.part`` first, so a log cut short by an error is never
    mistaken for a whole one (leaving the ``with`` block by an exception
    removes it). Every block must have the same optional columns as the first;
    values must be finite and ``t`` strictly increasing across blocks.
    """

    def __init__(self, path: str | Path, meta: dict[str, Any] | None = None) -> None:
        self.path = str(path)
        self.meta = dict(meta or {})
        self.samples_written = 0
        self._part = self.path + ".part"
        self._columns: list[str] | None = None
        self._last_t: float | None = None
        self._closed = False

    def write(self, block: SampleBlock) -> None:
        """Append the samples of ``block``."""
        if self._closed:
            raise ValueError(f"{self.path}: writer is closed")
        cols = {
            "t": block.t,
            "gx": block.gyro[:, 0], "gy": block.gyro[:, 1], "gz": block.gyro[:, 2],
            "ax": block.accel[:, 0], "ay": block.accel[:, 1], "az": block.accel[:, 2],
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
            raise LogError(
                self.path, f"block has columns {names}, the log has {self._columns}"
            )
        if not len(block):
            return
        bad = _first_violation({k: v.astype(float) for k, v in cols.items()}, self._last_t)
        if bad is not None:
            raise LogError(self.path, f"cannot write sample {self.samples_written + bad[0]}: "
                           f"{bad[1]}")
        self._write(cols, len(block))
        self._last_t = float(block.t[-1])
        self.samples_written += len(block)

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
        os.replace(self._part, self.path)

    def abort(self) -> None:
        """Stop writing and remove the partial file."""
        if self._closed:
            return
        self._closed = True
        try:
            self._finish()
        finally:
            Path(self._part).unlink(missing_ok=True)

    def __enter__(self) -> LogWriter:
        return self

    def __exit__(self, exc_type: object, *exc: object) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


class CsvWriter(LogWriter):
    """Writes ``.csv`` / ``.csv.gz``: shortest round-trip float text, ``# key: value`` meta."""

    def __init__(self, path: str | Path, meta: dict[str, Any] | None = None) -> None:
        super().__init__(path, meta)
        lines = []
        for key, value in self.meta.items():
            if not isinstance(key, str) or not _META_KEY.fullmatch(key):
                raise LogError(self.path, f"metadata key {key!r} cannot be written as '# key:'")
            text = value if isinstance(value, str) else json.dumps(value)
            if "\n" in text or "\r" in text:
                raise LogError(self.path, f"metadata {key!r}: value has a line break")
            lines.append(f"# {key}: {text}\n")
        try:
            raw = open(self._part, "wb")  # noqa: SIM115 - closed in _finish
        except OSError as exc:
            raise LogError(self.path, f"cannot write: {exc.strerror or exc}") from None
        if self.path.lower().endswith(".gz"):
            name = os.path.basename(self.path)[:-3]
            self._fh: IO[bytes] = gzip.GzipFile(name, "wb", 6, raw, mtime=0)
            self._raw: IO[bytes] | None = raw
        else:
            self._fh, self._raw = raw, None
        self._fh.write("".join(lines).encode("utf-8"))

    def _start(self, columns: list[str]) -> None:
        self._fh.write((",".join(columns) + "\n").encode())

    def _write(self, cols: dict[str, np.ndarray], n: int) -> None:
        ncols = len(cols)
        parts: list[str | None] = [None] * (2 * n * ncols)
        for j, (name, v) in enumerate(cols.items()):
            if name in ("seq", "flags"):
                text = list(map(str, v.astype(np.int64).tolist()))
            else:
                text = _format_float(v.astype(float))
            parts[2 * j :: 2 * ncols] = text
            parts[2 * j + 1 :: 2 * ncols] = ["\n" if j == ncols - 1 else ","] * n
        self._fh.write("".join(parts).encode())  # type: ignore[arg-type]

    def _finish(self) -> None:
        self._fh.close()
        if self._raw is not None:
            self._raw.close()


class NpzWriter(LogWriter):
    """Writes ``.npz`` (as ``numpy.savez``), streaming each column through a temporary file."""

    def __init__(self, path: str | Path, meta: dict[str, Any] | None = None) -> None:
        super().__init__(path, meta)
        try:
            self._meta_json = json.dumps(self.meta)
        except (TypeError, ValueError) as exc:
            raise LogError(self.path, f"metadata is not JSON serialisable: {exc}") from None
        self._tmp: dict[str, IO[bytes]] = {}
        self._dtypes: dict[str, np.dtype] = {}

    def _start(self, columns: list[str]) -> None:
        for name in columns:
            self._dtypes[name] = np.dtype(
                {"seq": np.int64, "flags": np.uint16}.get(name, np.float64)
            )
            self._tmp[name] = tempfile.TemporaryFile(dir=os.path.dirname(self._part) or ".")

    def _write(self, cols: dict[str, np.ndarray], n: int) -> None:
        for name, v in cols.items():
            self._tmp[name].write(np.ascontiguousarray(v, dtype=self._dtypes[name]).tobytes())

    def _finish(self) -> None:
        try:
            if not self._closed:
                self._assemble()
        finally:
            for fh in self._tmp.values():
                fh.close()

    def _assemble(self) -> None:
        try:
            zf = zipfile.ZipFile(self._part, "w", zipfile.ZIP_STORED, allowZip64=True)
        except OSError as exc:
            raise LogError(self.path, f"cannot write: {exc.strerror or exc}") from None
        with zf:
            for name, fh in self._tmp.items():
                with zf.open(name + ".npy", "w", force_zip64=True) as out:
                    header = {"descr": np.lib.format.dtype_to_descr(self._dtypes[name]),
                              "fortran_order": False, "shape": (self.samples_written,)}
                    np.lib.format.write_array_header_1_0(out, header)
                    fh.seek(0)
                    shutil.copyfileobj(fh, out, 1 << 20)
            with zf.open("meta.npy", "w") as out:
                np.lib.format.write_array(out, np.array(self._meta_json), allow_pickle=False)


class BinWriter(LogWriter):
    """Writes raw wire captures (``.bin``) with :func:`imudiag.drivers.wire.encode_samples`.

    Outputs are rounded to int32 counts, ``t`` (s) to whole microseconds of the
    device clock (wrapping as the spec says), temp to 0.01 degC. The metadata,
    if any, is written first as a device-info frame (its JSON must fit the
    frame: at most 249 bytes), with the seq just before the first sample's.
    ``seq`` is taken from the blocks when present (gaps kept; it reads back
    modulo 65536, unwrapped from the first frame), otherwise counted from 1.
    The decoder always yields temp and flags: 0 where the blocks had none.
    """

    def __init__(self, path: str | Path, meta: dict[str, Any] | None = None) -> None:
        super().__init__(path, meta)
        from ..drivers import wire

        self._wire = wire
        self._info: bytes | None = None
        if self.meta:
            text = json.dumps(self.meta, separators=(",", ":")).encode("utf-8")
            if len(text) > 249:
                raise LogError(
                    self.path,
                    f"metadata is {len(text)} bytes of JSON, a device-info frame holds 249",
                )
        try:
            self._fh = open(self._part, "wb")  # noqa: SIM115 - closed in _finish
        except OSError as exc:
            raise LogError(self.path, f"cannot write: {exc.strerror or exc}") from None
        self._seq = 1

    def _write(self, cols: dict[str, np.ndarray], n: int) -> None:
        if cols["t"][0] < 0:
            raise LogError(self.path, "t must be >= 0 s in a .bin capture (device clock)")
        time_us = np.rint(cols["t"] * 1e6).astype(np.int64)
        raw = np.rint(np.column_stack([cols[c] for c in REQUIRED_COLUMNS[1:]]))
        if np.any(np.abs(raw) > 2**31 - 1):
            raise LogError(self.path, "output outside the int32 range of a .bin capture")
        raw = raw.astype(np.int32)
        seq = cols["seq"].astype(np.int64) if "seq" in cols else self._seq + np.arange(n)
        if self.samples_written == 0 and self.meta:
            self._fh.write(
                self._wire.encode_info(int(seq[0] - 1) & 0xFFFF, int(time_us[0]), self.meta)
            )
        temp, flags = cols.get("temp"), cols.get("flags")
        cuts = np.flatnonzero(np.diff(seq) != 1) + 1
        for a, b in zip(np.r_[0, cuts], np.r_[cuts, n], strict=True):
            self._fh.write(
                self._wire.encode_samples(
                    int(seq[a]) & 0xFFFF, time_us[a:b], raw[a:b],
                    None if temp is None else temp[a:b],
                    None if flags is None else flags[a:b].astype(np.uint16),
                )
            )
        self._seq = int(seq[-1]) + 1

    def _finish(self) -> None:
        self._fh.close()


_WRITERS: dict[str, type[LogWriter]] = {
    ".csv": CsvWriter,
    ".csv.gz": CsvWriter,
    ".npz": NpzWriter,
    ".bin": BinWriter,
}


def open_writer(path: str | Path, meta: dict[str, Any] | None = None) -> LogWriter:
    """A writer for a new log at ``path`` (format from the name), with metadata ``meta``."""
    return _WRITERS[log_format(path)](path, meta)


def write_log(path: str | Path, block: SampleBlock, meta: dict[str, Any] | None = None) -> None:
    """Write one block as a whole log (convenience)."""
    with open_writer(path, block.meta if meta is None else meta) as writer:
        writer.write(block)


__all__ = [
    "LogError",
    "LogReader",
    "LogWriter",
    "REQUIRED_COLUMNS",
    "OPTIONAL_COLUMNS",
    "log_format",
    "open_log",
    "read_log",
    "open_writer",
    "write_log",
]

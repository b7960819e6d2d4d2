"""CSV logs (``.csv``, ``.csv.gz``) of spec/sample-log.md: streaming reader and writer.

``#`` comment lines; ``# key: value`` comments before the header are metadata.
The header names the columns in any order: required ``t`` (s, strictly
increasing) ``gx gy gz ax ay az`` (raw outputs in the certificate's output
units), optional ``temp`` (degC), ``seq``, ``flags``. Other columns are
ignored (only their number of fields per row is checked). Empty lines are skipped.
"""

from __future__ import annotations

import gzip
import io
import json
import os
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any, cast

import numpy as np

from .. import kernels
from ..samples import SampleBlock
from . import arrow_csv
from .base import (
    DEFAULT_BLOCK_SIZE,
    META_KEY,
    OPTIONAL_COLUMNS,
    REQUIRED_COLUMNS,
    LogError,
    LogReader,
    LogWriter,
    first_violation,
    format_float,
    make_block,
    parse_meta_value,
)

#: What a corrupt gzip stream raises: gzip's and zlib's, and ISA-L's (:func:`_isal_gzip`).
_GZIP_ERRORS: tuple[type[BaseException], ...] = (EOFError, gzip.BadGzipFile, zlib.error)
_ISAL: dict[str, Any] = {}


def _isal_gzip() -> Any | None:
    """ISA-L's gzip module (``isal.igzip``, the ``fleet`` extra), or None where it is not
    installed; its decompression errors join :data:`_GZIP_ERRORS` once imported."""
    global _GZIP_ERRORS
    if "igzip" not in _ISAL:
        try:
            from isal import igzip, isal_zlib

            _ISAL["igzip"] = igzip
            _GZIP_ERRORS = (*_GZIP_ERRORS, cast("type[BaseException]", isal_zlib.error))
        except ImportError:
            _ISAL["igzip"] = None
    return _ISAL["igzip"]


class CsvReader(LogReader):
    """Streaming reader of ``.csv`` and ``.csv.gz`` logs (parsing vectorised per block)."""

    time_unit_option = True  #: --time-unit reads its t column in ms, us, ns

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

    def _file(self, data: bool = False) -> IO[bytes]:
        if not self.gzip:
            return self._open(open, self.path, "rb")
        # a C-level buffered reader over the gzip stream: line iteration without
        # a Python call per line; the data (``data``: past the header, read in large
        # pieces), with the kernels on (a fleet task), inflated by ISA-L where the fleet
        # extra installed it (the same bytes, about 2.3x less CPU than zlib; its line
        # iteration, the header's, held far more memory than zlib's)
        fast = _isal_gzip() if data and kernels.enabled() else None
        opener = gzip.GzipFile if fast is None else fast.IGzipFile
        return self._open(lambda p: io.BufferedReader(opener(p, "rb"), 1 << 18), self.path)

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
                if sep and META_KEY.fullmatch(key):
                    self.meta[key] = parse_meta_value(value.strip())
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
        except _GZIP_ERRORS as exc:
            raise LogError(self.path, f"corrupt gzip data: {exc}") from None

    def _chunks(self, fh: IO[bytes]) -> Iterator[tuple[bytes, int]]:
        """The data's text in chunks of ``block_size`` lines, the file's lines as iterating
        it gives them (each ending at a newline, the last perhaps not), and each chunk's number
        of lines: read in large pieces and cut after the ``block_size``-th newline (no
        Python object per line)."""
        need = self.block_size
        pending = b""
        newlines = 0
        eof = False
        per_line = 128.0  # bytes a line, until the data tell
        while True:
            while not eof and newlines < need:
                want = max(1 << 16, int((need - newlines) * per_line * 1.1))
                try:
                    data = fh.read(want)
                except _GZIP_ERRORS as exc:
                    raise LogError(self.path, f"corrupt gzip data: {exc}") from None
                if not data:
                    eof = True
                    break
                pending += data
                newlines += data.count(b"\n")
                if newlines:
                    per_line = len(pending) / newlines
            if not pending:
                return
            if newlines >= need:
                ends = np.flatnonzero(np.frombuffer(pending, dtype=np.uint8) == 10)
                cut = int(ends[need - 1]) + 1
                chunk, pending = pending[:cut], pending[cut:]
                newlines -= need
                yield chunk, need
            else:  # the end of the file: what is left (its last line perhaps unterminated)
                chunk, pending = pending, b""
                yield chunk, newlines + (0 if chunk.endswith(b"\n") else 1)
                newlines = 0

    def _blocks(self) -> Iterator[SampleBlock]:
        fh = self._file(data=True)
        try:
            fh.seek(self._data_offset)
            lineno = self._header_line + 1
            last_t: float | None = None
            for chunk, lines in self._chunks(fh):
                cols = self._parse(chunk, lineno, last_t, lines)
                lineno += lines
                if cols is not None:
                    last_t = float(cols["t"][-1])
                    yield make_block(cols, self.meta)
        finally:
            self._release(fh)

    def _parse(
        self, chunk: bytes, first_line: int, last_t: float | None, lines: int
    ) -> dict[str, np.ndarray] | None:
        """Validated columns of a chunk of ``lines`` lines (their text, the last perhaps
        without its newline) starting at file line ``first_line``."""
        text = chunk
        if not text.endswith(b"\n"):
            text += b"\n"
        if b"\r" in text:  # after the final newline: a last line "\r" is empty (fuzz/)
            text = text.replace(b"\r\n", b"\n")
        if kernels.enabled():
            cols = self._parse_plain(text, first_line, last_t, lines)
            if cols is not None:
                return cols
        buf = np.frombuffer(text, dtype=np.uint8)
        ends = np.flatnonzero(buf == 10)  # one per line
        starts = np.r_[0, ends[:-1] + 1]
        linenos: np.ndarray | None = None  # file line of each data row, if not consecutive
        # comment or empty lines (a line of only "\r"s is empty too: found by fuzz/)
        if np.any((buf[starts] == 35) | (buf[starts] == 10) | (buf[starts] == 13)):
            parts = chunk.split(b"\n")  # the file's lines, each with its b"\n"
            file_lines = [ln + b"\n" for ln in parts[:-1]] + ([parts[-1]] if parts[-1] else [])
            keep = [
                (first_line + i, ln.rstrip(b"\r\n") + b"\n")
                for i, ln in enumerate(file_lines)
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
        commas = np.flatnonzero(buf == 44)
        k = ncols - 1
        if (
            commas.size == ends.size * k
            and k > 0
            and ends.size
            and bool(np.all(commas[k - 1 :: k] < ends))  # each line's last comma before its end
            and bool(np.all(commas[k::k] > ends[:-1]))  # and its first after the line before
        ):  # every line has ncols fields (the usual case: no search)
            ragged = np.zeros(0, dtype=np.intp)
            fields = np.full(ends.size, ncols)
        else:
            commas_before_end = np.searchsorted(commas, ends)
            fields = np.diff(commas_before_end, prepend=0) + 1
            ragged = np.flatnonzero(fields != ncols)
        n = int(ragged[0]) if ragged.size else len(ends)
        cols = self._convert(text[: int(ends[n - 1]) + 1] if n else b"", n, line_of)
        bad = first_violation(cols, last_t) if n else None
        if bad is not None:
            raise LogError(self.path, bad[1], line_of(bad[0]))
        if ragged.size:
            k = int(fields[n])
            raise LogError(self.path, f"ragged row: {k} fields, header has {ncols}", line_of(n))
        return cols

    def _parse_plain(
        self, text: bytes, first_line: int, last_t: float | None, lines: int
    ) -> dict[str, np.ndarray] | None:
        """:meth:`_parse` of a chunk whose every line is a data row (no "#", empty line or
        carriage return) read whole by pyarrow's parser (:mod:`.arrow_csv`, the compiled
        path): its parser checks each row's number of fields, so a chunk it reads has no
        ragged row and needs no search for newlines and commas. None where the chunk is not
        such or pyarrow is not sure: :meth:`_parse`'s own path then reads it (and decides
        what is refused). ``text`` ends in a newline, one for each of its ``lines``."""
        # (one byte searched for each: a comment line has its "#"; an empty line is a row
        # of one field, which the parser refuses)
        if b"#" in text or b"\r" in text:
            return None
        values = arrow_csv.floats(text, lines, len(self.columns), self._used_idx.tolist())
        if values is None:
            return None
        cols = {name: values[:, j] for j, name in enumerate(self._used)}
        bad = first_violation(cols, last_t)
        if bad is not None:
            raise LogError(self.path, bad[1], first_line + bad[0])
        return cols

    def _convert(self, text: bytes, n: int, line_of: Any) -> dict[str, np.ndarray]:
        """Columns of ``n`` rows of the right width as floats; a non-numeric field raises."""
        ncols = len(self.columns)
        if n == 0:
            return {name: np.zeros(0) for name in self._used}
        values: np.ndarray | None = None
        if kernels.enabled():  # pyarrow's parser, where it is sure (logs/arrow_csv.py)
            values = arrow_csv.floats(text, n, ncols, self._used_idx.tolist())
            if values is not None:
                return {name: values[:, j] for j, name in enumerate(self._used)}
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


class CsvWriter(LogWriter):
    """Writes ``.csv`` / ``.csv.gz``: shortest round-trip float text, ``# key: value`` meta."""

    def __init__(self, path: str | Path, meta: dict[str, Any] | None = None) -> None:
        super().__init__(path, meta)
        lines = []
        for key, value in self.meta.items():
            if not isinstance(key, str) or not META_KEY.fullmatch(key):
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
            self._fh: IO[bytes] | gzip.GzipFile = gzip.GzipFile(name, "wb", 6, raw, mtime=0)
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
                text = format_float(v.astype(float))
            parts[2 * j :: 2 * ncols] = text
            parts[2 * j + 1 :: 2 * ncols] = ["\n" if j == ncols - 1 else ","] * n
        self._fh.write("".join(parts).encode())  # type: ignore[arg-type]

    def _finish(self) -> None:
        self._fh.close()
        if self._raw is not None:
            self._raw.close()

"""Text tables users already have (``.txt``, ``.tsv``, ``.dat``, and ``.csv`` read with options).

Separator found from the first data line: semicolon (a decimal comma is then
read as a point), tab, comma, else whitespace. Lines starting with ``#``, ``%``
or ``//`` (Xsens MT Manager's exports) are comments (``# key: value`` ones are
metadata). A header is a
first line with a field that is not a number; its names are matched to the
columns (``t``/``time``/``timestamp``, ``gx``/``gyro_x``/``wx``...,
``ax``/``acc_x``/``Accelerometer X``..., ``temp``); a unit in brackets is taken as
the log's own where a triad's three columns state one (x-io's ``Gyroscope X (deg/s)``)
and for the time column (``Timestamp (us)``), unless ``--units`` or ``--time-unit``
say otherwise. Without a header,
``--columns`` names the columns in file order (``_`` skips one). Without a
``t`` column, ``--rate HZ`` gives the time: ``t = i / rate`` s.

``t`` is converted to seconds by ``--time-unit`` (s, ms, us, ns). The outputs
are left in the log's own units; ``--units`` (or ``# units:`` metadata) states
them in ``meta["units"]`` for the unit check against the certificate.
"""

from __future__ import annotations

import gzip
import itertools
import re
from collections.abc import Iterator
from pathlib import Path
from typing import IO

import numpy as np

from ..samples import SampleBlock
from ..units import canonical, units_of
from .base import (
    DEFAULT_BLOCK_SIZE,
    META_KEY,
    OPTIONAL_COLUMNS,
    REQUIRED_COLUMNS,
    LogError,
    LogReader,
    first_violation,
    make_block,
    parse_meta_value,
)
from .options import TIME_UNITS, LogOptions, missing_columns, units_from_meta

#: Header names (lower case, unit in brackets removed) and the column they mean.
ALIASES = {
    "t": "t",
    "time": "t",
    "timestamp": "t",
    "stamp": "t",
    "time_s": "t",
    "gx": "gx",
    "gy": "gy",
    "gz": "gz",
    "ax": "ax",
    "ay": "ay",
    "az": "az",
    "temp": "temp",
    "temperature": "temp",
    "seq": "seq",
    "flags": "flags",
}
for _axis in "xyz":
    for _p in ("gyro_", "gyr_", "w", "omega_", "gyro", "g_", "gyroscope_"):
        ALIASES[f"{_p}{_axis}"] = f"g{_axis}"
    for _p in ("acc_", "accel_", "a_", "acc", "accel", "accelerometer_"):
        ALIASES[f"{_p}{_axis}"] = f"a{_axis}"
_UNIT_SUFFIX = re.compile(r"\s*[\[(](.*)[\])]\s*$")
#: time units a header may state in brackets (``Timestamp (us)``), as --time-unit names them
_HEADER_TIME_UNITS = {"s": "s", "sec": "s", "ms": "ms", "us": "us", "\u00b5s": "us", "ns": "ns"}


#: What starts a comment line: ``#``, ``%`` (MATLAB, Octave) and ``//`` (Xsens MT Manager).
COMMENT_PREFIXES = ("#", "%", "//")


def _delimiter(line: str) -> str | None:
    for d in (";", "\t", ","):
        if d in line:
            return d
    return None  # whitespace


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


class TextTableReader(LogReader):
    """Streaming reader of delimited text tables, with column names, time unit and rate."""

    time_unit_option = True  #: --time-unit reads its t column in ms, us, ns

    format = "text"

    def __init__(
        self,
        path: str | Path,
        block_size: int = DEFAULT_BLOCK_SIZE,
        options: LogOptions | None = None,
    ) -> None:
        super().__init__(path, block_size)
        self.options = options or LogOptions()
        self.header_units: dict[str, str] = {}  #: units the header states in brackets
        self.header_time_unit: str | None = None  #: the time column's, from the header
        self._data_line = 0  # file line of the first data row
        self._delim: str | None = None
        fh = self._file()
        try:
            self._read_table_head(fh)
        finally:
            self._release(fh)
        time_unit = self.options.time_unit or self.header_time_unit or "s"
        self.time_scale = TIME_UNITS[time_unit]  #: s per unit of t
        units = dict(self.options.units) or units_from_meta(self.meta)
        if not units and len(self.header_units) == 2:  # both triads' units in the header
            units = dict(self.header_units)
            self.meta["units_from"] = "the header's brackets"
        if units:
            self.meta["units"] = units
        if self.header_time_unit and not self.options.time_unit:
            self.meta["time_unit_from"] = f"the header's brackets ({self.header_time_unit})"
        if self.options.rate is not None and "t" not in self._names:
            self.meta.setdefault("sample_rate", self.options.rate)

    def _lines(self, fh: IO[bytes]) -> Iterator[tuple[int, str]]:
        for lineno, raw in enumerate(fh, start=1):
            if lineno == 1:
                raw = raw.removeprefix(b"\xef\xbb\xbf")
            try:
                yield lineno, raw.decode("utf-8").rstrip("\r\n")
            except UnicodeDecodeError:
                raise LogError(self.path, "not UTF-8 text", lineno) from None

    def _read_table_head(self, fh: IO[bytes]) -> None:
        for lineno, line in self._lines(fh):
            stripped = line.strip()
            if not stripped:
                continue
            if stripped.startswith(COMMENT_PREFIXES):
                mark = next(m for m in COMMENT_PREFIXES if stripped.startswith(m))
                key, sep, value = stripped[len(mark) :].partition(":")
                if sep and META_KEY.fullmatch(key.strip()):
                    self.meta[key.strip()] = parse_meta_value(value.strip())
                continue
            self._delim = _delimiter(stripped)
            fields = self._split(stripped)
            judged = fields
            cols = self.options.columns
            if cols and len(cols) == len(fields):  # skipped columns may hold text
                judged = [f for f, name in zip(fields, cols, strict=True) if name != "_"]
            header = not all(_is_number(self._number_text(f)) for f in judged)
            self._nfields = len(fields)
            if header:
                self._data_line = lineno + 1
                names = self._from_header(fields, lineno)
            else:
                self._data_line = lineno
                names = self._from_options(lineno)
            self._set_names(names, lineno)
            return
        raise LogError(self.path, "no data lines (empty log)")

    def _split(self, line: str) -> list[str]:
        parts = line.split(self._delim) if self._delim else line.split()
        return [p.strip() for p in parts]

    def _number_text(self, text: str) -> str:
        return text.replace(",", ".") if self._delim == ";" else text

    def _from_header(self, fields: list[str], lineno: int) -> list[str]:
        if self.options.columns:
            if len(self.options.columns) != len(fields):
                raise LogError(
                    self.path,
                    f"--columns names {len(self.options.columns)} columns, "
                    f"the header has {len(fields)}",
                    lineno,
                )
            return list(self.options.columns)
        names = []
        stated: dict[str, str] = {}  # column name -> the unit its header states in brackets
        for f in fields:
            key = _UNIT_SUFFIX.sub("", f).strip().lower().replace(" ", "_")
            names.append(ALIASES.get(key, "_"))
            unit = _UNIT_SUFFIX.search(f)
            if unit and names[-1] != "_":
                stated[names[-1]] = unit.group(1).strip()
        self._header_units(stated)
        missing = missing_columns(names, self.options.gyro_only)
        if missing:
            raise LogError(
                self.path,
                f"header {fields} does not name {', '.join(missing)}; name the columns with "
                f"--columns (e.g. t,gx,gy,gz,ax,ay,az; _ skips one)",
                lineno,
            )
        return names

    def _header_units(self, stated: dict[str, str]) -> None:
        """The units a header states in brackets (x-io's ``Gyroscope X (deg/s)``,
        ``Timestamp (us)``): a triad's where its three columns state one unit imudiag knows,
        the time column's where it is s, ms, us or ns. Kept in ``header_units`` and
        ``header_time_unit``; --units and --time-unit, where given, are taken instead."""
        for triad, prefix in (("gyro", "g"), ("accel", "a")):
            said = {stated.get(prefix + axis) for axis in "xyz"}
            if len(said) == 1 and None not in said:
                unit = canonical(said.pop() or "")
                if unit in units_of(triad):
                    self.header_units[triad] = unit
        time_unit = _HEADER_TIME_UNITS.get(stated.get("t", "").lower())
        if time_unit is not None:
            self.header_time_unit = time_unit

    def _from_options(self, lineno: int) -> list[str]:
        if not self.options.columns:
            raise LogError(
                self.path,
                f"no header and {self._nfields} fields per row: name the columns with --columns "
                "(e.g. t,gx,gy,gz,ax,ay,az; _ skips one) and, without t, give --rate HZ",
                lineno,
            )
        if len(self.options.columns) != self._nfields:
            raise LogError(
                self.path,
                f"--columns names {len(self.options.columns)} columns, "
                f"the row has {self._nfields} fields",
                lineno,
            )
        return list(self.options.columns)

    def _set_names(self, names: list[str], lineno: int) -> None:
        used = [n for n in names if n != "_"]
        if len(set(used)) != len(used):
            raise LogError(self.path, f"a column is named twice: {names}", lineno)
        if "t" not in used and self.options.rate is None:
            raise LogError(self.path, "no time column: give the sample rate with --rate HZ", lineno)
        self._names = names
        self._used = [n for n in REQUIRED_COLUMNS + OPTIONAL_COLUMNS if n in used]
        self._idx = [names.index(n) for n in self._used]

    def _file(self) -> IO[bytes]:
        if self.path.lower().endswith(".gz"):
            return self._open(gzip.open, self.path, "rb")
        return self._open(open, self.path, "rb")

    def _blocks(self) -> Iterator[SampleBlock]:
        fh = self._file()
        try:
            rows = self._data_rows(fh)
            last_t: float | None = None
            index = 0
            while True:
                chunk = list(itertools.islice(rows, self.block_size))
                if not chunk:
                    return
                values = self._parse(chunk)
                cols = {n: values[:, j] for j, n in enumerate(self._used)}
                if "t" in cols:
                    cols["t"] = cols["t"] * self.time_scale
                else:
                    rate = float(self.options.rate)  # type: ignore[arg-type]
                    cols = {"t": (index + np.arange(len(chunk))) / rate, **cols}
                bad = first_violation(cols, last_t)
                if bad is not None:
                    raise LogError(self.path, bad[1], chunk[bad[0]][0])
                last_t = float(cols["t"][-1])
                index += len(chunk)
                yield make_block(cols, self.meta)
        finally:
            self._release(fh)

    def _data_rows(self, fh: IO[bytes]) -> Iterator[tuple[int, str]]:
        for lineno, line in self._lines(fh):
            if lineno < self._data_line:
                continue
            stripped = line.strip()
            if stripped and not stripped.startswith(COMMENT_PREFIXES):
                yield lineno, stripped

    def _parse(self, chunk: list[tuple[int, str]]) -> np.ndarray:
        out = np.empty((len(chunk), len(self._used)))
        for r, (lineno, line) in enumerate(chunk):
            fields = self._split(line)
            if len(fields) != self._nfields:
                raise LogError(
                    self.path,
                    f"ragged row: {len(fields)} fields, expected {self._nfields}",
                    lineno,
                )
            for j, i in enumerate(self._idx):
                text = self._number_text(fields[i])
                try:
                    if "_" in text:
                        raise ValueError(text)
                    out[r, j] = float(text)
                except ValueError:
                    raise LogError(
                        self.path, f"column {self._used[j]!r}: not a number: {fields[i]!r}", lineno
                    ) from None
        return out

"""The messages of an ArduPilot DataFlash log as columns, read at numpy speed.

A DataFlash log is self-describing: ``FMT`` messages (type 128, 89 bytes) give each message
type its name, length, field formats and column names; every message is ``A3 95 type``
and its fixed-length payload. :func:`scan_messages` walks the messages once (one step of a
Python loop per message: the lengths chain them) keeping the offsets of the types wanted,
then decodes each type's payloads in one numpy view. pymavlink's ``DFReader`` (the
reference, :func:`pymavlink_messages`) builds a Python object per message and reads each
field through ``__getattr__``: about 100 s of CPU per 10^6 IMU samples, against about 1 s
here (docs/benchmarks.md).

The scan reads a log whose messages follow one another, as ArduPilot writes them: a
message the file ends inside of, or bytes after the last message that hold no message
head (a block log's padding), end it. Anything else (bytes between messages, a head of a
type no ``FMT`` defines, a type defined twice differently, a format pymavlink could not
unpack) raises :class:`ScanError`, and the reader reads that log through pymavlink as
before: how pymavlink resynchronises on damage depends on which of its indexers runs,
and the scan does not guess it (nor which type pymavlink reads where two types share a
name). Values are pymavlink's: the format characters ``c C e E`` are divided by 100 and
``L`` by 10^7 as pymavlink divides them, every number is returned as a float64 (what the
readers do with it), strings are left out. ``tests/test_dataflash_scan.py`` holds
both to the same columns on the real log, on logs of every era written here, and on logs
with bytes of garbage.
"""

from __future__ import annotations

import contextlib
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .kept import LastParse

HEAD1, HEAD2 = 0xA3, 0x95  #: the two bytes that start every message
FMT_TYPE = 128  #: the type of ``FMT`` messages
FMT_LENGTH = 89  #: bytes of an ``FMT`` message: head, type, length, name, format, columns
_FMT_BODY = struct.Struct("<BB4s16s64s")

#: DataFlash format character -> (numpy type, count, pymavlink's multiplier or None)
FORMAT_CHARS: dict[str, tuple[str, int, float | None]] = {
    "a": ("<i2", 32, None),
    "b": ("i1", 1, None),
    "B": ("u1", 1, None),
    "g": ("<f2", 1, None),
    "h": ("<i2", 1, None),
    "H": ("<u2", 1, None),
    "i": ("<i4", 1, None),
    "I": ("<u4", 1, None),
    "f": ("<f4", 1, None),
    "n": ("S4", 1, None),
    "N": ("S16", 1, None),
    "Z": ("S64", 1, None),
    "c": ("<i2", 1, 0.01),
    "C": ("<u2", 1, 0.01),
    "e": ("<i4", 1, 0.01),
    "E": ("<u4", 1, 0.01),
    "L": ("<i4", 1, 1.0e-7),
    "d": ("<f8", 1, None),
    "M": ("i1", 1, None),
    "q": ("<i8", 1, None),
    "Q": ("<u8", 1, None),
}


class ScanError(ValueError):
    """A log the scan leaves to pymavlink (module docstring: damage, redefinitions,
    formats pymavlink could not unpack)."""


@dataclass
class Messages:
    """The messages of the wanted names: for each name its numeric columns as float64
    (file order; ``a`` fields as (M, 32)) and ``offsets`` (M,), where each message starts in
    the file (bytes): the order of messages of different names."""

    columns: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)
    offsets: dict[str, np.ndarray] = field(default_factory=dict)

    def count(self, name: str) -> int:
        """How many messages of ``name`` the log holds."""
        return int(self.offsets[name].shape[0]) if name in self.offsets else 0

    def rows(self, names: set[str] | list[str]) -> list[tuple[str, dict[str, Any]]]:
        """The messages of ``names`` one by one in file order: (name, {column: value});
        a number as a float, an ``a`` field as a float64 array."""
        keyed = []
        for name in names:
            cols = self.columns.get(name)
            if cols is None:
                continue
            for k, at in enumerate(self.offsets[name].tolist()):
                keyed.append(
                    (at, name, {c: v[k] if v.ndim > 1 else float(v[k]) for c, v in cols.items()})
                )
        keyed.sort(key=lambda r: r[0])
        return [(name, row) for _, name, row in keyed]


@dataclass
class _Format:
    name: str
    length: int
    format: str
    columns: list[str]
    offsets: list[int] = field(default_factory=list)
    dtype: np.dtype | None = None  #: the payload as a numpy record (:func:`_dtype`)


def _null_term(b: bytes) -> str:
    text = b.decode("utf-8", errors="backslashreplace")
    return text.split("\0", 1)[0]


def _dtype(fmt: _Format) -> np.dtype:
    """The payload of a message of ``fmt`` as a numpy record (fields named by position)."""
    fields = []
    for k, c in enumerate(fmt.format):
        try:
            typ, count, _mul = FORMAT_CHARS[c]
        except KeyError:
            raise ScanError(f"format character {c!r} of {fmt.name} not known") from None
        fields.append((f"f{k}", typ, (count,)) if count > 1 else (f"f{k}", typ))
    dt = np.dtype(fields)
    if dt.itemsize != fmt.length - 3:
        raise ScanError(
            f"{fmt.name}: format {fmt.format!r} takes {dt.itemsize} bytes, its length says "
            f"{fmt.length - 3}"
        )
    return dt


def _decode(data: np.ndarray, fmt: _Format) -> dict[str, np.ndarray]:
    """The numeric columns (float64, pymavlink's values) of the messages of ``fmt`` at its
    offsets in the bytes ``data``."""
    dt = fmt.dtype if fmt.dtype is not None else _dtype(fmt)
    at = np.asarray(fmt.offsets, dtype=np.int64)
    # each message's payload a row of a sliding view over the bytes: one copy of the rows
    body = np.lib.stride_tricks.sliding_window_view(data, fmt.length - 3)[at + 3]
    rec = np.ascontiguousarray(body).view(dt).reshape(at.shape[0])
    out: dict[str, np.ndarray] = {}
    for k, c in enumerate(fmt.format):
        if k >= len(fmt.columns) or c in "nNZ":
            continue
        v = rec[f"f{k}"].astype(np.float64)
        mul = FORMAT_CHARS[c][2]
        if mul is not None:
            # pymavlink divides by 1/mul ("more accurate than multiplying by 1e-2 or 1e-7")
            v = v / (1 / mul)
        out[fmt.columns[k]] = v
    return out


#: the last scan kept (:mod:`.kept`): a log is read again for each of its IMU instances and
#: by each pass of a diagnosis (the noise figures, then the windows)
_LAST: LastParse[Messages] = LastParse(
    lambda m: (v for cols in m.columns.values() for v in cols.values())
)


def scan_messages(path: str | Path, names: set[str] | list[str]) -> Messages:
    """The messages named ``names`` of the DataFlash log at ``path`` (module docstring).
    Raises :class:`ScanError` for what it does not read as pymavlink would. The last scan
    (up to :data:`~imudiag.logs.kept.KEEP_BYTES`) is kept and given again while the file's
    size and modification time are unchanged."""
    return _LAST.get(path, frozenset(names), lambda: _scan(path, names))


def forget() -> None:
    """Drop the scan kept by :func:`scan_messages` (its memory; a benchmark's cold read)."""
    _LAST.forget()


def _scan(path: str | Path, names: set[str] | list[str]) -> Messages:
    wanted = set(names)
    raw = Path(path).read_bytes()
    n = len(raw)
    lengths = [0] * 256  #: by type: the message length, 0 for a type not defined
    keep: list[list[int] | None] = [None] * 256  #: by type: offsets of a wanted one
    defined: dict[int, tuple[Any, ...]] = {}  #: by type: its FMT fields
    lengths[FMT_TYPE] = FMT_LENGTH
    formats: list[_Format] = []  #: the definitions of the wanted types
    p = 0
    while p + 3 < n:  # pymavlink's indexer: a head and a type, then the rest
        if raw[p] == HEAD1 and raw[p + 1] == HEAD2:
            t = raw[p + 2]
            length = lengths[t]
            if not length:
                raise ScanError(f"a message of type {t} at byte {p}, which no FMT defines")
            if n - p < length:
                break  # the log ends inside its last message
            if t == FMT_TYPE:
                body = _FMT_BODY.unpack_from(raw, p + 3)
                ftype, flen, name, fmt, cols = body
                fm = _Format(_null_term(name), flen, _null_term(fmt), _null_term(cols).split(","))
                if fm.columns == [""]:
                    fm.columns = []
                fm.dtype = _dtype(fm)  # pymavlink could not unpack it: ScanError
                if ftype in defined and defined[ftype] != body:
                    raise ScanError(f"type {ftype} redefined by the FMT at byte {p}")
                if ftype == FMT_TYPE and (flen, fm.format) != (FMT_LENGTH, "BBnNZ"):
                    raise ScanError(f"the FMT at byte {p} gives FMT another layout")
                if ftype not in defined:
                    defined[ftype] = body
                    lengths[ftype] = flen
                    if fm.name in wanted:
                        if any(f.name == fm.name for f in formats):
                            raise ScanError(f"two message types named {fm.name}")
                        formats.append(fm)
                        keep[ftype] = fm.offsets
            else:
                offsets = keep[t]
                if offsets is not None:
                    offsets.append(p)
            p += length
            continue
        if raw.find(bytes((HEAD1, HEAD2)), p) == -1:
            break  # bytes after the last message (a block log's padding): the end
        raise ScanError(f"bytes at byte {p} that do not start a message, then more messages")
    # one definition per wanted name (else ScanError above), its offsets in walk order
    data = np.frombuffer(raw, dtype=np.uint8)
    out = Messages()
    for fm in formats:
        if fm.offsets:
            out.offsets[fm.name] = np.asarray(fm.offsets, dtype=np.int64)
            out.columns[fm.name] = _decode(data, fm)
    return out


def pymavlink_messages(path: str | Path, names: set[str] | list[str]) -> Messages:
    """:func:`scan_messages` by pymavlink's ``DFReader`` (the reference; needs pymavlink):
    each message's fields as pymavlink returns them, as float64."""
    from pymavlink import DFReader

    wanted = set(names)
    rows: dict[str, list[tuple[int, dict[str, Any]]]] = {}
    log = DFReader.DFReader_binary(str(path), zero_time_base=True)
    try:
        while (m := log.recv_match(type=list(wanted))) is not None:
            fmt = m.fmt
            values: dict[str, Any] = {}
            for k, c in enumerate(fmt.format[: len(fmt.columns)]):
                if c in "nNZ":
                    continue
                v = getattr(m, fmt.columns[k])
                values[fmt.columns[k]] = np.asarray(v, dtype=np.float64) if c == "a" else float(v)
            rows.setdefault(m.get_type(), []).append((log.offset - fmt.len, values))
    finally:
        # a map still exported (a message's view) is left to the garbage collector, the
        # file is closed all the same
        with contextlib.suppress(BufferError, AttributeError, ValueError):
            log.data_map.close()
        with contextlib.suppress(AttributeError, OSError):
            log.filehandle.close()
    out = Messages()  # pymavlink reads in file order
    for name, got in rows.items():
        out.offsets[name] = np.array([r[0] for r in got], dtype=np.int64)
        out.columns[name] = {c: np.array([r[1][c] for r in got]) for c in got[0][1]}
    return out


__all__ = [
    "FORMAT_CHARS",
    "Messages",
    "ScanError",
    "forget",
    "pymavlink_messages",
    "scan_messages",
]

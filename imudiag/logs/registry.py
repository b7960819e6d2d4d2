"""The registry of log formats: one entry per format, chosen by file name and magic bytes.

A format is found from the end of the file name (the longest registered
ending wins, so ``.csv.gz`` before ``.csv``). Where two formats share an
ending (a raw wire capture and an ArduPilot DataFlash log are both ``.bin``),
the first bytes of an existing file decide: the entry whose ``magic`` test
accepts them, else the entry registered without one. Plug-ins add formats
with :func:`register_format` (as python-can's interface registry does).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .base import LogError, LogReader, LogWriter

#: Bytes read from the head of a file for the magic tests.
MAGIC_BYTES = 64


@dataclass(frozen=True)
class LogFormat:
    """One log format: its name, file endings, reader, writer and magic test."""

    name: str  #: the format's name, e.g. ``.csv`` or ``dataflash``
    extensions: tuple[str, ...]  #: lower-case file name endings, e.g. ``(".csv",)``
    reader: Callable[..., LogReader] | None  #: ``reader(path, block_size, **options)``
    writer: Callable[..., LogWriter] | None = None  #: ``writer(path, meta)``
    magic: Callable[[bytes], bool] | None = None  #: accepts the file's first bytes
    description: str = ""
    takes_options: bool = False  #: the reader takes ``options=LogOptions``
    extra: str = ""  #: the pip extra holding the reader's dependencies, if any
    #: accepts a directory that is a log of this format (a ROS 2 bag directory)
    directory: Callable[[Path], bool] | None = None
    #: the log option that chooses the samples within a file of this format (``variable``,
    #: ``topic`` or ``instance``); the others are refused for it
    chooser: str = ""
    #: typical bytes a written sample takes (the writer's output), for free-space checks
    bytes_per_sample: float = 0.0

    @property
    def may_carry_gnss(self) -> bool:
        """Whether a log of this format can hold GNSS fixes of its own: False only where its
        reader is a :class:`LogReader` class that keeps the base's :meth:`LogReader.gnss`
        (none), so a caller asking for a log's own GNSS need not open it (a plug-in's
        reader made by a function is asked)."""
        reader = self.reader
        if isinstance(reader, type) and issubclass(reader, LogReader):
            return reader.gnss is not LogReader.gnss
        return True

    def open_reader(self, path: str | Path, block_size: int, options: Any = None) -> LogReader:
        """A reader of ``path``; raises LogError when the format cannot be read."""
        if self.reader is None:
            raise LogError(str(path), f"{self.name} logs cannot be read")
        if self.takes_options:
            return self.reader(path, block_size, options=options)
        return self.reader(path, block_size)

    def open_writer(self, path: str | Path, meta: dict[str, Any] | None) -> LogWriter:
        """A writer of a new ``path``; raises LogError when the format cannot be written."""
        if self.writer is None:
            writable = ", ".join(
                sorted({e for f in _FORMATS for e in f.extensions if f.writer is not None})
            )
            raise LogError(
                str(path), f"unknown log format for writing: {self.name} (writable: {writable})"
            )
        return self.writer(path, meta)


_FORMATS: list[LogFormat] = []


def register_format(fmt: LogFormat) -> None:
    """Add a format (a later registration with the same name replaces the earlier one)."""
    _FORMATS[:] = [f for f in _FORMATS if f.name != fmt.name]
    _FORMATS.append(fmt)


#: Entry-point group of plug-in formats: each entry point loads a :class:`LogFormat`.
ENTRY_POINT_GROUP = "imudiag.log_formats"
_plugins_loaded = False


def _load_plugins() -> None:
    """Register the formats of installed plug-ins (once; a broken plug-in raises)."""
    global _plugins_loaded
    if _plugins_loaded:
        return
    _plugins_loaded = True
    from importlib.metadata import entry_points

    for ep in entry_points(group=ENTRY_POINT_GROUP):
        fmt = ep.load()
        if not isinstance(fmt, LogFormat):
            raise TypeError(f"entry point {ep.name!r} of {ENTRY_POINT_GROUP}: not a LogFormat")
        if all(f.name != fmt.name for f in _FORMATS):
            _FORMATS.append(fmt)


def formats() -> list[LogFormat]:
    """The registered formats (built-in, then plug-ins), in registration order."""
    _load_plugins()
    return list(_FORMATS)


def _ending(path: str | Path) -> str | None:
    name = str(path).lower()
    endings = sorted({e for f in _FORMATS for e in f.extensions}, key=len, reverse=True)
    return next((e for e in endings if name.endswith(e)), None)


def _head(path: str | Path) -> bytes | None:
    try:
        with open(path, "rb") as fh:
            return fh.read(MAGIC_BYTES)
    except OSError:
        return None


def lookup(path: str | Path) -> LogFormat:
    """The format of ``path`` from its name and, where names collide, its first bytes."""
    _load_plugins()
    if Path(path).is_dir():
        for f in _FORMATS:
            if f.directory is not None and f.directory(Path(path)):
                return f
        raise LogError(
            str(path), "a directory, not a log (a ROS 2 bag directory holds a metadata.yaml)"
        )
    ending = _ending(path)
    if ending is None:
        known = ", ".join(sorted({e for f in _FORMATS for e in f.extensions}))
        raise LogError(str(path), f"unknown log format (expected one of {known})")
    candidates = [f for f in _FORMATS if ending in f.extensions]
    if len(candidates) > 1:
        head = _head(path)
        if head:
            for f in candidates:
                if f.magic is not None and f.magic(head):
                    return f
        plain = [f for f in candidates if f.magic is None]
        if plain:
            return plain[0]
    return candidates[0]


def log_format(path: str | Path) -> str:
    """The name of the format of ``path`` (``.csv``, ``.csv.gz``, ``.npz``, ``.bin``, ...)."""
    return lookup(path).name


#: Back-compatible tuple of the built-in endings (longest first).
FORMATS = (".csv.gz", ".csv", ".npz", ".bin")

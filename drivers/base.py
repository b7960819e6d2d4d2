"""The source interface every transport implements, and the URL registry."""

from __future__ import annotations

import importlib
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar
from urllib.parse import parse_qs, urlsplit

from imudiag.errors import SourceError
from imudiag.samples import SampleBlock


class EndOfStream(Exception):
    """A finite source (a replayed log, a finite scenario) has delivered everything."""


@dataclass
class Counters:
    """Receiver counters of spec/wire-protocol.md, cumulative since the source was made."""

    bytes: int = 0  #: bytes read from the transport
    frames: int = 0  #: good sample frames delivered
    crc_errors: int = 0  #: frames dropped for a bad CRC
    skipped_bytes: int = 0  #: bytes skipped while resynchronising
    lost: int = 0  #: frames missing by seq
    duplicates: int = 0  #: repeated seq, dropped

    def as_dict(self) -> dict[str, int]:
        """The counters as the status JSON ``counters`` object."""
        # built by hand: dataclasses.asdict deep-copies recursively and was a tenth of
        # the daemon's per-turn cost (benchmarks/latency.py profile)
        return {"bytes": self.bytes, "frames": self.frames, "crc_errors": self.crc_errors,
                "skipped_bytes": self.skipped_bytes, "lost": self.lost,
                "duplicates": self.duplicates}


@dataclass(frozen=True)
class SourceURL:
    """A parsed source URL: ``scheme://target?key=value``."""

    url: str
    scheme: str
    target: str  #: device path, VID:PID, file path or scenario name
    params: dict[str, str]

    def get(self, key: str, default: Any = None, cast: Callable[[str], Any] = str) -> Any:
        """Query parameter ``key`` converted with ``cast``; a bad value names the key."""
        if key not in self.params:
            return default
        try:
            return cast(self.params[key])
        except ValueError:
            raise SourceError(f"{self.url}: bad value for {key!r}: {self.params[key]!r}") from None


def parse_url(url: str) -> SourceURL:
    """Split a source URL; ``serial:///dev/x`` gives target ``/dev/x``."""
    parts = urlsplit(url)
    if not parts.scheme:
        raise SourceError(f"{url}: not a source URL (expected scheme://...)")
    target = parts.netloc + parts.path
    params = {k: v[-1] for k, v in parse_qs(parts.query, keep_blank_values=True).items()}
    return SourceURL(url=url, scheme=parts.scheme.lower(), target=target, params=params)


class Source(ABC):
    """One IMU input. Byte transports decode the wire protocol internally.

    Use as a context manager or call :meth:`open` / :meth:`close`. :meth:`read`
    returns the samples that arrived (possibly none) within ``timeout_s``
    seconds, raises :class:`EndOfStream` when a finite source is exhausted and
    :class:`SourceError` when the device has gone away.
    """

    scheme: ClassVar[str] = ""
    #: query keys the scheme understands; :func:`open_source` refuses any other (a misspelt
    #: ``?sped=0`` must not be ignored). None: the transport checks its own keys.
    url_keys: ClassVar[tuple[str, ...] | None] = None

    def __init__(self, url: SourceURL, **options: Any) -> None:
        self.url = url
        self.options = options
        self.counters = Counters()
        self.device_info: dict[str, Any] = {}

    @abstractmethod
    def open(self) -> None:
        """Open the device or file; raises SourceError if it cannot."""

    @abstractmethod
    def read(self, timeout_s: float = 0.1) -> SampleBlock:
        """Samples received within ``timeout_s`` seconds (an empty block if none)."""

    @abstractmethod
    def close(self) -> None:
        """Release the device or file; safe to call twice."""

    def write_command(self, line: str) -> None:  # noqa: B027 - optional for transports
        """Send an ASCII command (START, STOP, RATE <hz>, INFO); ignored where unsupported."""

    def __enter__(self) -> Source:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


_REGISTRY: dict[str, type[Source]] = {}
#: Modules that register the built-in schemes, imported on first use so that
#: optional dependencies (pyusb, hidapi) are only needed by their transport.
_BUILTIN_MODULES: dict[str, str] = {
    "serial": "imudiag.drivers.serial_port",
    "loop": "imudiag.drivers.serial_port",
    "socket": "imudiag.drivers.serial_port",
    "hid": "imudiag.drivers.hid",
    "usb": "imudiag.drivers.usb",
    "replay": "imudiag.drivers.replay",
    "sim": "imudiag.drivers.sim",
}


def register(scheme: str) -> Callable[[type[Source]], type[Source]]:
    """Class decorator adding a transport for ``scheme://`` URLs."""

    def deco(cls: type[Source]) -> type[Source]:
        cls.scheme = scheme
        _REGISTRY[scheme] = cls
        return cls

    return deco


def registered_schemes() -> list[str]:
    """Every scheme ``open_source`` accepts."""
    return sorted(set(_REGISTRY) | set(_BUILTIN_MODULES))


def source_class(scheme: str) -> type[Source]:
    """The transport class for ``scheme``, importing its module on first use."""
    if scheme not in _REGISTRY and scheme in _BUILTIN_MODULES:
        importlib.import_module(_BUILTIN_MODULES[scheme])
    try:
        return _REGISTRY[scheme]
    except KeyError:
        raise SourceError(
            f"unknown source scheme {scheme!r}; known: {', '.join(registered_schemes())}"
        ) from None


def open_source(url: str, **options: Any) -> Source:
    """Make (not yet open) the source for ``url``; options go to the transport.

    Common options: ``certificate`` (a Certificate, for ``sim://``).
    """
    parsed = parse_url(url)
    cls = source_class(parsed.scheme)
    if cls.url_keys is not None:
        unknown = sorted(set(parsed.params) - set(cls.url_keys))
        if unknown:
            known = ", ".join(cls.url_keys) or "none"
            raise SourceError(
                f"{url}: unknown query key {unknown[0]!r} for {parsed.scheme}:// (known: {known})"
            )
    return cls(parsed, **options)

"""The source interface every transport implements, and the URL registry."""

from __future__ import annotations

import importlib
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass
from importlib.metadata import EntryPoint, entry_points
from typing import Any, ClassVar
from urllib.parse import parse_qs, urlsplit

from imudiag.errors import SourceError
from imudiag.samples import SampleBlock

from .wire import Counters


class EndOfStream(Exception):
    """A finite source (a replayed log, a finite scenario) has delivered everything."""


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
    "isensor": "imudiag.drivers.isensor",
    "witmotion": "imudiag.drivers.witmotion",
    "iio": "imudiag.drivers.iio",
}
#: Entry-point group of the sources that live above the driver layer (``sim://`` and
#: ``replay://`` in :mod:`imudiag.sources`, and any plug-in package's): name = scheme,
#: value = ``module:SourceClass``. The driver layer never imports them by name.
ENTRY_POINT_GROUP = "imudiag.sources"
_entry_points_cache: dict[str, EntryPoint] | None = None


def _entry_points() -> dict[str, EntryPoint]:
    global _entry_points_cache
    if _entry_points_cache is None:
        _entry_points_cache = {ep.name: ep for ep in entry_points(group=ENTRY_POINT_GROUP)}
    return _entry_points_cache


def _load_entry_point(scheme: str, ep: EntryPoint) -> None:
    """Import the source an entry point names and register it for ``scheme``."""
    try:
        cls = ep.load()
    except Exception as exc:  # a broken plug-in must say so, not vanish
        raise SourceError(
            f"{scheme}://: the source {ep.value!r} (entry point {ENTRY_POINT_GROUP}) "
            f"cannot be loaded: {type(exc).__name__}: {exc}"
        ) from exc
    if not (isinstance(cls, type) and issubclass(cls, Source)):
        raise SourceError(
            f"{scheme}://: the entry point {ep.value!r} ({ENTRY_POINT_GROUP}) is not a Source class"
        )
    if scheme not in _REGISTRY:
        register(scheme)(cls)


def register(scheme: str) -> Callable[[type[Source]], type[Source]]:
    """Class decorator adding a transport for ``scheme://`` URLs."""

    def deco(cls: type[Source]) -> type[Source]:
        cls.scheme = scheme
        _REGISTRY[scheme] = cls
        return cls

    return deco


def registered_schemes() -> list[str]:
    """Every scheme ``open_source`` accepts."""
    return sorted(set(_REGISTRY) | set(_BUILTIN_MODULES) | set(_entry_points()))


def source_class(scheme: str) -> type[Source]:
    """The transport class for ``scheme``, importing its module on first use (a driver
    module of this package, else the ``imudiag.sources`` entry point of that name)."""
    if scheme not in _REGISTRY:
        if scheme in _BUILTIN_MODULES:
            importlib.import_module(_BUILTIN_MODULES[scheme])
        elif scheme in _entry_points():
            _load_entry_point(scheme, _entry_points()[scheme])
    try:
        return _REGISTRY[scheme]
    except KeyError:
        hint = ""
        if scheme in ("sim", "replay"):
            hint = (
                " (imudiag's own sim:// and replay:// are found through its entry points: "
                "install the package, e.g. pip install -e .)"
            )
        raise SourceError(
            f"unknown source scheme {scheme!r}; known: {', '.join(registered_schemes())}{hint}"
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

"""Daemon configuration: a YAML file (``config/imudiag.yaml`` holds the defaults).

``load_config(path)`` reads a site file over the defaults: keys it omits keep
the bundled values. ``merge_cli(config, args)`` lets command-line options win.
Every rule is checked at start; an unknown key, a wrong type, an out-of-range
value or a duplicate key raises :class:`ConfigError` naming the file, the key
path (``status.rate_hz``) and the reason. docs/service.md describes each key.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

from imudiag import validate, yamlio
from imudiag.certificate import AUTO
from imudiag.errors import BadInput

BUNDLED_CONFIG_NAME = "imudiag.yaml"
LOG_LEVELS = ("debug", "info", "warning", "error", "critical")


class ConfigError(BadInput):
    """A configuration breaking a rule: ``source`` (file or "command line"), ``key``, ``reason``."""

    def __init__(self, source: str, key: str, reason: str) -> None:
        self.source = source
        self.key = key
        self.reason = reason
        super().__init__(f"{source}: {key}: {reason}")


@dataclass(frozen=True)
class DaemonConfig:
    """Settings of ``imudiag run``; the defaults equal ``config/imudiag.yaml``."""

    source: str = "sim://multiposition?loop=1"  #: sample source URL (drivers registry)
    #: pause after a read that brought samples, s: CPU share against verdict latency
    read_interval_s: float = 0.005
    #: certificate file; None = the bundled one; "auto" = the bundled data-sheet certificate
    #: the source's identity names (docs/devices.md)
    certificate: str | None = None
    status_stdout: bool = True  #: JSON status lines on standard output
    status_serial: str | None = None  #: NMEA status link URL; None = none
    status_rate_hz: float = 1.0  #: JSON status lines per second, Hz
    nmea_rate_hz: float = 1.0  #: NMEA status cycles per second, Hz
    nmea_queue: int = 64  #: sentences buffered for the serial writer
    nmea_write_timeout_s: float = 0.5  #: write timeout of one sentence, s
    f0_persistence_k: int = 20  #: F0 fails when k of the last n checked samples fail ...
    f0_persistence_n: int = 50  #: ... of n samples
    stuck_samples: int = 50  #: identical consecutive raw outputs meaning "stuck", samples
    no_data_timeout_s: float = 1.0  #: no valid frame for this long -> state no_data, s
    reconnect_min_s: float = 0.2  #: first reconnect back-off, s
    reconnect_max_s: float = 4.0  #: longest reconnect back-off, s (< WatchdogSec / 2)
    diagnosis_window_intervals: int = 24  #: quasi-static intervals per fit window
    diagnosis_window_max_s: float = 900.0  #: intervals older than this leave the window, s
    diagnosis_persist_windows: int = 2  #: consecutive windows before a fault is reported
    static_window_s: float = 0.5  #: quasi-static detector window, s
    log_level: str = "info"  #: debug | info | warning | error | critical
    aiding: str | None = None  #: GNSS aiding gpsd://HOST:PORT; None = none
    origin: str | None = dataclasses.field(default=None, compare=False)  #: file read from

    def __post_init__(self) -> None:
        """Each value checked as the file's (:data:`SCHEMA`): BadInput naming its YAML key
        (``status.rate_hz: ...``), so a configuration built in code is held to the file's
        rules. The rules linking keys are :func:`from_dict`'s and :func:`merge_cli`'s."""
        for name, check in _FIELD_CHECK.items():
            value = getattr(self, name)
            check(value, validate.failing(_FIELD_KEY[name]))

    def replace(self, **changes: Any) -> DaemonConfig:
        """A copy with ``changes`` applied, each value checked (:meth:`__post_init__`)."""
        return dataclasses.replace(self, **changes)


# ---------------------------------------------------------------------------
# value checks: each takes (value, fail) and returns the normalised value


Check = Callable[[Any, Callable[[str], Exception]], Any]


def _number(lo: float, hi: float, lo_open: bool = True) -> Check:
    def check(value: Any, fail: Callable[[str], Exception]) -> float:
        return validate.number(value, fail, lo, hi, lo_open=lo_open)

    return check


def _integer(lo: int, hi: int) -> Check:
    def check(value: Any, fail: Callable[[str], Exception]) -> int:
        return validate.integer(value, fail, lo, hi)

    return check


_boolean: Check = validate.boolean
_text: Check = validate.text


def _optional(check: Check) -> Check:
    def inner(value: Any, fail: Callable[[str], Exception]) -> Any:
        return None if value is None else check(value, fail)

    return inner


def _source_url(value: Any, fail: Callable[[str], Exception]) -> str:
    from imudiag.drivers.base import SourceError, parse_url, registered_schemes

    value = _text(value, fail)
    try:
        url = parse_url(value)
    except SourceError:
        raise fail(f"not a source URL (expected scheme://...): {value!r}") from None
    schemes = registered_schemes()
    if url.scheme not in schemes:
        raise fail(f"unknown source scheme {url.scheme!r}; known: {', '.join(schemes)}")
    return value


def _log_level(value: Any, fail: Callable[[str], Exception]) -> str:
    value = _text(value, fail).lower()
    if value not in LOG_LEVELS:
        raise fail(f"expected one of {', '.join(LOG_LEVELS)}, got {value!r}")
    return value


def _aiding_url(value: Any, fail: Callable[[str], Exception]) -> str:
    from imudiag.aiding.gpsd_client import parse_gpsd_url
    from imudiag.errors import BadInput

    value = _text(value, fail)
    try:
        parse_gpsd_url(value)
    except BadInput as exc:
        raise fail(str(exc).removeprefix("aiding: ")) from None
    return value


#: YAML key path -> (DaemonConfig field, check). The order is the file's.
SCHEMA: dict[tuple[str, ...], tuple[str, Check]] = {
    ("source",): ("source", _source_url),
    ("read_interval_s",): ("read_interval_s", _number(0.0, 0.1, lo_open=False)),
    ("certificate",): ("certificate", _optional(_text)),
    ("status", "stdout"): ("status_stdout", _boolean),
    ("status", "serial"): ("status_serial", _optional(_text)),
    ("status", "rate_hz"): ("status_rate_hz", _number(0.0, 100.0)),
    ("status", "nmea_rate_hz"): ("nmea_rate_hz", _number(0.0, 20.0)),
    ("status", "nmea_queue"): ("nmea_queue", _integer(1, 100_000)),
    ("status", "nmea_write_timeout_s"): ("nmea_write_timeout_s", _number(0.0, 60.0)),
    ("monitor", "f0_persistence_k"): ("f0_persistence_k", _integer(1, 100_000)),
    ("monitor", "f0_persistence_n"): ("f0_persistence_n", _integer(1, 100_000)),
    ("monitor", "stuck_samples"): ("stuck_samples", _integer(2, 1_000_000)),
    ("monitor", "no_data_timeout_s"): ("no_data_timeout_s", _number(0.0, 3600.0)),
    ("reconnect", "min_s"): ("reconnect_min_s", _number(0.0, 3600.0)),
    ("reconnect", "max_s"): ("reconnect_max_s", _number(0.0, 3600.0)),
    ("diagnosis", "window_intervals"): ("diagnosis_window_intervals", _integer(9, 10_000)),
    ("diagnosis", "window_max_s"): ("diagnosis_window_max_s", _number(0.0, 86_400.0)),
    ("diagnosis", "persist_windows"): ("diagnosis_persist_windows", _integer(1, 1000)),
    ("diagnosis", "static_window_s"): ("static_window_s", _number(0.0, 60.0)),
    ("log_level",): ("log_level", _log_level),
    ("aiding",): ("aiding", _optional(_aiding_url)),
}
_FIELD_KEY = {name: ".".join(path) for path, (name, _) in SCHEMA.items()}
_FIELD_CHECK = {name: check for name, check in SCHEMA.values()}
_SECTIONS = {path[0] for path in SCHEMA if len(path) > 1}


def _parse_yaml(text: str, source: str) -> Any:
    try:
        return yamlio.parse(text)
    except yamlio.YamlError as exc:
        where = f"line {exc.line}" if exc.line is not None else "(document)"
        raise ConfigError(source, where, exc.problem) from None


# ---------------------------------------------------------------------------
# public API


def from_dict(doc: Any, source: str = "(config)", base: DaemonConfig | None = None) -> DaemonConfig:
    """Validate a parsed YAML document and apply it over ``base`` (default: field defaults).

    Relative certificate paths are resolved against the directory of ``source``
    when ``source`` is a file.
    """
    base = DaemonConfig() if base is None else base
    if doc is None:
        doc = {}
    if not isinstance(doc, Mapping):
        got = type(doc).__name__
        raise ConfigError(source, "(document)", f"expected a mapping of keys, got {got}")

    def fail_at(key: str) -> Callable[[str], Exception]:
        return lambda reason: ConfigError(source, key, reason)

    top_known = sorted({path[0] for path in SCHEMA})
    changes: dict[str, Any] = {}
    for key, value in doc.items():
        if not isinstance(key, str) or key not in top_known:
            raise ConfigError(source, str(key), f"unknown key; known: {', '.join(top_known)}")
        if key in _SECTIONS:
            if value is None:
                continue
            if not isinstance(value, Mapping):
                raise ConfigError(source, key, f"expected a mapping, got {value!r}")
            sub_known = sorted(path[1] for path in SCHEMA if path[0] == key and len(path) > 1)
            for sub, sub_value in value.items():
                if not isinstance(sub, str) or sub not in sub_known:
                    raise ConfigError(
                        source, f"{key}.{sub}", f"unknown key; known: {', '.join(sub_known)}"
                    )
                name, check = SCHEMA[(key, sub)]
                changes[name] = check(sub_value, fail_at(f"{key}.{sub}"))
        else:
            name, check = SCHEMA[(key,)]
            changes[name] = check(value, fail_at(key))

    cert = changes.get("certificate")
    if cert is not None and cert != AUTO:
        path = Path(cert).expanduser()
        if not path.is_absolute() and Path(source).is_file():
            path = Path(source).resolve().parent / path
        changes["certificate"] = str(path)
    config = base.replace(origin=source, **changes)
    _check_consistency(config, lambda fields: (source, _FIELD_KEY[fields[0]]))
    return config


def _check_consistency(
    config: DaemonConfig, where: Callable[[tuple[str, ...]], tuple[str, str]]
) -> None:
    """Rules linking several keys, and the certificate file's existence.

    ``where(fields)`` gives the (source, key) to name for a rule involving
    ``fields`` (the first is the one reported unless another came from elsewhere).
    """

    def fail(fields: tuple[str, ...], reason: str) -> ConfigError:
        return ConfigError(*where(fields), reason)

    if config.f0_persistence_k > config.f0_persistence_n:
        raise fail(
            ("f0_persistence_k", "f0_persistence_n"),
            f"k = {config.f0_persistence_k} exceeds f0_persistence_n = {config.f0_persistence_n}",
        )
    if config.reconnect_max_s < config.reconnect_min_s:
        raise fail(
            ("reconnect_max_s", "reconnect_min_s"),
            f"{config.reconnect_max_s:g} s is below reconnect min_s = {config.reconnect_min_s:g} s",
        )
    if config.certificate not in (None, AUTO) and not Path(config.certificate).is_file():
        raise fail(("certificate",), f"no such certificate file: {config.certificate}")


def loads_config(text: str, source: str = "(config)") -> DaemonConfig:
    """Parse configuration YAML text over the defaults."""
    return from_dict(_parse_yaml(text, source), source)


def load_config(path: str | Path) -> DaemonConfig:
    """Read and validate a configuration file; omitted keys keep the defaults."""
    path = Path(path)
    try:
        text = yamlio.read_text(path)
    except OSError as exc:
        raise ConfigError(str(path), "(file)", f"cannot read: {exc.strerror or exc}") from None
    except yamlio.YamlError as exc:
        raise ConfigError(str(path), "(file)", exc.problem) from None
    return from_dict(_parse_yaml(text, str(path)), str(path))


def bundled_config_path() -> Path:
    """Path of the bundled default configuration ``imudiag/config/imudiag.yaml``."""
    return Path(str(resources.files("imudiag.config").joinpath(BUNDLED_CONFIG_NAME)))


def default_config() -> DaemonConfig:
    """The bundled default configuration (the simulated board, status on stdout)."""
    return load_config(bundled_config_path())


#: Field name -> option of ``imudiag run`` where the two differ (named in errors).
CLI_OPTIONS = {
    "status_rate_hz": "--status-rate",
    "nmea_rate_hz": "--nmea-rate",
    "no_data_timeout_s": "--no-data-timeout",
}


def merge_cli(
    config: DaemonConfig,
    args: Mapping[str, Any],
    option_names: Mapping[str, str] | None = None,
) -> DaemonConfig:
    """Apply command-line options over ``config``; ``None`` means "not given".

    Keys are :class:`DaemonConfig` field names (``source``, ``certificate``,
    ``status_rate_hz``, ``log_level``, ...; argparse dests of ``--status-rate-hz``
    and the like) plus ``status``: a string or a list of strings, ``-`` for
    standard output and anything else the NMEA serial URL; when given, the
    sinks are exactly those listed. Other keys (argparse's ``func``,
    ``command``, ``config``) are ignored. Values get the same checks as the
    file, reported as ``command line: --option: reason``, the option named by
    ``option_names`` (default :data:`CLI_OPTIONS`) or ``--field-name``.
    """
    source = "command line"
    names = CLI_OPTIONS if option_names is None else option_names

    def option(name: str) -> str:
        return names.get(name) or "--" + name.replace("_", "-")

    changes: dict[str, Any] = {}
    for name, value in args.items():
        if value is None:
            continue
        if name == "status":
            changes.update(_status_sinks(value, source))
        elif name in _FIELD_CHECK and name != "origin":
            check = _FIELD_CHECK[name]

            def fail(reason: str, n: str = name) -> ConfigError:
                return ConfigError(source, option(n), reason)

            changes[name] = check(value, fail)
    if "certificate" in changes and changes["certificate"] != AUTO:
        changes["certificate"] = str(Path(changes["certificate"]).expanduser())
    merged = config.replace(**changes)

    def where(fields: tuple[str, ...]) -> tuple[str, str]:
        """Blame the command line when it set one of ``fields``, else the file."""
        given = [f for f in fields if f in changes]
        if given:
            return source, option(given[0])
        return str(config.origin or "(config)"), _FIELD_KEY[fields[0]]

    _check_consistency(merged, where)
    return merged


def _status_sinks(value: Any, source: str) -> dict[str, Any]:
    items = [value] if isinstance(value, str) else value
    if not isinstance(items, (list, tuple)) or not items:
        raise ConfigError(source, "--status", f"expected '-' or a serial URL, got {value!r}")
    stdout, serial = False, None
    for item in items:
        if not isinstance(item, str) or not item.strip():
            raise ConfigError(source, "--status", f"expected '-' or a serial URL, got {item!r}")
        if item.strip() == "-":
            stdout = True
        elif serial is not None:
            raise ConfigError(
                source, "--status", f"only one serial status link, got {serial!r} and {item!r}"
            )
        else:
            serial = item.strip()
    return {"status_stdout": stdout, "status_serial": serial}


__all__ = [
    "BUNDLED_CONFIG_NAME",
    "CLI_OPTIONS",
    "ConfigError",
    "DaemonConfig",
    "SCHEMA",
    "bundled_config_path",
    "default_config",
    "from_dict",
    "load_config",
    "loads_config",
    "merge_cli",
]

"""Bench scenarios: a motion, a duration and faults injected at known sample times (YAML).

A scenario file (docs/bench.md has the full reference)::

    format: imudiag-bench-scenario/1
    name: sensor-faults
    motion: static                 # imudiag.sim scenario: static, multiposition, ...
    motion_params: {dwell: 20}     # its parameters
    duration: 12.0                 # s of sample time
    seed: 3
    speed: 5.0                     # board pace relative to real time
    device: native                 # the fake device (imudiag.bench.devices.ENCODERS)
    effects: [board]               # imudiag.sim text effects
    daemon:                        # daemon configuration keys (config/imudiag.yaml layout)
      monitor: {stuck_samples: 50}
    injections:
      - {t: 2.0, kind: bias, sensor: az, value: 800, within: 1.0,
         expect: [{triad: accel, cause: f0}]}
      - {t: 5.0, kind: garbage, bytes: 500}
      - {t: 6.0, kind: unplug, outage: 1.0}

Sensor kinds (imudiag.sim.faults): ``bias scale_factor misalignment stuck noise
dead``; transport kinds: ``garbage`` (``bytes``; ``random: true`` lets the
bytes hold sync patterns: then false frame candidates may add CRC errors, which
are not checked), ``crc`` (``frames`` corrupted),
``lost`` (``frames`` never sent), ``duplicate`` (the last frame sent again
``frames`` times), ``unplug`` (``outage`` s of wall time without the device),
``stall`` (the device stays plugged in but sends nothing for ``outage`` s of
wall time). A device other than ``native`` (docs/devices.md) takes every transport kind
but ``random`` garbage (its frames are its own: the fake device splits and corrupts them).

Every rule is checked on load; a violation raises :class:`ScenarioError`
naming the file, the line and the key.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

from imudiag import validate, yamlio
from imudiag.errors import BadInput
from imudiag.sim.drive import GnssSimConfig
from imudiag.sim.faults import KINDS as SENSOR_KINDS
from imudiag.sim.faults import Fault
from imudiag.sim.scenarios import DRIVES, canonical_scenario, parse_effects, scenario_params

FORMAT = "imudiag-bench-scenario/1"
COUNTER_KINDS = ("garbage", "crc", "lost", "duplicate")  #: checked by exact counter increments
OUTAGE_KINDS = ("unplug", "stall")  #: no samples for a while: checked by state no_data
TRANSPORT_KINDS = (*COUNTER_KINDS, *OUTAGE_KINDS)
KINDS = (*SENSOR_KINDS, *TRANSPORT_KINDS)
CAUSES = ("f0", "bias", "scale_factor", "misalignment", "stuck", "noise", "saturation")
TRIADS = ("gyro", "accel")
REQUIRES = ("diagnosis",)
ERROR_COUNTERS = ("crc_errors", "skipped_bytes", "lost", "duplicates")

DEFAULT_WITHIN_S = 2.0  #: sample-time bound of a per-sample (monitor) detection, s
DEFAULT_DIAGNOSIS_WITHIN_S = 120.0  #: sample-time bound of a window-diagnosis detection, s
DEFAULT_COUNTER_WITHIN_S = 0.5  #: sample-time bound for the counters to show an injection, s
DEFAULT_SPEED = 5.0
MIN_TRANSPORT_GAP_S = 0.5  #: sample time between counter injections (attribution), s

#: Daemon configuration the bench runs with unless the scenario's ``daemon`` overrides it.
BENCH_DAEMON_DEFAULTS: dict[str, Any] = {
    "status": {"rate_hz": 10.0},
    "monitor": {"no_data_timeout_s": 0.5},
    "reconnect": {"min_s": 0.1, "max_s": 0.4},
}


class ScenarioError(BadInput):
    """A scenario breaking a rule: ``source`` file, ``line`` (or None), ``key``, ``reason``."""

    def __init__(self, source: str, line: int | None, key: str, reason: str) -> None:
        self.source, self.line, self.key, self.reason = source, line, key, reason
        where = f"{source}:{line}" if line is not None else source
        super().__init__(f"{where}: {key}: {reason}")


# ---------------------------------------------------------------------------
# the model


@dataclass(frozen=True)
class Expectation:
    """A status ``faults`` entry that counts as detecting an injected fault.

    ``sensor`` None matches any sensor (or none); ``within_s`` is the bound on
    the detection latency in sample time (s); ``requires`` ``"diagnosis"``
    marks what only the sliding-window diagnosis can see.
    """

    triad: str
    cause: str
    sensor: str | None = None
    within_s: float = DEFAULT_WITHIN_S
    requires: str | None = None
    #: also matched by a moving-base group ("one of", sensors and causes ``|``-joined)
    #: that holds this sensor and cause
    group: bool = False

    def matches(self, entry: Mapping[str, Any]) -> bool:
        """True if the status fault entry ``entry`` is this expectation."""
        if entry.get("triad") != self.triad:
            return False
        cause, sensor = str(entry.get("cause") or ""), str(entry.get("sensor") or "")
        if self.group and "|" in cause:
            members = list(zip(sensor.split("|"), cause.split("|"), strict=False))
            return any(
                c == self.cause and (self.sensor is None or s == self.sensor) for s, c in members
            )
        if cause != self.cause:
            return False
        return self.sensor is None or sensor == self.sensor

    def describe(self) -> str:
        """``accel az bias`` style text."""
        return " ".join(p for p in (self.triad, self.sensor, self.cause) if p)

    def as_dict(self) -> dict[str, Any]:
        """JSON form."""
        d: dict[str, Any] = {"triad": self.triad}
        if self.sensor is not None:
            d["sensor"] = self.sensor
        d["cause"] = self.cause
        d["within_s"] = self.within_s
        if self.requires:
            d["requires"] = self.requires
        if self.group:
            d["group"] = True
        return d


@dataclass(frozen=True)
class Injection:
    """One fault injected at sample time ``t_s``.

    Sensor faults carry ``sensor``/``value`` (imudiag.sim.faults units) and
    ``expect``; ``also`` lists side effects that are not false alarms.
    Counter faults carry ``count`` (bytes for garbage, frames otherwise);
    ``within_s`` bounds the sample time until the counters show them.
    ``unplug`` and ``stall`` carry ``outage_s`` (wall s without the device or
    without data), ``within_s`` (wall s until ``no_data``),
    ``recover_within_s`` (wall s from replug or resume until samples flow
    again); ``unplug`` also ``drain`` (wait until the daemon read every byte
    before pulling the plug, so that no frame is lost in flight).
    """

    number: int  #: 1-based position in the file
    t_s: float
    kind: str
    sensor: str | None = None
    value: float | None = None
    count: int | None = None
    random: bool = False  #: garbage with sync patterns (CRC errors not checked)
    outage_s: float | None = None
    drain: bool = True
    within_s: float = DEFAULT_COUNTER_WITHIN_S
    recover_within_s: float = 3.0
    expect: tuple[Expectation, ...] = ()
    also: tuple[Expectation, ...] = ()
    line: int | None = None

    @property
    def category(self) -> str:
        """``sensor``, ``counters`` or ``outage`` (unplug, stall)."""
        if self.kind in SENSOR_KINDS:
            return "sensor"
        return "outage" if self.kind in OUTAGE_KINDS else "counters"

    def fault(self) -> Fault:
        """The simulator fault of a sensor injection."""
        assert self.sensor is not None
        return Fault(self.kind, self.sensor, self.t_s, self.value)

    def describe(self) -> str:
        """Short text: ``bias az 800``, ``garbage 500 B``, ``unplug 1.0 s``."""
        if self.category == "sensor":
            value = "" if self.value is None else f" {self.value:g}"
            return f"{self.kind} {self.sensor}{value}"
        if self.kind == "garbage":
            return f"garbage {self.count} B" + (" random" if self.random else "")
        if self.kind in OUTAGE_KINDS:
            return f"{self.kind} {self.outage_s:g} s"
        return f"{self.kind} {self.count} fr"

    def as_dict(self) -> dict[str, Any]:
        """JSON form (what was injected)."""
        d: dict[str, Any] = {"number": self.number, "t": self.t_s, "kind": self.kind}
        if self.category == "sensor":
            d["sensor"] = self.sensor
            if self.value is not None:
                d["value"] = self.value
        elif self.kind in OUTAGE_KINDS:
            d["outage_s"] = self.outage_s
            if self.kind == "unplug":
                d["drain"] = self.drain
        else:
            d["bytes" if self.kind == "garbage" else "frames"] = self.count
            if self.kind == "garbage":
                d["random"] = self.random
        return d


@dataclass(frozen=True)
class AidingSpec:
    """GNSS aiding of a drive scenario: the simulated receiver whose UBX stream the bench
    feeds to a real gpsd, and the bound on when the daemon must report aiding in use."""

    rate_hz: float = 5.0  #: GNSS epochs per second, Hz
    sigma_h_m_s: float = 0.03  #: horizontal velocity noise per axis, m/s (1 sigma)
    sigma_v_m_s: float = 0.05  #: vertical velocity noise, m/s (1 sigma)
    latency_s: float = 0.12  #: receiver output latency (time tags late by it), s
    outlier_rate: float = 0.005  #: fraction of epochs with a multipath velocity error
    in_use_within: float = 60.0  #: sample time from the start until aiding is in use, s

    def gnss_config(self) -> GnssSimConfig:
        """The simulator's receiver (:class:`imudiag.sim.drive.GnssSimConfig`)."""
        return GnssSimConfig(
            rate_hz=self.rate_hz,
            sigma_h_m_s=self.sigma_h_m_s,
            sigma_v_m_s=self.sigma_v_m_s,
            latency_s=self.latency_s,
            outlier_rate=self.outlier_rate,
        )

    def as_dict(self) -> dict[str, Any]:
        """JSON form."""
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class BenchScenario:
    """A whole bench run: motion, duration, board effects, daemon settings, injections."""

    name: str
    motion: str = "static"
    motion_params: dict[str, str] = field(default_factory=dict)
    duration_s: float = 10.0
    seed: int = 0
    speed: float = DEFAULT_SPEED
    effects: tuple[str, ...] = ("board",)
    certificate: str | None = None  #: certificate file (None: the bundled one)
    daemon: dict[str, Any] = field(default_factory=dict)  #: daemon config document
    injections: tuple[Injection, ...] = ()
    description: str = ""
    source: str = "(scenario)"  #: file it was read from
    chunk_s: float = 0.05  #: sample time per write to the pty, s
    aiding: AidingSpec | None = None  #: GNSS aiding through a real gpsd (drives only)
    #: the fake device the board's samples go out as (imudiag.bench.devices.ENCODERS)
    device: str = "native"

    @property
    def sensor_injections(self) -> list[Injection]:
        """Injections handled by the simulator."""
        return [i for i in self.injections if i.category == "sensor"]

    @property
    def transport_injections(self) -> list[Injection]:
        """Injections handled by the byte feeder, in time order."""
        return sorted((i for i in self.injections if i.category != "sensor"), key=lambda i: i.t_s)

    def with_options(
        self, seed: int | None = None, speed: float | None = None, device: str | None = None
    ) -> BenchScenario:
        """A copy with a different seed, board speed or device."""
        changes: dict[str, Any] = {}
        if device is not None:
            problem = device_problem(device, self.injections)
            if problem:
                raise BadInput(f"--device: {problem}")
            changes["device"] = device
        if seed is not None:
            changes["seed"] = int(seed)
        if speed is not None:
            if not (math.isfinite(speed) and speed > 0):
                raise BadInput(f"--speed: must be a positive number, got {speed!r}")
            changes["speed"] = float(speed)
        return dataclasses.replace(self, **changes)


# ---------------------------------------------------------------------------
# YAML with line numbers and duplicate keys rejected


_LineDict = yamlio.LineDict


class _Reader:
    """Typed access to a parsed mapping with errors that name file, line and key path."""

    def __init__(self, source: str, doc: Mapping[str, Any], path: str = "") -> None:
        self.source = source
        self.doc = doc
        self.path = path

    def line(self, key: str | None = None) -> int | None:
        if key is not None and isinstance(self.doc, _LineDict) and key in self.doc.key_lines:
            return self.doc.key_lines[key]
        return getattr(self.doc, "line", None)

    def key(self, key: str) -> str:
        return f"{self.path}.{key}" if self.path else key

    def fail(self, key: str | None, reason: str) -> ScenarioError:
        return ScenarioError(
            self.source,
            self.line(key),
            self.key(key) if key else (self.path or "(document)"),
            reason,
        )

    def _fail(self, key: str | None) -> validate.Fail:
        return lambda reason: self.fail(key, reason)

    def check_keys(self, known: tuple[str, ...]) -> None:
        validate.unknown_keys(self.doc, known, self._fail)

    def get(self, key: str, default: Any = None) -> Any:
        return self.doc.get(key, default)

    def number(
        self,
        key: str,
        default: float | None = None,
        lo: float = -math.inf,
        hi: float = math.inf,
        lo_open: bool = False,
        required: bool = False,
    ) -> float:
        if key not in self.doc or self.doc[key] is None:
            if required or default is None:
                raise self.fail(key, "required number missing")
            return default
        return validate.number(self.doc[key], self._fail(key), lo, hi, lo_open=lo_open)

    def integer(self, key: str, default: int | None = None, lo: int = 0, hi: int = 10**9) -> int:
        if key not in self.doc or self.doc[key] is None:
            if default is None:
                raise self.fail(key, "required integer missing")
            return default
        return validate.integer(self.doc[key], self._fail(key), lo, hi)

    def text(self, key: str, default: str | None = None, choices: tuple[str, ...] = ()) -> str:
        v = self.doc.get(key, default)
        if v is None:
            raise self.fail(key, "required text missing")
        return validate.text(v, self._fail(key), choices)

    def boolean(self, key: str, default: bool) -> bool:
        return validate.boolean(self.doc.get(key, default), self._fail(key))

    def mapping(self, key: str) -> _Reader | None:
        v = self.doc.get(key)
        if v is None:
            return None
        if not isinstance(v, Mapping):
            raise self.fail(key, f"expected a mapping, got {v!r}")
        return _Reader(self.source, v, self.key(key))

    def sequence(self, key: str) -> list[Any]:
        v = self.doc.get(key)
        if v is None:
            return []
        if not isinstance(v, list):
            raise self.fail(key, f"expected a list, got {v!r}")
        return v


# ---------------------------------------------------------------------------
# parsing


#: transport injections a device other than the native board takes
DEVICE_TRANSPORT_KINDS = ("garbage", "crc", "lost", "duplicate", "unplug", "stall")


def device_problem(device: str, injections: tuple[Injection, ...]) -> str | None:
    """Why ``device`` cannot play these injections (None: it can)."""
    from .devices import ENCODERS

    if device not in ENCODERS:
        return f"unknown device {device!r}; known: {', '.join(sorted(ENCODERS))}"
    if device == "native":
        return None
    for inj in injections:
        if device == "iio" and inj.kind in ("garbage", "crc"):
            return (
                f"injection {inj.number} ({inj.kind}): device iio is a kernel buffer of "
                "packed records, with no framing and no checksum: garbage and corrupted "
                "frames cannot happen on it (lost, duplicate, unplug and stall can)"
            )
        if inj.category != "sensor" and (inj.kind not in DEVICE_TRANSPORT_KINDS or inj.random):
            return (
                f"injection {inj.number} (random garbage) is the native wire protocol's; "
                f"device {device} takes garbage without random"
            )
    return None


_TOP_KEYS = (
    "device",
    "format",
    "name",
    "description",
    "motion",
    "motion_params",
    "duration",
    "seed",
    "speed",
    "effects",
    "certificate",
    "daemon",
    "injections",
    "chunk",
    "aiding",
)
_EXPECT_KEYS = ("triad", "sensor", "cause", "within", "requires", "group")
DRIVE_MOTION = "drive"  #: ``motion: drive`` with ``motion_params.route`` (a DRIVES name)
_AIDING_KEYS = tuple(f.name for f in dataclasses.fields(AidingSpec))
_SENSOR_NAMES = {"gyro": ("gx", "gy", "gz"), "accel": ("ax", "ay", "az")}


def _triad_of(sensor: str) -> str:
    return "gyro" if sensor.startswith("g") else "accel"


def _default_expectations(kind: str, sensor: str) -> tuple[Expectation, ...]:
    """What a sensor fault should produce when the scenario does not say."""
    triad = _triad_of(sensor)
    if kind in ("stuck", "dead"):
        return (Expectation(triad, "stuck", sensor),)
    return (Expectation(triad, kind, sensor, DEFAULT_DIAGNOSIS_WITHIN_S, "diagnosis"),)


def _expectation(
    item: Any, reader: _Reader, key: str, index: int, default_within: float
) -> Expectation:
    path = f"{key}[{index}]"
    if not isinstance(item, Mapping):
        raise reader.fail(key, f"{path}: expected a mapping like {{triad: accel, cause: f0}}")
    r = _Reader(reader.source, item, reader.key(path))
    r.check_keys(_EXPECT_KEYS)
    triad = r.text("triad", choices=TRIADS)
    cause = r.text("cause", choices=CAUSES)
    sensor = None
    if r.get("sensor") is not None:
        sensor = r.text("sensor")
        names = _SENSOR_NAMES[triad]
        ok = sensor in names or (
            "/" in sensor and all(p in names for p in sensor.split("/")) and len(sensor) == 5
        )
        if not ok:
            raise r.fail(
                "sensor",
                f"{sensor!r} is not a {triad} sensor or pair "
                f"({', '.join(names)}, or a pair like {names[0]}/{names[1]})",
            )
    requires = r.text("requires", choices=REQUIRES) if r.get("requires") is not None else None
    if requires and default_within == DEFAULT_WITHIN_S:
        default_within = DEFAULT_DIAGNOSIS_WITHIN_S
    within = r.number("within", default_within, lo=0.0, lo_open=True)
    return Expectation(triad, cause, sensor, within, requires, r.boolean("group", False))


def _injection(item: Any, reader: _Reader, index: int, duration: float) -> Injection:
    path = f"injections[{index}]"
    if not isinstance(item, Mapping):
        raise reader.fail("injections", f"{path}: expected a mapping with t and kind")
    r = _Reader(reader.source, item, path)
    line = r.line()
    kind = r.text("kind", choices=KINDS)
    t = r.number("t", lo=0.0, hi=duration, required=True)
    if t >= duration:
        raise r.fail("t", f"{t:g} s is not before the end of the scenario ({duration:g} s)")
    number = index + 1
    if kind in SENSOR_KINDS:
        r.check_keys(("t", "kind", "sensor", "value", "within", "expect", "also"))
        sensor = r.text("sensor")
        value = None if r.get("value") is None else r.number("value")
        try:
            Fault(kind, sensor, t, value)
        except ValueError as exc:
            raise r.fail(
                "sensor" if "sensor" in str(exc) or "pair" in str(exc) else "value", str(exc)
            ) from None
        within = r.number("within", DEFAULT_WITHIN_S, lo=0.0, lo_open=True)
        items = r.sequence("expect")
        expect = (
            tuple(_expectation(e, r, "expect", k, within) for k, e in enumerate(items))
            if items
            else _default_expectations(kind, sensor)
        )
        also = tuple(
            _expectation(e, r, "also", k, within) for k, e in enumerate(r.sequence("also"))
        )
        return Injection(
            number,
            t,
            kind,
            sensor=sensor,
            value=value,
            within_s=within,
            expect=expect,
            also=also,
            line=line,
        )
    if kind in OUTAGE_KINDS:
        keys = ("t", "kind", "outage", "within", "recover_within")
        r.check_keys((*keys, "drain") if kind == "unplug" else keys)
        outage = r.number("outage", 1.0, lo=0.0, hi=600.0, lo_open=True)
        return Injection(
            number,
            t,
            kind,
            outage_s=outage,
            drain=r.boolean("drain", True) if kind == "unplug" else True,
            within_s=r.number("within", 2.0, lo=0.0, lo_open=True),
            recover_within_s=r.number("recover_within", 3.0, lo=0.0, lo_open=True),
            line=line,
        )
    count_key = "bytes" if kind == "garbage" else "frames"
    r.check_keys(
        ("t", "kind", count_key, "within", "random")
        if kind == "garbage"
        else ("t", "kind", count_key, "within")
    )
    count = r.integer(count_key, lo=1, hi=50_000_000 if kind == "garbage" else 100_000)
    if t < MIN_TRANSPORT_GAP_S:
        raise r.fail(
            "t",
            f"a {kind} injection needs t >= {MIN_TRANSPORT_GAP_S:g} s (a status "
            "line before it is the baseline of its counters)",
        )
    if duration - t < MIN_TRANSPORT_GAP_S:
        raise r.fail(
            "t",
            f"a {kind} injection needs {MIN_TRANSPORT_GAP_S:g} s of samples after "
            f"it (the receiver counts losses at the next frame)",
        )
    within = r.number("within", DEFAULT_COUNTER_WITHIN_S, lo=0.0, lo_open=True)
    random = r.boolean("random", False) if kind == "garbage" else False
    return Injection(number, t, kind, count=count, random=random, within_s=within, line=line)


def _line_of(doc: Any, path: tuple[str, ...]) -> int | None:
    """Line of the deepest key of ``path`` found in the parsed document."""
    line = getattr(doc, "line", None)
    for key in path:
        if not isinstance(doc, _LineDict) or key not in doc:
            break
        line = doc.key_lines.get(key, line)
        doc = doc[key]
    return line


def _merge(base: Mapping[str, Any], over: Mapping[str, Any]) -> dict[str, Any]:
    out = {k: (dict(v) if isinstance(v, Mapping) else v) for k, v in base.items()}
    for k, v in over.items():
        if isinstance(v, Mapping) and isinstance(out.get(k), Mapping):
            out[k] = _merge(out[k], v)
        else:
            out[k] = v
    return out


def _plain(obj: Any) -> Any:
    if isinstance(obj, Mapping):
        return {k: _plain(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_plain(v) for v in obj]
    return obj


def _motion(r: _Reader, params: _Reader | None) -> str:
    """The simulator scenario of ``motion:``; ``drive`` takes ``motion_params.route``."""
    if r.get("motion") is not None and r.text("motion") == DRIVE_MOTION:
        if params is None or params.get("route") is None:
            raise r.fail(
                "motion", f"motion drive needs motion_params.route: one of {', '.join(DRIVES)}"
            )
        return params.text("route", choices=DRIVES)
    try:
        return canonical_scenario(r.text("motion", "static"))
    except ValueError as exc:
        raise r.fail("motion", str(exc)) from None


def from_dict(doc: Any, source: str = "(scenario)") -> BenchScenario:
    """Validate a parsed scenario document (see the module docstring)."""
    if not isinstance(doc, Mapping):
        raise ScenarioError(
            source, None, "(document)", f"expected a mapping of keys, got {type(doc).__name__}"
        )
    r = _Reader(source, doc)
    r.check_keys(_TOP_KEYS)
    if r.get("format") is not None and r.text("format") != FORMAT:
        raise r.fail("format", f"expected {FORMAT!r}, got {r.get('format')!r}")
    name = r.text("name", Path(source).stem if source != "(scenario)" else "scenario")
    params_reader = r.mapping("motion_params")
    motion = _motion(r, params_reader)
    params: dict[str, str] = {}
    if params_reader is not None:
        allowed = scenario_params(motion)
        for k, v in params_reader.doc.items():
            if k == "route" and r.text("motion") == DRIVE_MOTION:
                continue
            if k not in allowed:
                raise params_reader.fail(
                    str(k), f"unknown parameter of motion {motion}; known: {', '.join(allowed)}"
                )
            if isinstance(v, bool) or not isinstance(v, (int, float, str)):
                raise params_reader.fail(str(k), f"expected a number or text, got {v!r}")
            params[str(k)] = str(v)
    try:
        from imudiag.sim.scenarios import scenario_motion

        scenario_motion(motion, 0, params)
    except ValueError as exc:
        raise r.fail("motion_params", str(exc)) from None
    duration = r.number("duration", lo=0.0, hi=86_400.0, lo_open=True, required=True)
    seed = r.integer("seed", 0, lo=0, hi=2**32 - 1)
    speed = r.number("speed", DEFAULT_SPEED, lo=0.0, hi=1000.0, lo_open=True)
    chunk = r.number("chunk", 0.05, lo=0.0, hi=1.0, lo_open=True)
    effects_raw = r.sequence("effects") if r.get("effects") is not None else ["board"]
    effects: list[str] = []
    for n, e in enumerate(effects_raw):
        if not isinstance(e, str):
            raise r.fail("effects", f"effects[{n}]: expected text like 'noise:1', got {e!r}")
        effects.append(e)
    try:
        parse_effects(effects)
    except ValueError as exc:
        raise r.fail("effects", str(exc)) from None
    certificate = None
    if r.get("certificate") is not None:
        cert_path = Path(r.text("certificate")).expanduser()
        if not cert_path.is_absolute() and Path(source).is_file():
            cert_path = Path(source).resolve().parent / cert_path
        if not cert_path.is_file():
            raise r.fail("certificate", f"no such certificate file: {cert_path}")
        certificate = str(cert_path)
    daemon_doc: dict[str, Any] = {}
    if r.get("daemon") is not None:
        dr = r.mapping("daemon")
        assert dr is not None
        for bad in ("source", "certificate", "aiding"):
            if bad in dr.doc:
                raise dr.fail(
                    bad,
                    "set by the bench (the scenario's certificate: key, the pty, "
                    "its aiding: section)",
                )
        daemon_doc = _plain(dr.doc)
    daemon_doc = _merge(BENCH_DAEMON_DEFAULTS, daemon_doc)
    from imudiag.service.config import ConfigError
    from imudiag.service.config import from_dict as config_from_dict

    try:
        config_from_dict(daemon_doc, f"{source}: daemon")
    except ConfigError as exc:
        raise ScenarioError(
            source, _line_of(doc, ("daemon", *exc.key.split("."))), f"daemon.{exc.key}", exc.reason
        ) from None
    injections = tuple(
        _injection(item, r, k, duration) for k, item in enumerate(r.sequence("injections"))
    )
    counter_times = sorted(i.t_s for i in injections if i.category != "sensor")
    for a, b in zip(counter_times, counter_times[1:], strict=False):
        if b - a < MIN_TRANSPORT_GAP_S:
            late = next(i for i in injections if i.category != "sensor" and i.t_s == b)
            raise ScenarioError(
                source,
                late.line,
                f"injections[{late.number - 1}].t",
                f"transport injections at {a:g} s and {b:g} s are closer than "
                f"{MIN_TRANSPORT_GAP_S:g} s (their counter increments could not be told apart)",
            )
    device = r.text("device", "native")
    problem = device_problem(device, injections)
    if problem:
        raise r.fail("device", problem)
    aiding = _aiding(r, motion, duration)
    if aiding is not None:
        drive = scenario_motion(motion, seed, params)
        if drive.duration_s < duration:
            raise r.fail(
                "duration",
                f"{duration:g} s is longer than the {motion} drive of seed {seed} "
                f"({drive.duration_s:.1f} s): raise motion_params.length",
            )
    return BenchScenario(
        name=name,
        motion=motion,
        motion_params=params,
        duration_s=duration,
        seed=seed,
        speed=speed,
        effects=tuple(effects),
        certificate=certificate,
        daemon=daemon_doc,
        injections=injections,
        description=str(r.get("description") or "").strip(),
        source=source,
        chunk_s=chunk,
        aiding=aiding,
        device=device,
    )


def _aiding(r: _Reader, motion: str, duration: float) -> AidingSpec | None:
    """The ``aiding:`` section (None when absent); it needs a drive motion."""
    if r.get("aiding") is None:
        return None
    ar = r.mapping("aiding")
    assert ar is not None
    if motion not in DRIVES:
        raise r.fail(
            "aiding",
            f"GNSS aiding needs a drive motion ({', '.join(DRIVES)}), got {motion}",
        )
    ar.check_keys(_AIDING_KEYS)
    d = AidingSpec()
    return AidingSpec(
        rate_hz=ar.number("rate_hz", d.rate_hz, lo=0.5, hi=20.0),
        sigma_h_m_s=ar.number("sigma_h_m_s", d.sigma_h_m_s, lo=0.0, hi=5.0),
        sigma_v_m_s=ar.number("sigma_v_m_s", d.sigma_v_m_s, lo=0.0, hi=5.0),
        latency_s=ar.number("latency_s", d.latency_s, lo=0.0, hi=1.0),
        outlier_rate=ar.number("outlier_rate", d.outlier_rate, lo=0.0, hi=0.5),
        in_use_within=ar.number(
            "in_use_within", d.in_use_within, lo=0.0, hi=duration, lo_open=True
        ),
    )


def loads(text: str, source: str = "(scenario)") -> BenchScenario:
    """Parse scenario YAML text."""
    try:
        doc = yamlio.parse(text)
    except yamlio.YamlError as exc:
        raise ScenarioError(source, exc.line, "(document)", exc.problem) from None
    return from_dict(doc, source)


def load(path: str | Path) -> BenchScenario:
    """Read and validate a scenario file."""
    p = Path(path)
    try:
        text = yamlio.read_text(p)
    except OSError as exc:
        raise ScenarioError(str(p), None, "(file)", f"cannot read: {exc.strerror or exc}") from None
    except yamlio.YamlError as exc:
        raise ScenarioError(str(p), None, "(file)", exc.problem) from None
    return loads(text, str(p))


def bundled_names() -> list[str]:
    """Names of the scenarios shipped in ``imudiag/bench/scenarios``."""
    root = resources.files("imudiag.bench").joinpath("scenarios")
    return sorted(p.name[: -len(".yaml")] for p in root.iterdir() if p.name.endswith(".yaml"))


def bundled_path(name: str) -> Path:
    """The file of bundled scenario ``name``; BadInput lists the known ones."""
    root = resources.files("imudiag.bench").joinpath("scenarios")
    p = root.joinpath(f"{name}.yaml")
    if not p.is_file():
        raise BadInput(
            f"unknown bench scenario {name!r}; bundled: {', '.join(bundled_names())} "
            "(or --scenario FILE.yaml)"
        )
    return Path(str(p))


def load_bundled(name: str) -> BenchScenario:
    """A bundled scenario by name."""
    return load(bundled_path(name))


__all__ = [
    "AidingSpec",
    "BENCH_DAEMON_DEFAULTS",
    "BenchScenario",
    "COUNTER_KINDS",
    "ERROR_COUNTERS",
    "Expectation",
    "FORMAT",
    "Injection",
    "KINDS",
    "OUTAGE_KINDS",
    "ScenarioError",
    "TRANSPORT_KINDS",
    "bundled_names",
    "bundled_path",
    "from_dict",
    "load",
    "load_bundled",
    "loads",
]

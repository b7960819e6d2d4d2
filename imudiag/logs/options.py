"""Options that say how to read a log the user brought, shared by every log command and replay://.

``--columns t,gx,gy,gz,ax,ay,az`` names a text table's columns in file order
(``_`` skips one), ``--units gyro=deg/s,accel=g`` states the log's units,
``--time-unit s|ms|us|ns`` the unit of ``t``, ``--rate HZ`` the sample rate of
a log without time stamps. The same keys are ``replay://`` URL query keys
(``?columns=t,gx,...&units=gyro=deg/s,accel=g&time_unit=ms&rate=100``).
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, field
from typing import Any

from .. import validate
from ..argtypes import nonnegative_int, sample_rate
from ..errors import BadInput
from ..units import canonical, units_of
from .base import OPTIONAL_COLUMNS, REQUIRED_COLUMNS
from .timing import TIME_UNITS

#: Units a log's outputs may be stated in, per triad (``count`` is raw ADC output; the
#: physical ones convert exactly to a certificate's, imudiag.units).
GYRO_UNITS = units_of("gyro")
ACCEL_UNITS = units_of("accel")
#: Column names --columns accepts, besides ``_`` (skip).
COLUMN_NAMES = REQUIRED_COLUMNS + OPTIONAL_COLUMNS
GYRO_COLUMNS = ("gx", "gy", "gz")

#: The ROS 2 distribution whose message definitions read a bag that stores none and
#: does not say its own (``--ros-distro``): the current LTS, Lyrical Luth (May 2026).
#: sensor_msgs/Imu, NavSatFix and the geometry_msgs velocities are the same since Foxy.
DEFAULT_ROS_DISTRO = "lyrical"
#: ROS 2 distributions rosbags has message definitions of (``--ros-distro``).
ROS2_DISTROS = (
    "dashing", "eloquent", "foxy", "galactic", "humble", "iron", "jazzy", "kilted", "lyrical",
)  # fmt: skip


@dataclass
class LogOptions:
    """How to read a log: column names, units, time unit, sample rate (Hz)."""

    columns: list[str] | None = None
    units: dict[str, str] = field(default_factory=dict)  #: {"gyro": ..., "accel": ...}
    time_unit: str | None = None
    rate: float | None = None  #: Hz, for logs without time stamps
    variable: str | None = None  #: the matrix of a MATLAB file, the object of an R file
    #: accept a log without accelerometer columns (a gyro on a turntable, ``--known-rate``):
    #: its accelerometer outputs read as NaN
    gyro_only: bool = False
    instance: int | None = None  #: the sensor instance of a multi-sensor log (PX4 multi id)
    topic: str | None = None  #: the IMU topic of a ROS bag
    #: the ROS 2 distribution whose message definitions read a bag that stores none and
    #: does not name its own (default: the current LTS)
    ros_distro: str | None = None

    def given(self) -> bool:
        """True when any option was given."""
        return bool(
            self.columns
            or self.units
            or self.time_unit
            or self.rate
            or self.variable
            or self.instance is not None
            or self.topic
            or self.ros_distro
        )


def missing_columns(names: list[str], gyro_only: bool = False) -> list[str]:
    """The sensor columns a log must name that ``names`` lacks (accelerometer axes not
    needed for a ``gyro_only`` log)."""
    need = GYRO_COLUMNS if gyro_only else REQUIRED_COLUMNS[1:]
    return [n for n in need if n not in names]


def parse_columns(text: str, where: str = "--columns", gyro_only: bool = False) -> list[str]:
    """``t,gx,...`` -> names; ``_`` skips a column. Raises BadInput naming the bad name."""
    names = [c.strip() for c in text.split(",")]
    seen: set[str] = set()
    for name in names:
        if name == "_":
            continue
        if name not in COLUMN_NAMES:
            raise BadInput(
                f"{where}: unknown column {name!r}; expected {', '.join(COLUMN_NAMES)} or _ (skip)"
            )
        if name in seen:
            raise BadInput(f"{where}: column {name!r} named twice")
        seen.add(name)
    missing = missing_columns(list(seen), gyro_only)
    if missing:
        raise BadInput(f"{where}: missing {', '.join(missing)} (name the gyro and accel axes)")
    return names


def parse_units(text: str, where: str = "--units") -> dict[str, str]:
    """``gyro=deg/s,accel=g`` -> {"gyro": "deg/s", "accel": "g"}; raises BadInput."""
    units: dict[str, str] = {}
    for part in text.replace(" ", ",").split(","):
        if not part.strip():
            continue
        key, sep, value = part.partition("=")
        key, value = key.strip(), value.strip()
        allowed = {"gyro": GYRO_UNITS, "accel": ACCEL_UNITS}.get(key)
        if not sep or allowed is None:
            raise BadInput(f"{where}: expected gyro=UNIT,accel=UNIT, got {part!r}")
        value = canonical(value) if value else value
        if value not in allowed:
            raise BadInput(f"{where}: {key} unit {value!r} unknown; expected {', '.join(allowed)}")
        units[key] = value
    return units


def parse_time_unit(text: str, where: str = "--time-unit") -> str:
    """One of s, ms, us, ns; raises BadInput."""
    if text not in TIME_UNITS:
        raise BadInput(f"{where}: expected one of {', '.join(TIME_UNITS)}, got {text!r}")
    return text


def parse_rate(value: Any, where: str = "--rate") -> float:
    """A sample rate in Hz given as text or a number (a URL query's ``rate=200``), checked
    as every sample rate is (:func:`imudiag.validate.sample_rate`); raises BadInput."""
    try:
        rate = float(value)
    except (TypeError, ValueError):
        raise BadInput(f"{where}: expected a rate in Hz, got {value!r}") from None
    return validate.sample_rate(rate, where)


def add_log_options(parser: argparse.ArgumentParser) -> None:
    """Add --columns, --units, --time-unit and (unless the command has one) --rate."""
    g = parser.add_argument_group("reading logs (text tables, foreign formats)")
    g.add_argument(
        "--columns",
        metavar="NAMES",
        help="a text table's columns in file order, e.g. t,gx,gy,gz,ax,ay,az,temp (_ skips one)",
    )
    g.add_argument(
        "--units",
        metavar="SPEC",
        help="the log's units: gyro=rad/s|deg/s|count,accel=m/s^2|g|count",
    )
    g.add_argument(
        "--time-unit", metavar="U", help="unit of the t column: s (default), ms, us or ns"
    )
    g.add_argument(
        "--variable",
        metavar="NAME",
        help="the matrix of a MATLAB .mat file, the data.frame or matrix of an R .rda file",
    )
    g.add_argument(
        "--topic",
        metavar="NAME",
        help="the sensor_msgs/msg/Imu topic of a ROS bag (needed when it has several)",
    )
    g.add_argument(
        "--ros-distro",
        metavar="NAME",
        help="ROS 2 distribution of a bag that stores no message definitions and does not "
        "name its own (foxy, humble, iron, jazzy, ...; default: the current LTS)",
    )
    g.add_argument(
        "--instance",
        metavar="N",
        type=nonnegative_int("a sensor instance"),
        help="the sensor instance of a PX4 ULog (raw sensor_gyro/sensor_accel multi id; "
        "default: sensor_combined unless the raw topics are logged as fast)",
    )
    if "--rate" not in parser._option_string_actions:
        g.add_argument(
            "--rate",
            type=sample_rate,
            metavar="HZ",
            help="sample rate of a log without a t column (Hz)",
        )


def log_options(args: argparse.Namespace) -> LogOptions:
    """The validated options of a parsed command line (exit 2 on a bad value)."""
    opts = LogOptions(gyro_only=getattr(args, "known_rate", None) is not None)
    if getattr(args, "columns", None):
        opts.columns = parse_columns(args.columns, gyro_only=opts.gyro_only)
    if getattr(args, "units", None):
        opts.units = parse_units(args.units)
    if getattr(args, "time_unit", None):
        opts.time_unit = parse_time_unit(args.time_unit)
    if getattr(args, "rate", None) is not None:
        opts.rate = parse_rate(args.rate)
    if getattr(args, "variable", None):
        opts.variable = args.variable
    if getattr(args, "instance", None) is not None:
        opts.instance = parse_instance(args.instance)
    if getattr(args, "topic", None):
        opts.topic = args.topic
    if getattr(args, "ros_distro", None):
        opts.ros_distro = parse_ros_distro(args.ros_distro)
    return opts


def parse_ros_distro(text: str, where: str = "--ros-distro") -> str:
    """A ROS 2 distribution's name, lower case (foxy, humble, ...); raises BadInput."""
    name = str(text).strip().lower()
    if name not in ROS2_DISTROS:
        raise BadInput(f"{where}: unknown ROS 2 distribution {text!r}; expected one of "
                       f"{', '.join(ROS2_DISTROS)}")  # fmt: skip
    return name


def parse_instance(text: str, where: str = "--instance") -> int:
    """A sensor instance number (>= 0); raises BadInput."""
    try:
        value = int(str(text).strip())
    except ValueError:
        raise BadInput(
            f"{where}: expected a sensor instance number (0, 1, ...), got {text!r}"
        ) from None
    if value < 0:
        raise BadInput(f"{where}: expected a sensor instance number >= 0, got {value}")
    return value


def options_from_query(query: dict[str, str]) -> LogOptions:
    """The options of ``replay://`` URL query keys columns, units, time_unit, rate."""
    opts = LogOptions()
    if "columns" in query:
        opts.columns = parse_columns(query["columns"], "replay://?columns")
    if "units" in query:
        opts.units = parse_units(query["units"], "replay://?units")
    if "time_unit" in query:
        opts.time_unit = parse_time_unit(query["time_unit"], "replay://?time_unit")
    if "rate" in query:
        opts.rate = parse_rate(query["rate"], "replay://?rate")
    if "variable" in query:
        opts.variable = query["variable"]
    if "topic" in query:
        opts.topic = query["topic"]
    if "instance" in query:
        opts.instance = parse_instance(query["instance"], "replay://?instance")
    if "ros_distro" in query:
        opts.ros_distro = parse_ros_distro(query["ros_distro"], "replay://?ros_distro")
    return opts


def units_from_meta(meta: dict[str, Any]) -> dict[str, str]:
    """A log's ``units`` metadata (``gyro=deg/s accel=g`` or a JSON object) as a dict.

    Empty when absent or not in the known units (then nothing is assumed).
    """
    value = meta.get("units")
    if value is None:
        return {}
    if isinstance(value, dict):
        value = ",".join(f"{k}={v}" for k, v in value.items())
    try:
        return parse_units(str(value), "metadata units")
    except BadInput:
        return {}


#: The replay:// query keys these options add.
URL_KEYS = (
    "columns", "units", "time_unit", "rate", "variable", "instance", "topic", "ros_distro",
)  # fmt: skip

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

Each format lives in a module of its own (``csv_format``, ``npz_format``,
``wire_capture``, ``matlab``, ``rdata_format``, ...; docs/logs.md lists them) and is
found through :mod:`imudiag.logs.registry`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..samples import SampleBlock
from .base import (
    DEFAULT_BLOCK_SIZE,
    OPTIONAL_COLUMNS,
    REQUIRED_COLUMNS,
    LogError,
    LogReader,
    LogWriter,
)
from .csv_format import CsvReader, CsvWriter
from .dataflash import DataFlashReader, is_dataflash
from .matlab import MatReader
from .npz_format import NpzReader, NpzWriter
from .options import LogOptions
from .rdata_format import RDataReader
from .registry import FORMATS, LogFormat, formats, log_format, lookup, register_format
from .rosbag import RosbagReader, is_bag_directory, is_ros1_bag
from .text_table import TextTableReader
from .ulog import ULogReader, is_ulog
from .wire_capture import BinReader, BinWriter

# bytes_per_sample: measured on imudiag simulate sessions (t, six outputs, temp, seq, flags)
register_format(
    LogFormat(".csv", (".csv",), CsvReader, CsvWriter, description="CSV table", bytes_per_sample=70)
)
register_format(
    LogFormat(
        ".csv.gz",
        (".csv.gz",),
        CsvReader,
        CsvWriter,
        description="gzip-compressed CSV table",
        bytes_per_sample=16,
    )
)
register_format(
    LogFormat(
        ".npz", (".npz",), NpzReader, NpzWriter, description="NumPy arrays", bytes_per_sample=74
    )
)
register_format(
    LogFormat(
        ".bin",
        (".bin",),
        BinReader,
        BinWriter,
        description="raw wire capture (spec/wire-protocol.md)",
        bytes_per_sample=40,
    )
)

register_format(
    LogFormat(
        "dataflash",
        (".bin",),
        DataFlashReader,
        magic=is_dataflash,
        description="ArduPilot DataFlash log (IMU messages; --instance)",
        takes_options=True,
        chooser="instance",
        extra="ardupilot",
    )
)
register_format(
    LogFormat(
        "text",
        (".txt", ".tsv", ".dat", ".txt.gz", ".tsv.gz", ".dat.gz"),
        TextTableReader,
        description="text table (comma, semicolon, tab or whitespace; --columns, --rate)",
        takes_options=True,
    )
)
register_format(
    LogFormat(
        ".ulg",
        (".ulg",),
        ULogReader,
        magic=is_ulog,
        description="PX4 ULog flight log (sensor_combined, or sensor_gyro/sensor_accel with "
        "--instance)",
        takes_options=True,
        chooser="instance",
        extra="px4",
    )
)
register_format(
    LogFormat(
        "rosbag2",
        (".db3", ".mcap"),
        RosbagReader,
        description="ROS 2 bag: a bag directory (metadata.yaml) or one .db3 / .mcap file "
        "(sensor_msgs/msg/Imu; --topic)",
        takes_options=True,
        chooser="topic",
        extra="ros",
        directory=is_bag_directory,
    )
)
register_format(
    LogFormat(
        "rosbag1",
        (".bag",),
        RosbagReader,
        magic=is_ros1_bag,
        description="ROS 1 bag (sensor_msgs/msg/Imu; --topic)",
        takes_options=True,
        chooser="topic",
        extra="ros",
    )
)
register_format(
    LogFormat(
        ".mat",
        (".mat",),
        MatReader,
        description="MATLAB matrix (v5 via scipy, v7.3 via h5py; --variable, --columns)",
        takes_options=True,
        chooser="variable",
        extra="mat",
    )
)
register_format(
    LogFormat(
        "rdata",
        (".rda", ".rdata", ".rds"),
        RDataReader,
        description="R data.frame or matrix (.rda/.RData from save, .rds from saveRDS; "
        "--variable, --columns)",
        takes_options=True,
        chooser="variable",
        extra="r",
    )
)


#: Log options that choose the samples within a file; each applies to some formats only.
CHOOSERS = ("variable", "topic", "instance")


def open_log(
    path: str | Path, block_size: int = DEFAULT_BLOCK_SIZE, options: LogOptions | None = None
) -> LogReader:
    """Open a sample log for streaming (format from the file name and magic bytes).

    The header and metadata are read and checked now; the samples as the
    reader is iterated, in blocks of at most ``block_size`` samples. ``options``
    (column names, units, time unit, rate) say how to read a text table; a
    ``.csv`` is read as a text table when they are given or when its header is
    not the spec's. Raises :class:`LogError` for an unreadable file or a rule
    violation.
    """
    fmt = lookup(path)
    for opt in CHOOSERS:
        if options is not None and getattr(options, opt) is not None and fmt.chooser != opt:
            raise LogError(str(path), f"--{opt} does not apply to {fmt.name} logs")
    if options is not None and options.ros_distro and fmt.name not in ("rosbag1", "rosbag2"):
        raise LogError(str(path), f"--ros-distro does not apply to {fmt.name} logs")
    table = options is not None and bool(options.columns or options.time_unit)
    if fmt.name in (".csv", ".csv.gz") and table:
        reader: LogReader = TextTableReader(path, block_size, options=options)
    elif fmt.name in (".csv", ".csv.gz"):
        try:
            reader = fmt.open_reader(path, block_size)
        except LogError as exc:
            if not exc.reason.startswith("missing column"):
                raise
            try:  # a user's own table: other column names, or no header
                reader = TextTableReader(path, block_size, options=options)
            except LogError as text_exc:
                hint = "name the columns with --columns (e.g. t,gx,gy,gz,ax,ay,az; _ skips one)"
                if "--columns" in text_exc.reason or "--rate" in text_exc.reason:
                    raise LogError(exc.path, f"{exc.reason}; {hint}", exc.line) from None
                raise text_exc from None
    else:
        if table and not fmt.takes_options:
            raise LogError(str(path), f"--columns and --time-unit do not apply to {fmt.name} logs")
        reader = fmt.open_reader(path, block_size, options)
    if options is not None and options.units:
        reader.meta["units"] = dict(options.units)
    return reader


def read_log(path: str | Path) -> SampleBlock:
    """The whole log as one block (convenience for logs that fit in memory)."""
    with open_log(path) as reader:
        block = SampleBlock.concat(list(reader))
        block.meta = reader.meta
        return block


def open_writer(path: str | Path, meta: dict[str, Any] | None = None) -> LogWriter:
    """A writer for a new log at ``path`` (format from the name), with metadata ``meta``."""
    return lookup(path).open_writer(path, meta)


def write_log(path: str | Path, block: SampleBlock, meta: dict[str, Any] | None = None) -> None:
    """Write one block as a whole log (convenience)."""
    with open_writer(path, block.meta if meta is None else meta) as writer:
        writer.write(block)


__all__ = [
    "DEFAULT_BLOCK_SIZE",
    "FORMATS",
    "LogError",
    "LogFormat",
    "LogOptions",
    "TextTableReader",
    "BinReader",
    "BinWriter",
    "CsvReader",
    "CsvWriter",
    "NpzReader",
    "NpzWriter",
    "RDataReader",
    "formats",
    "lookup",
    "register_format",
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

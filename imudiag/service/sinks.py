"""Status sinks chosen by the configuration: JSON lines on stdout, NMEA on a serial URL."""

from __future__ import annotations

import sys
from typing import Any

from ..errors import BadInput
from .config import DaemonConfig
from .nmea import SerialStatusSink, StatusLinkError
from .status import JsonLinesSink


def make_sinks(config: DaemonConfig) -> list[Any]:
    """The sinks of ``config``; a serial status URL that cannot be opened is bad input."""
    sinks: list[Any] = []
    if config.status_stdout:
        sinks.append(JsonLinesSink(sys.stdout))
    if config.status_serial:
        try:
            sinks.append(
                SerialStatusSink(
                    config.status_serial,
                    rate_hz=config.nmea_rate_hz,
                    queue_size=config.nmea_queue,
                    write_timeout_s=config.nmea_write_timeout_s,
                )
            )
        except (StatusLinkError, ValueError) as exc:
            raise BadInput(f"status.serial {config.status_serial!r}: {exc}") from None
    for sink in sinks[1:] if config.status_stdout else sinks:
        sink.self_paced = True  # the NMEA sink rate-limits itself and reacts to changes
    return sinks

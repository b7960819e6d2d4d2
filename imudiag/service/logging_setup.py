"""Journald-friendly logging for the daemon.

Log records go to standard error as plain lines. Under systemd, when
``JOURNAL_STREAM`` names the device and inode of our standard error (systemd
sets it when stderr is connected to the journal), each line starts with the
syslog priority in angle brackets (``<3>`` error, ``<4>`` warning, ``<6>``
info, ``<7>`` debug; sd-daemon(3)) and carries no timestamp, since the journal
stamps every entry; every line of a multi-line record (a traceback) gets the
prefix, so none of them falls back to the default priority. Elsewhere the
lines carry a timestamp and the level name. Standard output stays free for
the JSON status stream.
"""

from __future__ import annotations

import logging
import os
import sys
from collections.abc import Mapping
from typing import TextIO

#: Python level -> syslog priority (sd-daemon(3) prefixes).
SYSLOG_PRIORITY = {
    logging.CRITICAL: 2,
    logging.ERROR: 3,
    logging.WARNING: 4,
    logging.INFO: 6,
    logging.DEBUG: 7,
}


def syslog_priority(levelno: int) -> int:
    """The syslog priority (0 emerg .. 7 debug) for a Python log level."""
    for level in sorted(SYSLOG_PRIORITY, reverse=True):
        if levelno >= level:
            return SYSLOG_PRIORITY[level]
    return 7


def stream_is_journal(stream: TextIO, environ: Mapping[str, str] | None = None) -> bool:
    """True when ``JOURNAL_STREAM`` (``device:inode``) matches the file behind ``stream``."""
    env = os.environ if environ is None else environ
    value = env.get("JOURNAL_STREAM", "")
    try:
        dev_text, ino_text = value.split(":")
        dev, ino = int(dev_text), int(ino_text)
        st = os.fstat(stream.fileno())
    except (ValueError, OSError, AttributeError):
        return False
    return st.st_dev == dev and st.st_ino == ino


class JournalFormatter(logging.Formatter):
    """``<priority>logger: message`` on every line of the record, no timestamp."""

    def __init__(self) -> None:
        super().__init__("%(name)s: %(message)s")

    def format(self, record: logging.LogRecord) -> str:
        prefix = f"<{syslog_priority(record.levelno)}>"
        text = super().format(record)
        return "\n".join(prefix + line for line in text.splitlines() or [""])


class ConsoleFormatter(logging.Formatter):
    """``2026-01-01 12:00:00,000 WARNING logger: message`` for a terminal or a file."""

    def __init__(self) -> None:
        super().__init__("%(asctime)s %(levelname)s %(name)s: %(message)s")


def setup_logging(
    level: str | int = "info",
    stream: TextIO | None = None,
    journal: bool | None = None,
    environ: Mapping[str, str] | None = None,
) -> logging.Handler:
    """Log to ``stream`` (default stderr): ``imudiag.*`` from ``level``, other libraries
    from WARNING (or ``level`` if higher), through one handler on the root logger.

    ``journal`` forces the journald format on or off; ``None`` decides from
    ``JOURNAL_STREAM``. Calling it again (a reload) replaces the previous
    handler. Returns the installed handler.
    """
    stream = sys.stderr if stream is None else stream
    if journal is None:
        journal = stream_is_journal(stream, environ)
    if isinstance(level, str):
        numeric = logging.getLevelName(level.upper())
        if not isinstance(numeric, int):
            raise ValueError(f"unknown log level {level!r}")
        level = numeric
    handler = logging.StreamHandler(stream)
    handler.setFormatter(JournalFormatter() if journal else ConsoleFormatter())
    handler._imudiag = True  # type: ignore[attr-defined]  # marks ours for replacement
    root = logging.getLogger()
    for old in [h for h in root.handlers if getattr(h, "_imudiag", False)]:
        root.removeHandler(old)
    root.addHandler(handler)
    # other libraries (pyserial, pyusb, ...) speak from WARNING up; ours from ``level``
    root.setLevel(max(level, logging.WARNING))
    ours = logging.getLogger("imudiag")
    ours.setLevel(level)
    ours.propagate = True
    return handler


__all__ = [
    "ConsoleFormatter",
    "JournalFormatter",
    "SYSLOG_PRIORITY",
    "setup_logging",
    "stream_is_journal",
    "syslog_priority",
]

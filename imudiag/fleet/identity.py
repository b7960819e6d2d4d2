"""Who recorded a log and when: the vehicle's identity and the log's start time, read from
the log itself where its format says them, else the folder the log sits in (said so)."""

from __future__ import annotations

import datetime as dt
import math
import re
from pathlib import Path
from typing import Any

#: Metadata keys of a CSV / NPZ / capture log that name the vehicle, in the order tried.
VEHICLE_KEYS = ("vehicle", "vehicle_id", "serial", "device_serial", "sys_uuid")
#: Metadata keys that give the log's start (ISO 8601 text, or Unix seconds).
START_KEYS = ("start", "start_time", "start_utc")
#: Sample times above this many seconds are taken as UTC Unix time (2001-09-09 on).
UNIX_TIME_MIN_S = 1.0e9
#: DataFlash messages read at most while looking for the board's identity.
DATAFLASH_SCAN = 200_000
#: ArduPilot's board-id text message: board name and three 32-bit words of the MCU's UID.
_BOARD_UID = re.compile(r"^(\S+) ([0-9A-Fa-f]{8}) ([0-9A-Fa-f]{8}) ([0-9A-Fa-f]{8})$")


def iso(t_unix_s: float) -> str:
    """UTC Unix seconds as ISO 8601 text with its offset."""
    return dt.datetime.fromtimestamp(t_unix_s, dt.UTC).isoformat()


def parse_start(value: Any) -> str | None:
    """A metadata start value (ISO 8601 text or Unix seconds) as ISO 8601 UTC, else None."""
    if isinstance(value, int | float) and value > UNIX_TIME_MIN_S:
        return iso(float(value))
    if isinstance(value, str):
        try:
            when = dt.datetime.fromisoformat(value.replace("Z", "+00:00"))
        except ValueError:
            return None
        if when.tzinfo is None:
            when = when.replace(tzinfo=dt.UTC)
        return when.astimezone(dt.UTC).isoformat()
    return None


def _ulog(path: Path) -> tuple[str | None, str, str | None]:
    from pyulog import ULog  # the px4 extra, present when the log could be read

    info = ULog(str(path), message_name_filter_list=[]).msg_info_dict
    start = None
    ref = info.get("time_ref_utc")
    if isinstance(ref, int | float) and ref > UNIX_TIME_MIN_S:
        start = iso(float(ref))
    for key in ("sys_uuid", "hw_serial", "ver_hw_serial"):
        if info.get(key):
            return str(info[key]), f"ulog {key}", start
    return None, "", start


def _dataflash(path: Path) -> tuple[str | None, str]:
    from pymavlink import mavutil  # the ardupilot extra, present when the log could be read

    conn = mavutil.mavlink_connection(str(path))
    serial, uid = None, None
    try:
        for _ in range(DATAFLASH_SCAN):
            msg = conn.recv_match(type=["PARM", "MSG"])
            if msg is None:
                break
            d = msg.to_dict()
            if msg.get_type() == "PARM" and d.get("Name") == "BRD_SERIAL_NUM" and d.get("Value"):
                serial = str(int(d["Value"]))
            elif msg.get_type() == "MSG" and uid is None:
                m = _BOARD_UID.match(str(d.get("Message", "")).strip())
                if m:
                    uid = f"{m[1]}-{m[2]}{m[3]}{m[4]}"
    finally:
        conn.close()
    if serial:
        return serial, "dataflash PARM BRD_SERIAL_NUM"
    if uid:
        return uid, "dataflash board id message"
    return None, ""


#: ``start_source`` of a start read from the clock tie of the log's own GNSS.
GNSS_CLOCK_START = "the log's GNSS time (the diagnosis's clock tie at the first sample)"


def start_from_gnss_clock(report: dict[str, Any], t0_s: float | None) -> str | None:
    """The log's start (ISO 8601 UTC) from the clock tie of its GNSS in a diagnosis report
    (``moving_base.gnss.clock``: UTC Unix s = ``offset_s`` + ``rate`` x log time, s) at
    the first sample time ``t0_s`` (s, the log's clock), or None without a tie."""
    clock = ((report.get("moving_base") or {}).get("gnss") or {}).get("clock") or {}
    offset, rate = clock.get("offset_s"), clock.get("rate")
    if t0_s is None or not isinstance(offset, int | float) or not isinstance(rate, int | float):
        return None
    t_utc = float(offset) + float(rate) * t0_s
    return iso(t_utc) if math.isfinite(t_utc) and t_utc > UNIX_TIME_MIN_S else None


def folder_vehicle(path: str | Path) -> str:
    """The vehicle of a log that does not name one: the folder it sits in."""
    return Path(path).absolute().parent.name or "/"


def identify(
    path: str | Path, fmt: str, meta: dict[str, Any], t0_s: float | None
) -> dict[str, str | None]:
    """``vehicle``, ``vehicle_source``, ``start`` (ISO 8601 UTC or None) and ``start_source``
    of a log of format ``fmt`` with metadata ``meta`` and first sample time ``t0_s`` (s)."""
    p = Path(path)
    vehicle, source, start, start_source = None, "", None, None
    for key in VEHICLE_KEYS:
        if meta.get(key) not in (None, ""):
            vehicle, source = str(meta[key]), f"log metadata {key!r}"
            break
    if vehicle is None and fmt == ".ulg":
        vehicle, source, start = _ulog(p)
        start_source = "ulog time_ref_utc" if start else None
    elif vehicle is None and fmt == "dataflash":
        vehicle, source = _dataflash(p)
    for key in START_KEYS:
        if start is None and parse_start(meta.get(key)):
            start, start_source = parse_start(meta.get(key)), f"log metadata {key!r}"
    if start is None and t0_s is not None and t0_s > UNIX_TIME_MIN_S:
        start, start_source = iso(t0_s), "first sample time (UTC Unix seconds)"
    if vehicle is None:
        vehicle, source = folder_vehicle(p), "folder name (the log names no vehicle)"
    return {
        "vehicle": vehicle,
        "vehicle_source": source,
        "start": start,
        "start_source": start_source,
    }


__all__ = [
    "GNSS_CLOCK_START",
    "folder_vehicle",
    "identify",
    "iso",
    "parse_start",
    "start_from_gnss_clock",
]

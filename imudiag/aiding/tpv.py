"""gpsd TPV reports: one JSON object a line, every object tagged with ``class``.

A ``gpspipe -w`` log (what gpsd users record) holds VERSION, DEVICES, WATCH,
SKY and TPV objects; only TPV (time-position-velocity) matters here. Fields
used (gpsd JSON, proto 3.x): ``time`` (ISO 8601 UTC), ``mode`` (0/1 no fix,
2 2D, 3 3D), ``status``, ``lat``/``lon`` (deg), ``altHAE`` (m above the
ellipsoid; ``alt`` or ``altMSL`` + ``geoidSep`` as fallbacks), ``velN``,
``velE``, ``velD`` (m/s; ``-climb`` when velD is absent; ``speed``/``track``
when velN/velE are absent), ``eps`` (speed error, m/s), ``epc`` (climb error, m/s).
"""

from __future__ import annotations

import gzip
import json
import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import BadInput


@dataclass
class GnssTrack:
    """GNSS epochs in time order.

    t (K,) s UTC Unix; mode (K,) int; status (K,) int (0 unknown); lat_deg,
    lon_deg (K,) deg; alt_m (K,) m ellipsoidal (nan unknown); vel_ned (K, 3)
    m/s (nan unknown); eps, epc (K,) m/s (nan unknown); device: the gpsd path.
    """

    t: np.ndarray
    mode: np.ndarray
    status: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    alt_m: np.ndarray
    vel_ned: np.ndarray
    eps: np.ndarray
    epc: np.ndarray
    device: str = ""
    meta: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.t.shape[0])

    def period_s(self) -> float:
        """Median epoch period, s (nan with fewer than two epochs)."""
        if len(self) < 2:
            return float("nan")
        return float(np.median(np.diff(self.t)))


def _num(obj: dict, key: str) -> float:
    v = obj.get(key)
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return math.nan
    return float(v)


def parse_time(value: object) -> float:
    """gpsd ``time`` (ISO 8601 string, or seconds in old protocol versions) to Unix s."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return float(value)
    if not isinstance(value, str):
        raise ValueError(f"time is {value!r}, not an ISO 8601 string")
    return datetime.fromisoformat(value.replace("Z", "+00:00")).timestamp()


def parse_tpv(obj: dict) -> dict | None:
    """One TPV object as a flat dict of floats, or None when it has no time."""
    if obj.get("class") != "TPV" or "time" not in obj:
        return None
    t = parse_time(obj["time"])
    vn, ve = _num(obj, "velN"), _num(obj, "velE")
    if math.isnan(vn) or math.isnan(ve):
        speed, track = _num(obj, "speed"), _num(obj, "track")
        if not (math.isnan(speed) or math.isnan(track)):
            vn = speed * math.cos(math.radians(track))
            ve = speed * math.sin(math.radians(track))
    vd = _num(obj, "velD")
    if math.isnan(vd):
        vd = -_num(obj, "climb")
    alt = _num(obj, "altHAE")
    if math.isnan(alt):
        alt = _num(obj, "alt")
    if math.isnan(alt):
        alt = _num(obj, "altMSL") + _num(obj, "geoidSep")
    mode = obj.get("mode", 0)
    status = obj.get("status", 0)
    return {
        "t": t,
        "mode": int(mode) if isinstance(mode, int) else 0,
        "status": int(status) if isinstance(status, int) else 0,
        "lat": _num(obj, "lat"),
        "lon": _num(obj, "lon"),
        "alt": alt,
        "vn": vn,
        "ve": ve,
        "vd": vd,
        "eps": _num(obj, "eps"),
        "epc": _num(obj, "epc"),
        "device": str(obj.get("device", "")),
    }


def track_from_reports(reports: Iterable[dict], device: str | None = None) -> GnssTrack:
    """A track from parsed TPV dicts (:func:`parse_tpv`), sorted by time; several
    reports with one time are merged, later values winning over earlier ones.

    ``device``: keep only that gpsd device (default: the first device seen).
    """
    rows = [r for r in reports if r is not None]
    if device is None and rows:
        device = rows[0]["device"]
    rows = [r for r in rows if device is None or r["device"] == device]
    rows.sort(key=lambda r: r["t"])  # stable: reports of one time keep their order
    dedup: list[dict] = []
    for r in rows:
        if dedup and r["t"] <= dedup[-1]["t"]:
            # gpsd may report an epoch twice (u-blox NAV-PVT, then NAV-VELNED with the
            # epoch's velocity): later values win, but a missing value does not erase one
            merged = dict(dedup[-1])
            for k, v in r.items():
                if not (isinstance(v, float) and math.isnan(v)):
                    merged[k] = v
            dedup[-1] = merged
            continue
        dedup.append(r)

    def col(key: str, dtype: type = float) -> np.ndarray:
        return np.array([r[key] for r in dedup], dtype=dtype)

    return GnssTrack(
        t=col("t"),
        mode=col("mode", int),
        status=col("status", int),
        lat_deg=col("lat"),
        lon_deg=col("lon"),
        alt_m=col("alt"),
        vel_ned=np.stack([col("vn"), col("ve"), col("vd")], 1) if dedup else np.zeros((0, 3)),
        eps=col("eps"),
        epc=col("epc"),
        device=device or "",
    )


def track_from_stream(
    objects: Iterable[dict | str | bytes], device: str | None = None, source: str = "gnss"
) -> GnssTrack:
    """A track from gpsd's JSON stream (``gpspipe -w``, a gpsd socket's lines): each item
    one object, parsed (a dict) or its line of text; objects of other classes (SKY,
    VERSION...) are ignored. :class:`BadInput` naming ``source`` and the item's number for
    an item that is not a gpsd object, and when no TPV report has a time."""
    reports: list[dict] = []
    for i, item in enumerate(objects, start=1):
        obj: Any = item
        if isinstance(item, (str, bytes)):
            text = item.strip()
            if not text:
                continue
            try:
                obj = json.loads(text)
            except json.JSONDecodeError as exc:
                raise BadInput(f"{source}:{i}: not a gpsd JSON object: {exc.msg}") from exc
        if not isinstance(obj, dict) or "class" not in obj:
            raise BadInput(f'{source}:{i}: not a gpsd JSON object (no "class" key)')
        try:
            r = parse_tpv(obj)
        except ValueError as exc:
            raise BadInput(f"{source}:{i}: bad TPV: {exc}") from exc
        if r is not None:
            reports.append(r)
    track = track_from_reports(reports, device)
    if len(track) == 0:
        raise BadInput(f"{source}: no TPV report with a time in the GNSS stream")
    return track


def read_gpspipe_log(path: str | Path, device: str | None = None) -> GnssTrack:
    """Read a ``gpspipe -w`` log (plain or .gz) into a track (:func:`track_from_stream`).

    Lines that are not JSON objects stop the read with :class:`BadInput`
    naming the file and line (a truncated last line is skipped: a recording
    cut off mid-write). Objects of other classes are ignored.
    """
    p = Path(path)
    try:
        opener = gzip.open if p.suffix == ".gz" else open
        with opener(p, "rt", encoding="utf-8") as fh:
            lines = fh.read().splitlines()
    except (OSError, UnicodeDecodeError, EOFError) as exc:
        raise BadInput(f"{p}: cannot read the GNSS log: {exc}") from exc
    if lines:
        try:
            json.loads(lines[-1]) if lines[-1].strip() else None
        except json.JSONDecodeError:
            lines[-1] = ""  # cut off mid-write
    return track_from_stream(lines, device, str(p))


__all__ = [
    "GnssTrack",
    "parse_time",
    "parse_tpv",
    "read_gpspipe_log",
    "track_from_reports",
    "track_from_stream",
]

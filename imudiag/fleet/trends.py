"""Per vehicle: each parameter's estimates over its logs, the drift test, the first log
beyond the limit, and the ranked list of units to look at (``DIR/fleet.json``,
docs/fleet.md)."""

from __future__ import annotations

import datetime as dt
import math
from collections import defaultdict
from typing import Any

import numpy as np

from ..diagnosis.config import DiagnosisConfig
from ..reports import FLEET_FORMAT, header

#: A drift is significant when its slope is at least this many of its std (two-sided,
#: about 6e-5 by chance per parameter under Gaussian errors).
DRIFT_Z = 4.0
#: A significant drift names a unit only when, carried on for as many logs again as the
#: vehicle has, it reaches the limit: drifting *toward* the limit, not merely measurable.
HORIZON_LOGS_FACTOR = 1.0
#: Logs a parameter needs before its slope is tested.
MIN_LOGS = 3
SECONDS_PER_DAY = 86400.0
#: A log's estimate is beyond its limit when it deviates from the certificate by more than
#: the limit and by more than this many of its std: the diagnosis's own rule for a
#: candidate fault (DiagnosisConfig.k_sigma), applied to the log's best-determined window.
K_SIGMA = DiagnosisConfig().k_sigma


def _days(start: str | None) -> float | None:
    if not start:
        return None
    return dt.datetime.fromisoformat(start).timestamp() / SECONDS_PER_DAY


def weighted_slope(x: np.ndarray, y: np.ndarray, std: np.ndarray) -> tuple[float, float, float]:
    """Weighted least-squares line through ``(x, y)`` with per-point ``std``: its slope, the
    slope's std (scaled up by the root of the reduced chi-square when above 1, so scatter
    the stds do not explain makes no drift) and the fitted value at the last ``x``."""
    w = 1.0 / np.square(std)
    xm = np.sum(w * x) / np.sum(w)
    ym = np.sum(w * y) / np.sum(w)
    sxx = np.sum(w * np.square(x - xm))
    if not sxx > 0:
        return math.nan, math.nan, math.nan
    slope = float(np.sum(w * (x - xm) * (y - ym)) / sxx)
    resid = y - (ym + slope * (x - xm))
    dof = len(x) - 2
    chi2 = float(np.sum(w * np.square(resid)) / dof) if dof > 0 else 1.0
    slope_std = math.sqrt(max(1.0, chi2) / sxx)
    return slope, slope_std, float(ym + slope * (x[-1] - xm))


def _order(records: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """A vehicle's logs in time order (start, then path; logs without a start last)."""
    return sorted(records, key=lambda r: (r.get("start") is None, r.get("start") or "", r["path"]))


#: A parameter of a vehicle: (IMU instance or None, triad, sensor, cause).
Key = tuple[int | None, str, str, str]


def label(item: dict[str, Any]) -> str:
    """A trend's or reason's parameter in words: ``IMU 1 gyro gx scale_factor`` (``accel ax
    bias`` for the one IMU stream of a log, instance None)."""
    words = f"{item['triad']} {item['sensor']} {item['cause']}"
    return words if item.get("instance") is None else f"IMU {item['instance']} {words}"


def key_of(item: dict[str, Any]) -> Key:
    """A trend's or reason's :data:`Key`."""
    return (item.get("instance"), item["triad"], item["sensor"], item["cause"])


def _imus(record: dict[str, Any]) -> list[tuple[int | None, list[dict[str, Any]], dict]]:
    """(instance, parameters, report) of each IMU a record diagnosed: the log's own report
    (instance None for a log of one IMU stream) and each other instance diagnosed."""
    out = [(record.get("instance"), record.get("parameters") or [], record.get("report") or {})]
    for item in record.get("instances") or []:
        if item.get("status") == "ok":
            out.append((item["instance"], item.get("parameters") or [], item.get("report") or {}))
    return out


def _faulted(record: dict[str, Any]) -> set[Key]:
    return {
        (instance, f["triad"], f["sensor"], f["cause"])
        for instance, _, report in _imus(record)
        for f in (report.get("verdict") or {}).get("faults") or []
        if f.get("cause") != "f0"
    }


def parameter_trend(logs: list[dict[str, Any]], key: Key) -> dict[str, Any]:
    """The trend of parameter ``key`` (IMU instance, triad, sensor, cause) over a vehicle's
    ordered ``logs``: its points (estimate and std per log), slope and slope std per log
    and per day, significance, and the first log whose diagnosis found it beyond its
    limit."""
    instance, triad, sensor, cause = key
    points: list[dict[str, Any]] = []
    crosses = None
    n_beyond = 0
    for index, rec in enumerate(logs):
        beyond = key in _faulted(rec)
        for p in (p for i, params, _ in _imus(rec) if i == instance for p in params):
            if (p["triad"], p["sensor"], p["cause"]) == key[1:]:
                dev = abs(p["estimate"] - p["certificate"])
                beyond = beyond or (dev > p["limit"] and dev > K_SIGMA * p["std"])
                points.append(
                    {
                        "index": index,
                        "path": rec["path"],
                        "start": rec.get("start"),
                        "estimate": p["estimate"],
                        "std": p["std"],
                        "deviation": p["estimate"] - p["certificate"],
                        "certificate": p["certificate"],
                        "limit": p["limit"],
                        "unit": p["unit"],
                    }
                )
        n_beyond += beyond
        if crosses is None and beyond:
            crosses = {"path": rec["path"], "index": index, "start": rec.get("start")}
    out: dict[str, Any] = {
        "instance": instance,
        "triad": triad,
        "sensor": sensor,
        "cause": cause,
        "unit": points[0]["unit"] if points else None,
        "limit": points[-1]["limit"] if points else None,
        "points": points,
        "slope_per_log": None,
        "slope_std_per_log": None,
        "slope_per_day": None,
        "slope_std_per_day": None,
        "significance": None,
        "deviation_last": None,
        "crosses_limit": crosses["path"] if crosses else None,
        "crosses_limit_index": crosses["index"] if crosses else None,
        "logs_beyond": n_beyond,
        "drifting": False,
    }
    if len(points) < MIN_LOGS:
        return out
    y = np.array([p["deviation"] for p in points])
    s = np.array([p["std"] for p in points])
    slope, slope_std, last = weighted_slope(np.array([float(p["index"]) for p in points]), y, s)
    if not math.isfinite(slope):
        return out
    out.update(
        slope_per_log=slope,
        slope_std_per_log=slope_std,
        significance=abs(slope) / slope_std,
        deviation_last=last,
    )
    days = [_days(p["start"]) for p in points]
    if all(d is not None for d in days):
        x = np.array(days, dtype=float)
        sd, sd_std, _ = weighted_slope(x - x[0], y, s)
        if math.isfinite(sd):
            out.update(slope_per_day=sd, slope_std_per_day=sd_std)
    horizon = HORIZON_LOGS_FACTOR * len(logs)
    limit = float(out["limit"])
    out["drifting"] = bool(
        abs(slope) >= DRIFT_Z * slope_std and abs(last + slope * horizon) >= limit
    )
    return out


def _reason(trend: dict[str, Any], n_logs: int) -> dict[str, Any]:
    unit = trend["unit"]
    keys = (
        "instance",
        "triad",
        "sensor",
        "cause",
        "slope_per_log",
        "slope_std_per_log",
        "slope_per_day",
        "slope_std_per_day",
        "significance",
        "unit",
        "limit",
        "deviation_last",
        "crosses_limit",
        "crosses_limit_index",
        "logs_beyond",
    )
    r = {k: trend[k] for k in keys if not k.startswith("slope")}
    r["slope"] = {"per_log": trend["slope_per_log"], "per_day": trend["slope_per_day"]}
    r["slope_std"] = {"per_log": trend["slope_std_per_log"], "per_day": trend["slope_std_per_day"]}
    words = []
    if trend["crosses_limit"] is not None:
        k, path = trend["crosses_limit_index"] + 1, trend["crosses_limit"]
        where = f"from log {k} of {n_logs} ({path}), in {trend['logs_beyond']} of the {n_logs}"
        if trend["limit"] is None:  # a fault with no parameter estimate (noise, stuck...)
            words.append(f"raised as a fault {where}")
        else:
            words.append(f"beyond its limit ({trend['limit']:.4g} {unit}) {where}")
    if trend["drifting"]:
        words.append(
            f"drifting {trend['slope_per_log']:+.4g} {unit} per log "
            f"({trend['significance']:.1f} std), now {trend['deviation_last']:+.4g} {unit} "
            f"from the certificate, limit {trend['limit']:.4g} {unit}"
        )
    r["why"] = "; ".join(words)
    used = 0.0
    if trend["deviation_last"] is not None and trend["limit"]:
        used = abs(trend["deviation_last"]) / trend["limit"]
    r["limit_used"] = used
    return r


def vehicle_summary(vehicle: str, records: list[dict[str, Any]]) -> dict[str, Any]:
    """One vehicle of ``fleet.json``: its logs, trends, reasons and whether to look at it."""
    ok = _order([r for r in records if r.get("status") == "ok"])
    keys: list[Key] = []
    for rec in ok:
        for instance, params, _ in _imus(rec):
            for p in params:
                k = (instance, p["triad"], p["sensor"], p["cause"])
                if k not in keys:
                    keys.append(k)
        for k in sorted(
            _faulted(rec), key=lambda k: (k[0] is not None, k[0] or 0, *map(str, k[1:]))
        ):
            if k not in keys:
                keys.append(k)
    trends = [parameter_trend(ok, k) for k in keys]
    reasons = [
        _reason(t, len(ok)) for t in trends if t["drifting"] or t["crosses_limit"] is not None
    ]
    reasons.sort(key=lambda r: (r["crosses_limit"] is None, -r["limit_used"]))
    score = max(
        (r["limit_used"] + (1.0 if r["crosses_limit"] else 0.0) for r in reasons), default=0.0
    )
    return {
        "vehicle": vehicle,
        "logs": len(records),
        "logs_ok": len(ok),
        "errors": len(records) - len(ok),
        "first": ok[0].get("start") if ok else None,
        "last": ok[-1].get("start") if ok else None,
        "look_at": bool(reasons),
        "score": score,
        "reasons": reasons,
        "trends": trends,
    }


def attach_unreadable(records: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The records with each log that could not say its vehicle (known by its folder) given
    the vehicle the other logs of its folder name, when they all name the same one."""
    from pathlib import Path

    named: dict[str, set[str]] = defaultdict(set)
    for r in records:
        if r.get("status") == "ok":
            named[str(Path(r["path"]).parent)].add(str(r["vehicle"]))
    out = []
    for r in records:
        names = named.get(str(Path(r["path"]).parent), set())
        if r.get("status") != "ok" and len(names) == 1 and r.get("vehicle") not in names:
            r = {
                **r,
                "vehicle": next(iter(names)),
                "vehicle_source": "the other logs of its folder name this vehicle",
            }
        out.append(r)
    return out


def error_kinds(errors: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The failed logs grouped by their reason with the log's own path said as ``LOG``
    (a folder of logs in SI units against a certificate in counts is one kind): each
    ``reason``, its number of ``logs`` and the ``first`` log's path, most logs first."""
    kinds: dict[str, dict[str, Any]] = {}
    for e in errors:
        reason = str(e.get("reason") or "unknown").replace(str(e["path"]), "LOG")
        kind = kinds.setdefault(reason, {"reason": reason, "logs": 0, "first": e["path"]})
        kind["logs"] += 1
    return sorted(kinds.values(), key=lambda k: -k["logs"])


def summarize(records: list[dict[str, Any]]) -> dict[str, Any]:
    """``fleet.json`` from the per-log records (docs/fleet.md): always rebuilt whole."""
    by_vehicle: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for r in attach_unreadable(records):
        by_vehicle[str(r.get("vehicle"))].append(r)
    vehicles = [vehicle_summary(v, rs) for v, rs in by_vehicle.items()]
    vehicles.sort(key=lambda v: (not v["look_at"], -v["score"], v["vehicle"]))
    errors = [  # by path: the same summary whatever order the logs completed in
        {"path": r["path"], "vehicle": r.get("vehicle"), "reason": r.get("reason")}
        for r in sorted(attach_unreadable(records), key=lambda r: str(r["path"]))
        if r.get("status") != "ok"
    ]
    return {
        **header(FLEET_FORMAT),
        "logs": len(records),
        "ok": len(records) - len(errors),
        "errors": errors,
        "error_kinds": error_kinds(errors),
        "look_at": [v["vehicle"] for v in vehicles if v["look_at"]],
        "drift_z": DRIFT_Z,
        "vehicles": vehicles,
    }


__all__ = [
    "Key",
    "key_of",
    "label",
    "DRIFT_Z",
    "parameter_trend",
    "summarize",
    "vehicle_summary",
    "weighted_slope",
]

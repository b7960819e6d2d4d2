"""ArduPilot DataFlash logs (``.bin`` that starts with a FMT message) through pymavlink's
DFReader (extra ``[ardupilot]``), of every era.

A ``.bin`` is a raw wire capture unless its first bytes are a DataFlash FMT
message (``A3 95 80``): the registry's magic test tells them apart. The samples
of one IMU instance (``--instance N``, by default the lowest; the ``source``
metadata lists the instances), from the first of:

- ``ACC`` / ``GYR`` (raw IMU logging, every sample, ``SampleUS``), when logged at
  least as fast as ``IMU``; the accelerometer interpolated to the gyro's times;
- ``IMU`` (field ``I`` in current firmware; ``IMU``, ``IMU2``, ``IMU3`` for
  instances 0, 1, 2 in older logs);
- the batch sampler's ``ISBH`` / ``ISBD`` bursts (raw int16 / ``mul``), only when
  the log has neither (they come in bursts with gaps between).

``GyrX..Z`` are rad/s, ``AccX..Z`` m/s^2, ``T`` degC; ``t`` is ``TimeUS`` (or
``TimeMS`` in logs before 2015, or ``SampleUS``) in s since boot. ``GPS`` (and
``GPA``'s speed accuracy) are the log's own GNSS fixes (:meth:`DataFlashReader.gnss`):
boot time (``TimeUS``, or ``T`` ms before 2015) and GPS time (``GWk``/``GMS``, or
``Week``/``TimeMS`` before 2015). The file is read whole by the scan of
:mod:`.dataflash_scan` (pymavlink's values, about 50 times faster), or through pymavlink
where the scan leaves it (damage, redefinitions), then handed out in blocks.
"""

from __future__ import annotations

import types
from pathlib import Path
from typing import Any

import numpy as np

from ..certificate import FLIGHT_CONTROLLER_DATASHEET
from .base import DEFAULT_BLOCK_SIZE, ColumnsReader, LogError
from .dataflash_scan import Messages, ScanError, pymavlink_messages, scan_messages
from .extras import require
from .gnss_fixes import GnssFixes, gps_week_ms_to_unix, mode_of_fix_type
from .options import LogOptions

#: First bytes of a DataFlash log: the message head A3 95 and the FMT message id 128.
DATAFLASH_MAGIC = b"\xa3\x95\x80"
_NAMES = {"IMU": 0, "IMU2": 1, "IMU3": 2}
_TYPES = [*_NAMES, "ACC", "GYR", "ISBH", "ISBD", "GPS", "GPA"]


def is_dataflash(head: bytes) -> bool:
    """Whether a file's first bytes are a DataFlash log's."""
    return head.startswith(DATAFLASH_MAGIC)


def boot_s(m: Any) -> float:
    """A DataFlash message's time since boot, s: ``TimeUS`` or, before 2015, ``TimeMS``."""
    us = getattr(m, "TimeUS", None)
    if us is not None:
        return float(us) * 1e-6
    ms = getattr(m, "TimeMS", None)
    if ms is None:
        raise ValueError(f"{m.get_type()} message without TimeUS or TimeMS")
    return float(ms) * 1e-3


def _rate(t: np.ndarray) -> float:
    return float(1.0 / np.median(np.diff(t))) if t.shape[0] > 1 else 0.0


class DataFlashReader(ColumnsReader):
    """Reader of the IMU samples of one instance of an ArduPilot DataFlash log."""

    format = "dataflash"

    def __init__(
        self,
        path: str | Path,
        block_size: int = DEFAULT_BLOCK_SIZE,
        options: LogOptions | None = None,
    ) -> None:
        super().__init__(path, block_size)
        self.options = options or LogOptions()
        head = self._read_head(len(DATAFLASH_MAGIC))  # refused before the library's import
        if not is_dataflash(head):
            raise LogError(self.path, "not a DataFlash log (no FMT message at the start)")
        # pymavlink: the reference, and the reader of what the scan leaves (ScanError)
        require("pymavlink.DFReader", "ardupilot", "ArduPilot DataFlash logs")
        try:
            try:
                msgs = scan_messages(self.path, _TYPES)
            except ScanError:
                msgs = pymavlink_messages(self.path, _TYPES)
            imu, raw = _imu_rows(msgs), _raw_rows(msgs)
            batches: dict[int, dict[str, Any]] = {}
            gps: list[tuple[float, ...]] = []
            gpa: dict[float, float] = {}
            for name, row in msgs.rows(["ISBH", "ISBD", "GPS", "GPA"]):
                m = _Message(name, row)
                if name == "ISBH":
                    batches[int(m.N)] = {"head": m, "data": []}
                elif name == "ISBD":
                    if int(m.N) in batches:
                        batches[int(m.N)]["data"].append((int(m.seqno), m.x, m.y, m.z))
                elif name == "GPS" and int(getattr(m, "I", 0)) == 0:
                    try:  # a GPS layout without these fields gives no fixes, not an error
                        gps.append(self._gps_row(m))
                    except (AttributeError, TypeError, ValueError):
                        self.meta["gps_messages_unread"] = (
                            self.meta.get("gps_messages_unread", 0) + 1
                        )
                elif name == "GPA" and int(getattr(m, "I", 0)) == 0:
                    gpa[boot_s(m)] = float(getattr(m, "SAcc", np.nan))
        except LogError:
            raise
        except Exception as exc:  # a corrupt log: pymavlink raises plain errors
            raise LogError(self.path, f"not a readable DataFlash log: {exc}") from None
        self._gnss = self._fixes(gps, gpa)
        sources = self._sources(imu, raw, batches)
        if not sources:
            raise LogError(
                self.path, "no IMU messages in the DataFlash log (IMU, ACC/GYR or ISBH/ISBD)"
            )
        kind, cols_by_inst = sources
        have = sorted(cols_by_inst)
        listed = ", ".join(map(str, have))
        wanted = self.options.instance
        if wanted is not None and wanted not in cols_by_inst:
            raise LogError(
                self.path, f"--instance {wanted}: no IMU of that instance (have {listed})"
            )
        inst = have[0] if wanted is None else wanted
        self._cols = cols_by_inst[inst]
        if "temp" in self._cols and not np.all(np.isfinite(self._cols["temp"])):
            del self._cols["temp"]
        how = "--instance" if wanted is not None else "the lowest; --instance N for another"
        rate = _rate(self._cols["t"])
        self.meta.update(
            {
                "source": f"DataFlash {kind} instance {inst} ({how}; instances in the log: "
                f"{listed})",
                "units": {"gyro": "rad/s", "accel": "m/s^2"},
                "device": f"ArduPilot DataFlash {Path(self.path).name}",
                # an autopilot's IMU in SI: the class's data sheet (--certificate auto)
                "datasheet": FLIGHT_CONTROLLER_DATASHEET,
            }
        )
        if rate > 0:
            self.meta["sample_rate"] = round(rate, 3)
        self.meta["instance"] = inst
        self.meta["imu_instances"] = [
            {"instance": i, "rate_hz": round(_rate(cols_by_inst[i]["t"]), 3)} for i in have
        ]

    # -- IMU sources ----------------------------------------------------------

    def _sources(
        self,
        imu: dict[int, np.ndarray],
        raw: dict[tuple[str, int], np.ndarray],
        batches: dict[int, dict[str, Any]],
    ) -> tuple[str, dict[int, dict[str, np.ndarray]]] | None:
        names = ("t", "gx", "gy", "gz", "ax", "ay", "az", "temp")
        imu_cols = {i: {n: m[:, k] for k, n in enumerate(names)} for i, m in imu.items()}
        raw_cols: dict[int, dict[str, np.ndarray]] = {}
        for (name, i), g in raw.items():
            if name == "GYR" and ("ACC", i) in raw:
                cols = _pair(g, raw[("ACC", i)])
                if cols is not None:
                    raw_cols[i] = cols
        imu_rate = max((_rate(c["t"]) for c in imu_cols.values()), default=0.0)
        if raw_cols and max(_rate(c["t"]) for c in raw_cols.values()) >= imu_rate:
            return "ACC/GYR", raw_cols
        if imu_cols:
            return "IMU", imu_cols
        isb = _batch_columns(batches)
        return ("ISBH/ISBD batch sampler", isb) if isb else None

    # -- GNSS -----------------------------------------------------------------

    @staticmethod
    def _gps_row(m: Any) -> tuple[float, ...]:
        if hasattr(m, "TimeUS"):
            t_log = float(m.TimeUS) * 1e-6
            week, ms = getattr(m, "GWk", 0), getattr(m, "GMS", 0)
        else:  # before 2015: TimeMS is GPS ms of week, T the boot time in ms
            t_log = float(getattr(m, "T", np.nan)) * 1e-3
            week, ms = getattr(m, "Week", 0), getattr(m, "TimeMS", 0)
        t_gnss = float(gps_week_ms_to_unix(np.array([week]), np.array([ms]))[0])
        spd, crs = float(m.Spd), np.radians(float(m.GCrs))
        mode, status = mode_of_fix_type(float(m.Status))
        alt = float(getattr(m, "Alt", np.nan))
        return (t_log, t_gnss, float(m.Lat), float(m.Lng), alt, spd * np.cos(crs),
                spd * np.sin(crs), float(m.VZ), np.nan, float(mode), float(status))  # fmt: skip

    @staticmethod
    def _fixes(gps: list[tuple[float, ...]], gpa: dict[float, float]) -> GnssFixes | None:
        rows = [r for r in gps if np.isfinite(r[0])]
        if not rows:
            return None
        rows = [(*r[:8], gpa.get(r[0], np.nan), *r[9:]) for r in rows]
        return GnssFixes.from_rows(
            rows,
            "DataFlash GPS (instance 0; GPA SAcc as speed accuracy)",
            "GPS week and ms of week of each GPS message (GWk/GMS, Week/TimeMS before 2015)",
        )

    def gnss(self) -> GnssFixes | None:
        """The log's GPS messages (instance 0) with boot time and GPS time."""
        return self._gnss

    def _where(self, index: int) -> str:
        return f"IMU sample {index + 1}"


class _Message(types.SimpleNamespace):
    """One message of :meth:`Messages.rows` with its fields as attributes, as pymavlink's."""

    def __init__(self, name: str, row: dict[str, Any]) -> None:
        super().__init__(**row)
        self._name = name

    def get_type(self) -> str:
        return self._name


def _boot_s_columns(name: str, cols: dict[str, np.ndarray]) -> np.ndarray:
    """:func:`boot_s` of every message of a table: ``TimeUS`` or ``TimeMS``, s."""
    if "TimeUS" in cols:
        return cols["TimeUS"] * 1e-6
    if "TimeMS" in cols:
        return cols["TimeMS"] * 1e-3
    raise ValueError(f"{name} message without TimeUS or TimeMS")


def _in_order(parts: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """The rows of (offsets, rows) parts in the log's order."""
    at = np.concatenate([p[0] for p in parts])
    rows = np.concatenate([p[1] for p in parts])
    return rows[np.argsort(at, kind="stable")]


def _imu_rows(msgs: Messages) -> dict[int, np.ndarray]:
    """By instance: (t, gyro xyz, accel xyz, temp) of the IMU messages (``I``, or the name
    in logs before it), in the log's order."""
    parts: dict[int, list[tuple[np.ndarray, np.ndarray]]] = {}
    for name, default in _NAMES.items():
        cols = msgs.columns.get(name)
        if cols is None:
            continue
        n = msgs.count(name)
        inst = cols["I"] if name == "IMU" and "I" in cols else np.full(n, float(default))
        rows = np.column_stack(
            [_boot_s_columns(name, cols)]
            + [cols[c] for c in ("GyrX", "GyrY", "GyrZ", "AccX", "AccY", "AccZ")]
            + [cols.get("T", np.full(n, np.nan))]
        )
        at = msgs.offsets[name]
        for i in np.unique(inst).tolist():
            pick = inst == i
            parts.setdefault(int(i), []).append((at[pick], rows[pick]))
    return {i: _in_order(p) for i, p in parts.items()}


def _raw_rows(msgs: Messages) -> dict[tuple[str, int], np.ndarray]:
    """By (``ACC`` or ``GYR``, instance): (t, x, y, z) of the raw IMU messages, ``t`` their
    ``SampleUS`` (else ``TimeUS``), in the log's order."""
    out: dict[tuple[str, int], np.ndarray] = {}
    for name, p in (("ACC", "Acc"), ("GYR", "Gyr")):
        cols = msgs.columns.get(name)
        if cols is None:
            continue
        n = msgs.count(name)
        t = cols["SampleUS"] if "SampleUS" in cols else cols["TimeUS"]
        rows = np.column_stack([t * 1e-6] + [cols[p + a] for a in "XYZ"])
        inst = cols["I"] if "I" in cols else np.zeros(n)
        for i in np.unique(inst).tolist():
            out[(name, int(i))] = rows[inst == i]
    return out


def _pair(g: np.ndarray, a: np.ndarray) -> dict[str, np.ndarray] | None:
    """Gyro rows (t, x, y, z) with the accelerometer interpolated to their times, only where
    an accelerometer sample lies within 1.5 of its steps (bursts are not bridged)."""
    g = g[np.argsort(g[:, 0], kind="stable")]
    a = a[np.argsort(a[:, 0], kind="stable")]
    if g.shape[0] < 2 or a.shape[0] < 2:
        return None
    step = float(np.median(np.diff(a[:, 0])))
    j = np.clip(np.searchsorted(a[:, 0], g[:, 0]), 1, a.shape[0] - 1)
    near = np.minimum(np.abs(a[j, 0] - g[:, 0]), np.abs(a[j - 1, 0] - g[:, 0]))
    bridge = a[j, 0] - a[j - 1, 0]
    on_sample = near <= 1e-9  # a gyro sample at an accelerometer sample's time
    keep = (on_sample | ((near <= 1.5 * step) & (bridge <= 1.5 * step))) & (g[:, 0] >= a[0, 0])
    keep &= g[:, 0] <= a[-1, 0]
    if keep.sum() < 2:
        return None
    t = g[keep, 0]
    cols = {"t": t}
    for k, axis in enumerate("xyz"):
        cols[f"g{axis}"] = g[keep, 1 + k]
        cols[f"a{axis}"] = np.interp(t, a[:, 0], a[:, 1 + k])
    return cols


def _batch_columns(batches: dict[int, dict[str, Any]]) -> dict[int, dict[str, np.ndarray]]:
    """The batch sampler's bursts (ISBH type 0 accel, 1 gyro; ISBD int16 x/y/z / mul) as
    columns per instance."""
    rows: dict[tuple[int, int], list[np.ndarray]] = {}
    for b in batches.values():
        h, data = b["head"], sorted(b["data"], key=lambda d: d[0])
        if not data or float(h.smp_rate) <= 0 or float(h.mul) == 0:
            continue
        xyz = np.concatenate([np.asarray(d[1:], dtype=float).T for d in data]) / float(h.mul)
        t = float(h.SampleUS) * 1e-6 + np.arange(xyz.shape[0]) / float(h.smp_rate)
        rows.setdefault((int(h.type), int(h.instance)), []).append(np.column_stack([t, xyz]))
    out: dict[int, dict[str, np.ndarray]] = {}
    for (kind, inst), parts in rows.items():
        if kind == 1 and (0, inst) in rows:
            cols = _pair(np.concatenate(parts), np.concatenate(rows[(0, inst)]))
            if cols is not None:
                out[inst] = cols
    return out


__all__ = ["DATAFLASH_MAGIC", "DataFlashReader", "boot_s", "is_dataflash"]

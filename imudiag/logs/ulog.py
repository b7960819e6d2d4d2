"""PX4 ULog flight logs (``.ulg``) through pyulog (extra ``[px4]``).

Which topics: the raw ``sensor_gyro`` and ``sensor_accel`` of one instance
(``--instance N``, the sensor's multi id) when asked for, or when they are
logged at least half as fast as ``sensor_combined`` (PX4 usually logs the raw
topics at about 1 Hz and ``sensor_combined`` at the control rate, 100-250
Hz); otherwise ``sensor_combined``. The choice and its reason are in the
metadata (``source``) and printed by the commands that show the log's source.
Units are SI (rad/s, m/s^2, the ``units`` metadata says so); time is the
sample's ``timestamp`` (``timestamp_sample`` for raw topics) in s from the
log's start. With the raw topics the accelerometer samples are interpolated
linearly to the gyro's time stamps (their clocks differ), within their
overlap; the gyro's temperature is ``temp``. The file is parsed whole (pyulog
reads a ULog in one pass), then handed out in blocks; the last parse is kept while the file
is unchanged (:mod:`.kept`: a diagnosis reads a log twice, a fleet once per instance).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..certificate import FLIGHT_CONTROLLER_DATASHEET
from .base import DEFAULT_BLOCK_SIZE, ColumnsReader, LogError
from .extras import require
from .gnss_fixes import GnssFixes, mode_of_fix_type
from .kept import LastParse
from .options import LogOptions

#: First bytes of a ULog file ("ULog" then 0x01 0x12 0x35).
ULOG_MAGIC = b"ULog\x01\x12\x35"
_TOPICS = ["sensor_combined", "sensor_gyro", "sensor_accel", "vehicle_imu"]
#: GNSS topics, in order of preference (the selected/blended receiver, then receiver 0).
GPS_TOPICS = ("vehicle_gps_position", "sensor_gps")


#: pyulog's last parse of a file: (the log's start, us; the topics' columns by (name, multi id))
_Topics = tuple[int, dict[tuple[str, int], dict[str, np.ndarray]]]
_LAST: LastParse[_Topics] = LastParse(lambda p: (v for d in p[1].values() for v in d.values()))


def is_ulog(head: bytes) -> bool:
    """Whether a file's first bytes are a ULog header."""
    return head.startswith(ULOG_MAGIC)


def _rate_hz(t_s: np.ndarray) -> float:
    return float(1.0 / np.median(np.diff(t_s))) if t_s.shape[0] > 1 else 0.0


class ULogReader(ColumnsReader):
    """Reader of the IMU topics of a PX4 ULog file."""

    format = ".ulg"

    def __init__(
        self,
        path: str | Path,
        block_size: int = DEFAULT_BLOCK_SIZE,
        options: LogOptions | None = None,
    ) -> None:
        super().__init__(path, block_size)
        self.options = options or LogOptions()
        head = self._read_head(len(ULOG_MAGIC))  # refused before the library's import
        if not is_ulog(head):
            raise LogError(self.path, "not a ULog file (no ULog header)")
        self._start_us, topics = _LAST.get(self.path, "imu+gps", self._parse)
        self._gnss = self._fixes(topics)
        self._cols, source = self._choose(topics)
        self.meta.update(
            {
                "source": source,
                "units": {"gyro": "rad/s", "accel": "m/s^2"},
                "sample_rate": round(_rate_hz(self._cols["t"]), 3),
                "device": f"PX4 ULog {Path(self.path).name}",
                "instance": self._instance,
                "imu_instances": self._instances(topics),
                # an autopilot's IMU in SI: the class's data sheet (--certificate auto)
                "datasheet": FLIGHT_CONTROLLER_DATASHEET,
            }
        )

    def _parse(self) -> _Topics:
        pyulog = require("pyulog", "px4", "PX4 ULog files")
        try:
            ulog = pyulog.ULog(self.path, message_name_filter_list=[*_TOPICS, *GPS_TOPICS])
        except Exception as exc:  # pyulog raises bare Exceptions on corrupt files
            raise LogError(self.path, f"not a readable ULog file: {exc}") from None
        return int(ulog.start_timestamp), {
            (d.name, int(d.multi_id)): d.data for d in ulog.data_list
        }

    def _instances(
        self, topics: dict[tuple[str, int], dict[str, np.ndarray]]
    ) -> list[dict[str, Any]]:
        """Every IMU instance ``--instance N`` reads (raw sensor_gyro + sensor_accel, else
        vehicle_imu) with the rate of its time stamps, Hz."""
        out = []
        for i in sorted({i for (name, i) in topics if name in ("sensor_gyro", "vehicle_imu")}):
            if ("sensor_gyro", i) in topics and ("sensor_accel", i) in topics:
                stamps = topics[("sensor_gyro", i)]["timestamp"]
            elif ("vehicle_imu", i) in topics:
                d = topics[("vehicle_imu", i)]
                stamps = d.get("timestamp_sample", d["timestamp"])
            else:
                continue
            out.append({"instance": i, "rate_hz": round(_rate_hz(self._time(stamps)), 3)})
        return out

    # -- topic choice ---------------------------------------------------------

    def _choose(
        self, topics: dict[tuple[str, int], dict[str, np.ndarray]]
    ) -> tuple[dict[str, np.ndarray], str]:
        instances = sorted(
            i for (name, i) in topics if name == "sensor_gyro" and ("sensor_accel", i) in topics
        )
        combined = topics.get(("sensor_combined", 0))
        wanted = self.options.instance
        imus = sorted(i for (name, i) in topics if name == "vehicle_imu")
        self._instance: int | None = None  # the instance read; None: sensor_combined
        if wanted is not None and wanted not in instances and wanted in imus:
            self._instance = wanted
            cols = self._vehicle_imu(topics[("vehicle_imu", wanted)])
            return cols, f"vehicle_imu instance {wanted} (--instance), {_rate_hz(cols['t']):.3g} Hz"
        if wanted is None and combined is None and not instances and imus:
            self._instance = imus[0]
            cols = self._vehicle_imu(topics[("vehicle_imu", imus[0])])
            return cols, (
                f"vehicle_imu instance {imus[0]} (no sensor_combined nor raw topics; "
                f"instances {', '.join(map(str, imus))}), {_rate_hz(cols['t']):.3g} Hz"
            )
        if wanted is not None:
            if wanted not in instances:
                have = ", ".join(map(str, instances)) or "none"
                raise LogError(
                    self.path,
                    f"--instance {wanted}: no sensor_gyro and sensor_accel of that instance "
                    f"(instances with both: {have})",
                )
            self._instance = wanted
            cols = self._raw(topics, wanted)
            return cols, (
                f"sensor_gyro/sensor_accel instance {wanted} (--instance), "
                f"{_rate_hz(cols['t']):.3g} Hz"
            )
        if combined is None and not instances:
            raise LogError(
                self.path, "no IMU topic: neither sensor_combined nor sensor_gyro + sensor_accel"
            )
        comb_rate = _rate_hz(self._time(combined["timestamp"])) if combined is not None else 0.0
        for i in instances:
            t = self._time(topics[("sensor_gyro", i)]["timestamp"])
            raw_rate = _rate_hz(t)
            if raw_rate >= 0.5 * comb_rate:
                self._instance = i
                cols = self._raw(topics, i)
                return cols, (
                    f"sensor_gyro/sensor_accel instance {i} ({raw_rate:.3g} Hz raw; "
                    f"sensor_combined {comb_rate:.3g} Hz)"
                )
        assert combined is not None
        why = (
            f"the raw sensor_gyro/sensor_accel topics (instances "
            f"{', '.join(map(str, instances))}) are logged at "
            f"{_rate_hz(self._time(topics[('sensor_gyro', instances[0])]['timestamp'])):.3g} Hz;"
            " --instance N reads them"
            if instances
            else "no raw sensor_gyro/sensor_accel topics in the log"
        )
        return self._combined(combined), f"sensor_combined, {comb_rate:.3g} Hz ({why})"

    def _vehicle_imu(self, d: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """vehicle_imu's integrated deltas over their intervals: rad/s and m/s^2."""
        t = self._time(d.get("timestamp_sample", d["timestamp"]))
        da = np.asarray(d["delta_angle_dt"], dtype=float) * 1e-6
        dv = np.asarray(d["delta_velocity_dt"], dtype=float) * 1e-6
        ok = (da > 0) & (dv > 0)
        cols = {"t": t[ok]}
        for k, axis in enumerate("xyz"):
            cols[f"g{axis}"] = np.asarray(d[f"delta_angle[{k}]"], dtype=float)[ok] / da[ok]
            cols[f"a{axis}"] = np.asarray(d[f"delta_velocity[{k}]"], dtype=float)[ok] / dv[ok]
        return cols

    def _fixes(self, topics: dict[tuple[str, int], dict[str, np.ndarray]]) -> GnssFixes | None:
        """vehicle_gps_position (or sensor_gps 0): boot time ``timestamp`` and the receiver's
        UTC ``time_utc_usec`` (0: unknown); lat/lon in 1e-7 deg (``latitude_deg`` in newer
        logs), altitude mm (``altitude_ellipsoid_m`` m), NED velocity m/s, speed accuracy
        ``s_variance_m_s`` m/s, ``fix_type``."""
        name = next((n for n in GPS_TOPICS if (n, 0) in topics), None)
        if name is None:
            return None
        d = topics[(name, 0)]

        def f(*keys: str, scale: float = 1.0) -> np.ndarray:
            for k in keys:
                if k in d:
                    return np.asarray(d[k], dtype=float) * (scale if k in keys[:1] else 1.0)
            return np.full(len(d["timestamp"]), np.nan)

        lat = f("lat", "latitude_deg", scale=1e-7)
        lon = f("lon", "longitude_deg", scale=1e-7)
        alt = f("alt_ellipsoid", "altitude_ellipsoid_m", scale=1e-3)
        utc = f("time_utc_usec") * 1e-6
        utc[~(utc > 0)] = np.nan
        vel = np.column_stack([f("vel_n_m_s"), f("vel_e_m_s"), f("vel_d_m_s")])
        if "vel_ned_valid" in d:
            vel[np.asarray(d["vel_ned_valid"]) == 0] = np.nan
        mode, status = mode_of_fix_type(f("fix_type"))
        rows = np.column_stack(
            [self._time(d["timestamp"]), utc, lat, lon, alt, vel, f("s_variance_m_s"), mode,
             status]
        )  # fmt: skip
        return GnssFixes.from_rows(
            [tuple(r) for r in rows],
            f"ULog {name} (instance 0)",
            "the receiver's UTC time of each fix (time_utc_usec)",
        )

    def gnss(self) -> GnssFixes | None:
        """The log's GNSS fixes (vehicle_gps_position, else sensor_gps instance 0)."""
        return self._gnss

    def _time(self, stamp_us: np.ndarray) -> np.ndarray:
        return (np.asarray(stamp_us, dtype=np.int64) - self._start_us) * 1e-6

    def _combined(self, d: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        cols = {"t": self._time(d["timestamp"])}
        for k, axis in enumerate("xyz"):
            cols[f"g{axis}"] = np.asarray(d[f"gyro_rad[{k}]"], dtype=float)
            cols[f"a{axis}"] = np.asarray(d[f"accelerometer_m_s2[{k}]"], dtype=float)
        return cols

    def _raw(self, topics: dict[tuple[str, int], dict[str, np.ndarray]], i: int) -> dict[str, Any]:
        g = topics[("sensor_gyro", i)]
        a = topics[("sensor_accel", i)]
        tg = self._time(g.get("timestamp_sample", g["timestamp"]))
        ta = self._time(a.get("timestamp_sample", a["timestamp"]))
        order = np.argsort(ta, kind="stable")
        ta = ta[order]
        inside = (tg >= ta[0]) & (tg <= ta[-1])
        if inside.sum() < 2:
            raise LogError(
                self.path,
                f"instance {i}: the gyro and accelerometer samples do not overlap in time",
            )
        cols: dict[str, Any] = {"t": tg[inside]}
        for axis in "xyz":
            cols[f"g{axis}"] = np.asarray(g[axis], dtype=float)[inside]
            cols[f"a{axis}"] = np.interp(tg[inside], ta, np.asarray(a[axis], dtype=float)[order])
        if "temperature" in g:
            cols["temp"] = np.asarray(g["temperature"], dtype=float)[inside]
        return cols


__all__ = ["ULOG_MAGIC", "ULogReader", "is_ulog"]

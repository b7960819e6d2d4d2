"""GNSS fixes carried by a log itself (DataFlash GPS/GPA, ULog vehicle_gps_position/sensor_gps,
ROS NavSatFix with a velocity topic), in the log's own clock and, where the log says it, in
GNSS time.

A reader whose format carries GNSS returns a :class:`GnssFixes` from ``reader.gnss()``
(None when the log has none). ``t_log`` is in the clock of the log's samples (the same
``t`` as the IMU samples, s); ``t_gnss`` is the receiver's own time of the fix as UTC Unix
s (NaN where the log does not give it): the pairs are what ties the IMU clock to GNSS
time (:mod:`imudiag.aiding.log_clock`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: GPS time 0 (1980-01-06) as Unix s.
GPS_EPOCH_UNIX = 315964800
#: GPS - UTC leap seconds, from the GPS time (Unix s, UTC-ish) they start at.
_LEAPS = ((1341100800, 16), (1435708800, 17), (1483228800, 18))


def gps_week_ms_to_unix(week: np.ndarray, ms: np.ndarray) -> np.ndarray:
    """GPS week and ms of week -> UTC Unix s (leap seconds since 2012; week 0: NaN)."""
    week = np.asarray(week, dtype=float)
    gps = GPS_EPOCH_UNIX + week * 604800.0 + np.asarray(ms, dtype=float) * 1e-3
    leap = np.full(gps.shape, 15.0)
    for start, n in _LEAPS:
        leap[gps >= start + n] = n
    out = gps - leap
    out[week <= 0] = np.nan
    return out


@dataclass
class GnssFixes:
    """GNSS fixes of a log (arrays of K fixes, time order of the log).

    t_log s (the samples' clock); t_gnss s UTC Unix (NaN: unknown); lat_deg, lon_deg deg;
    alt_m m (NaN unknown); vel_ned (K, 3) m/s north, east, down (NaN unknown); eps m/s
    speed accuracy (NaN unknown); mode 1 no fix, 2 2D, 3 3D; status gpsd's (1 normal,
    2 DGPS, 3 RTK fixed, 4 RTK float). ``source`` says which messages, ``clock`` how
    ``t_gnss`` was found (or why it is absent).
    """

    t_log: np.ndarray
    t_gnss: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    alt_m: np.ndarray
    vel_ned: np.ndarray
    eps: np.ndarray
    mode: np.ndarray
    status: np.ndarray
    source: str = ""
    clock: str = ""
    meta: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.t_log.shape[0])

    @classmethod
    def from_rows(cls, rows: list[tuple[float, ...]], source: str, clock: str) -> GnssFixes:
        """From rows (t_log, t_gnss, lat, lon, alt, vn, ve, vd, eps, mode, status)."""
        m = np.asarray(rows, dtype=float).reshape(-1, 11)
        order = np.argsort(m[:, 0], kind="stable")
        m = m[order]
        return cls(
            t_log=m[:, 0],
            t_gnss=m[:, 1],
            lat_deg=m[:, 2],
            lon_deg=m[:, 3],
            alt_m=m[:, 4],
            vel_ned=m[:, 5:8],
            eps=m[:, 8],
            mode=m[:, 9].astype(int),
            status=m[:, 10].astype(int),
            source=source,
            clock=clock,
        )


def mode_of_fix_type(fix: np.ndarray | float) -> np.ndarray:
    """ArduPilot GPS Status / PX4 fix_type (0-1 none, 2 2D, 3 3D, 4 DGPS, 5 RTK float,
    6 RTK fixed) -> (gpsd mode, gpsd status)."""
    f = np.asarray(fix, dtype=float)
    mode = np.where(f >= 3, 3, np.where(f >= 2, 2, 1))
    status = np.select([f == 4, f == 5, f == 6], [2, 4, 3], default=1)
    return np.stack([mode, status])


__all__ = ["GPS_EPOCH_UNIX", "GnssFixes", "gps_week_ms_to_unix", "mode_of_fix_type"]

"""GNSS aiding for the moving-base scalar checks (issue 15).

The scalar method needs the magnitude of the specific force from outside the
triad (design note §1). On a moving vehicle GNSS gives it without any
attitude: in the local level frame (NED)

    f_n = dv_n/dt - g_n + (2 Omega_ie + omega_en) x v_n

and |f_n| = |f_b| because a rotation keeps lengths. Modules:

- :mod:`.tpv`: gpsd TPV reports (``gpspipe -w`` logs, live JSON lines) into a
  :class:`~.tpv.GnssTrack`.
- :mod:`.earth`: WGS-84 normal gravity, Earth rate and transport rate.
- :mod:`.specific_force`: |f| per GNSS epoch with its propagated noise and the
  quality gate; the IMU's mean |f| over the same epochs.
- :mod:`.align`: the GNSS latency by cross-correlating the two magnitudes.
- :mod:`.course_rate`: the gyro magnitude in turns from the GNSS course rate
  (land vehicles, under the no-slip assumption).
"""

from ..earth import earth_rate_ned, normal_gravity, transport_rate_ned
from .align import LatencyEstimate, estimate_latency
from .specific_force import (
    GateConfig,
    GnssEpochs,
    ImuEpochs,
    gnss_epochs,
    imu_epochs,
)
from .tpv import GnssTrack, parse_tpv, read_gpspipe_log, track_from_reports

__all__ = [
    "GateConfig",
    "GnssEpochs",
    "GnssTrack",
    "ImuEpochs",
    "LatencyEstimate",
    "earth_rate_ned",
    "estimate_latency",
    "gnss_epochs",
    "imu_epochs",
    "normal_gravity",
    "parse_tpv",
    "read_gpspipe_log",
    "track_from_reports",
    "transport_rate_ned",
]

"""The simulated GNSS stream as u-blox UBX binary (NAV-PVT + NAV-VELNED per epoch).

gpsfake (Debian gpsd-clients) replays such a file into a real gpsd, which
reports TPV objects: time, fix mode and position from NAV-PVT, velN/velE/velD
from NAV-VELNED (gpsd 3.22 takes the NED velocity from that message; its
resolution is 1 cm/s). Needs pyubx2 (a test dependency, not the daemon's).
"""

from __future__ import annotations

from datetime import datetime
from pathlib import Path

GPS_EPOCH_UNIX = 315964800.0  #: 1980-01-06T00:00:00Z
LEAP_S = 18.0  #: GPS - UTC, s (since 2017)


def ubx_epoch(report: dict) -> bytes:
    """NAV-PVT then NAV-VELNED bytes of one TPV report (from :func:`.drive.gnss_reports`)."""
    import pyubx2

    t = datetime.fromisoformat(report["time"]).timestamp()  # drive.py writes ISO 8601, UTC
    ms_total = int(round(t * 1000.0))
    dt = datetime.utcfromtimestamp(ms_total // 1000)
    gps_ms = int(round((t + LEAP_S - GPS_EPOCH_UNIX) * 1000.0))
    itow = gps_ms % (7 * 86400 * 1000)
    fix = report.get("mode", 0) >= 3
    vn, ve, vd = (report.get(k, 0.0) if fix else 0.0 for k in ("velN", "velE", "velD"))
    s_acc = int(round(1000 * report.get("eps", 0.1) / 2)) if fix else 99999
    pvt = pyubx2.UBXMessage(
        "NAV",
        "NAV-PVT",
        pyubx2.GET,
        iTOW=itow,
        year=dt.year,
        month=dt.month,
        day=dt.day,
        hour=dt.hour,
        min=dt.minute,
        second=dt.second,
        nano=(ms_total % 1000) * 1_000_000,
        validDate=1,
        validTime=1,
        fullyResolved=1,
        fixType=3 if fix else 0,
        gnssFixOk=1 if fix else 0,
        numSV=12 if fix else 0,
        lon=report.get("lon", 0.0) if fix else 0.0,
        lat=report.get("lat", 0.0) if fix else 0.0,
        height=int(round(1000 * report.get("altHAE", 0.0))) if fix else 0,
        hMSL=int(round(1000 * report.get("altHAE", 0.0))) if fix else 0,
        hAcc=500 if fix else 999999,
        vAcc=800 if fix else 999999,
        velN=int(round(1000 * vn)),
        velE=int(round(1000 * ve)),
        velD=int(round(1000 * vd)),
        gSpeed=int(round(1000 * (vn * vn + ve * ve) ** 0.5)),
        headMot=0.0,
        sAcc=s_acc,
        headAcc=1.0,
        pDOP=1.0,
    )
    vel = pyubx2.UBXMessage(
        "NAV",
        "NAV-VELNED",
        pyubx2.GET,
        iTOW=itow,
        velN=int(round(100 * vn)),
        velE=int(round(100 * ve)),
        velD=int(round(100 * vd)),
        speed=int(round(100 * (vn * vn + ve * ve + vd * vd) ** 0.5)),
        gSpeed=int(round(100 * (vn * vn + ve * ve) ** 0.5)),
        heading=0.0,
        sAcc=max(1, s_acc // 10),
        cAcc=1.0,
    )
    return pvt.serialize() + vel.serialize()


def write_ubx(path: str | Path, reports: list[dict]) -> None:
    """Write the TPV reports as a UBX binary log (atomically: a .part file renamed)."""
    p = Path(path)
    tmp = p.with_name(p.name + ".part")
    with open(tmp, "wb") as fh:
        for r in reports:
            if r.get("class") == "TPV":
                fh.write(ubx_epoch(r))
    tmp.replace(p)


__all__ = ["ubx_epoch", "write_ubx"]

"""``python -m benchmarks.dataflash_read [N]``: CPU of reading an ArduPilot DataFlash log,
s per 10^6 IMU samples of the instance read, through the scan (:mod:`imudiag.logs.dataflash_scan`,
what :func:`imudiag.logs.open_log` runs) and through pymavlink's ``DFReader`` (the reference;
what the reader ran before, and still runs on a log the scan leaves to it).

The log: ``N`` samples (default 2 10^5) of each of ``IMUS`` IMUs as current ArduPilot logs
them (``IMU`` with its instance field ``I``, 400 Hz), written in a temporary folder with a
GPS message every 0.2 s. Prints one line per path; no assertion: docs/benchmarks.md holds
the figures.
"""

from __future__ import annotations

import struct
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from imudiag.logs import LogOptions, open_log
from imudiag.logs import dataflash as dataflash_module
from imudiag.logs.dataflash_scan import ScanError, forget

IMUS = 3  #: IMU instances in the log
RATE_HZ = 400.0
HEAD = b"\xa3\x95"
IMU = (131, "IMU", "QBffffffIIfBB", "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,EG,EA,T,GH,AH")
GPS = (132, "GPS", "QBIHBiiifff", "TimeUS,I,GMS,GWk,Status,Lat,Lng,Alt,Spd,GCrs,VZ")


def _fmt(type_id: int, name: str, fmt: str, cols: str) -> bytes:
    length = 89 if name == "FMT" else 3 + struct.calcsize("<" + fmt)
    fmt_chars = fmt.replace("i", "L", 2) if name == "GPS" else fmt  # Lat, Lng: L (1e-7 deg)
    body = struct.pack("<BB4s16s64s", type_id, length, name.encode(), fmt_chars.encode(),
                       cols.encode())  # fmt: skip
    return HEAD + bytes([128]) + body


def write_log(path: Path, n: int, seed: int = 1) -> Path:
    """``n`` samples of :data:`IMUS` IMUs at :data:`RATE_HZ` as IMU messages, with GPS."""
    rng = np.random.default_rng(seed)
    out = [_fmt(128, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns"), _fmt(*IMU), _fmt(*GPS)]
    imu, gps = struct.Struct("<" + IMU[2]), struct.Struct("<" + GPS[2])
    g = rng.normal(0.0, 0.01, (n, 3))
    a = rng.normal(0.0, 0.05, (n, 3)) + [0.0, 0.0, -9.81]
    for k in range(n):
        us = 5_000_000 + int(k * 1e6 / RATE_HZ)
        for i in range(IMUS):
            out.append(HEAD + bytes([131]) + imu.pack(us, i, *g[k], *a[k], 0, 0, 31.5, 1, 1))
        if k % int(RATE_HZ / 5) == 0:
            rec = gps.pack(us, 0, k, 2300, 3, 473_977_000, 85_455_000, 48_800, 0.0, 0.0, 0.0)
            out.append(HEAD + bytes([132]) + rec)
    path.write_bytes(b"".join(out))
    return path


def read_cpu(path: Path, instances: tuple[int, ...] = (1,), cold: bool = True) -> tuple[float, int]:
    """(CPU s, samples) of reading the log whole for each of ``instances`` one after the
    other (the fleet's task reads each IMU instance, and a diagnosis reads a log twice);
    ``cold``: the scan kept by an earlier read dropped first."""
    if cold:
        forget()
    t0 = time.process_time()
    n = 0
    for instance in instances:
        with open_log(path, options=LogOptions(instance=instance)) as reader:
            for block in reader:
                n += len(block)
    return time.process_time() - t0, n


def _refuse(path: object, names: object) -> object:
    raise ScanError("the benchmark's reference path")


def main(argv: list[str]) -> int:
    n = int(float(argv[0])) if argv else 200_000
    with tempfile.TemporaryDirectory() as tmp:
        log = write_log(Path(tmp) / "flight.bin", n)
        read_cpu(log)  # imports paid
        size = log.stat().st_size / 1e6
        runs = [
            ("scan, one instance", (1,)),
            (f"scan, each of the {IMUS} instances, then again", tuple(range(IMUS)) * 2),
            ("pymavlink, one instance", (1,)),
        ]
        for name, instances in runs:
            if name.startswith("pymavlink"):
                dataflash_module.scan_messages = _refuse  # type: ignore[assignment]
            cpu, got = read_cpu(log, instances)
            print(
                f"{name}: {got} samples ({len(instances)} reads of a {size:.1f} MB log of "
                f"{IMUS} IMUs): {cpu:.2f} s CPU, {cpu / got * 1e6:.2f} s per 10^6 samples",
                flush=True,
            )
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

"""The floor the daemon's cost is judged against: a minimal Python reader of the same pty.

It does the least a monitor must do, at the daemon's read cadence: wake every
``--interval`` seconds (default 5 ms, the daemon's ``read_interval_s``), read
what the pty holds, take the whole sample frames (a sample-header search skips
the rare device-info frame), check their CRC (``binascii.crc_hqx``, the C
CRC-16/CCITT-FALSE), correct the accelerometer with the certificate (bias,
scale factor, N^-1 computed once) and compute its F0 with numpy, count the
failures, and write a status line to stdout once a second. No quasi-static
gating, no persistence, no gyro check, no diagnosis: what is left when a
monitor does nothing else.

Run: ``python -m benchmarks.floor_reader /dev/pts/N CERTIFICATE [--interval 0.005]``
(started by :func:`benchmarks.daemon_live.measure_live` beside the daemon).
"""

from __future__ import annotations

import argparse
import binascii
import json
import os
import signal
import sys
import time
import tty
from collections.abc import Sequence

import numpy as np

from imudiag.certificate import load
from imudiag.drivers.wire import FRAME_DTYPE, SAMPLE_FRAME_SIZE, SAMPLE_LENGTH, SYNC, TYPE_SAMPLE

_HEADER = SYNC + bytes([TYPE_SAMPLE, SAMPLE_LENGTH])


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("device")
    p.add_argument("certificate")
    p.add_argument("--interval", type=float, default=0.005, help="read interval, s")
    a = p.parse_args(argv)
    cert = load(a.certificate)
    acc = cert.accel
    n_inv_t = acc.n_inverse_t()
    to_g = acc.unit_to_si / cert.gravity
    limit = float(acc.limits.f0)
    stop = []
    signal.signal(signal.SIGTERM, lambda *_: stop.append(1))
    fd = os.open(a.device, os.O_RDONLY | os.O_NOCTTY | os.O_NONBLOCK)
    tty.setraw(fd)
    buf = b""
    frames = bad_crc = checked = failed = 0
    next_status = time.monotonic() + 1.0
    while not stop:
        t0 = time.monotonic()
        try:
            while True:
                chunk = os.read(fd, 65536)
                if not chunk:
                    break
                buf += chunk
        except BlockingIOError:
            pass
        pos = buf.find(_HEADER)
        rows: list[bytes] = []
        while pos >= 0 and pos + SAMPLE_FRAME_SIZE <= len(buf):
            frame = buf[pos : pos + SAMPLE_FRAME_SIZE]
            if binascii.crc_hqx(frame[2:38], 0xFFFF) == int.from_bytes(frame[38:], "little"):
                rows.append(frame)
                pos += SAMPLE_FRAME_SIZE
                if not buf.startswith(_HEADER, pos):
                    pos = buf.find(_HEADER, pos)
            else:
                bad_crc += 1
                pos = buf.find(_HEADER, pos + 1)
        buf = buf[pos:] if pos >= 0 else buf[-3:]
        if rows:
            f = np.frombuffer(b"".join(rows), FRAME_DTYPE)
            x = ((f["raw"][:, 3:] - acc.bias) / acc.scale_factor) @ n_inv_t * to_g
            f0 = 0.5 * (np.einsum("ij,ij->i", x, x) - 1.0)
            frames += len(rows)
            checked += f0.size
            failed += int(np.count_nonzero(np.abs(f0) > limit))
        now = time.monotonic()
        if now >= next_status:
            next_status += 1.0
            print(json.dumps({"class": "floor", "frames": frames, "crc_errors": bad_crc,
                              "checked": checked, "failed": failed}), flush=True)  # fmt: skip
        pause = t0 + a.interval - time.monotonic()
        if pause > 0:
            time.sleep(pause)
    os.close(fd)
    return 0


if __name__ == "__main__":
    sys.exit(main())

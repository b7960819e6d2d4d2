"""GNSS aiding through a real gpsd: gpsfake replays the simulator's GNSS stream (u-blox
UBX NAV-PVT + NAV-VELNED) into Debian's gpsd, and the daemon reads it over gpsd's socket
(?WATCH JSON) while it reads the IMU over a pty, both paced at SPEED x real time.

Skips with the reason where gpsd/gpsfake or pyubx2 is missing (.ci/run installs gpsd).
"""

from __future__ import annotations

import shutil
import subprocess

import pytest

from imudiag.aiding.gpsd_client import GpsdClient, parse_gpsd_url
from imudiag.bench.daemon_process import DaemonProcess
from imudiag.bench.gnss import find_gpsd, free_port, wait_listening
from imudiag.bench.pty import BoardWriter, PtyPair
from imudiag.certificate import load_default
from imudiag.errors import BadInput
from imudiag.sim.board import SimulatedBoard
from imudiag.sim.drive import GnssSimConfig, drive_motion, gnss_reports

pytestmark = pytest.mark.realtime  # tests/conftest.py: the two tiers

GPSD = find_gpsd()
GPSFAKE = shutil.which("gpsfake")
needs_gpsd = pytest.mark.skipif(
    not (GPSD and GPSFAKE),
    reason="Debian's gpsd and gpsfake (packages gpsd, gpsd-clients) are not installed: "
    "the real-gpsd aiding tests cannot run (.ci/run installs them when it runs as root)",
)
SPEED = 5.0  #: both streams at 5 x real time


def test_gpsd_url_and_unreachable_gpsd():
    assert parse_gpsd_url("gpsd://") == ("127.0.0.1", 2947)
    assert parse_gpsd_url("gpsd://10.0.0.2:3000") == ("10.0.0.2", 3000)
    with pytest.raises(BadInput, match="expected gpsd://HOST:PORT"):
        parse_gpsd_url("tcp://127.0.0.1:2947")
    c = GpsdClient(f"gpsd://127.0.0.1:{free_port()}")
    assert c.poll() == []
    assert c.state == "disconnected" and "not reachable" in c.last_error


@needs_gpsd
def test_daemon_aided_by_real_gpsd(tmp_path):
    pyubx2 = pytest.importorskip("pyubx2", reason="pyubx2 (test extra) writes the UBX log")
    assert pyubx2
    from imudiag.sim.ubx import write_ubx

    cert = load_default()
    motion = drive_motion("urban", 150.0, seed=5)
    ubx = tmp_path / "drive.ubx"
    write_ubx(ubx, gnss_reports(motion, GnssSimConfig(), seed=5))
    port = free_port()
    # two UBX messages per 0.2 s epoch
    gf = subprocess.Popen(
        [GPSFAKE, "-q", "-1", "-P", str(port), "-c", str(0.1 / SPEED), str(ubx)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        assert wait_listening(port, 10.0, lambda: gf.poll() is None), "gpsd did not listen"
        board = SimulatedBoard(cert, motion, seed=5, duration_s=motion.duration_s)
        with PtyPair() as pair:
            writer = BoardWriter(pair, board.iter_bytes(0.05), rate_hz=SPEED / 0.05)
            writer.start()
            with DaemonProcess(
                [
                    "--source",
                    f"serial://{pair.slave_path}",
                    "--aiding",
                    f"gpsd://127.0.0.1:{port}",
                    "--no-diagnosis",
                ]
            ) as d:
                first = d.wait_for(lambda s: "aiding" in s and s["t"] is not None)
                assert first["aiding"]["source"] == f"gpsd://127.0.0.1:{port}"
                used = d.wait_for(
                    lambda s: s["aiding"]["in_use"] and s["aiding"]["f0"]["checked"] >= 30,
                    timeout_s=60.0,
                )
                a = used["aiding"]
                assert a["link"] == "connected" and a["reason"] == ""
                assert a["mode"] == 3 and a["fixes"] > 100
                # a healthy unit in motion: no fault; single epochs may fail at the 3-sigma
                # threshold (the two streams' pacing jitter at 5 x real time adds to it)
                assert not a["f0"]["fault"] and a["f0"]["failed"] <= 0.05 * a["f0"]["checked"]
                assert not [f for f in used["faults"] if f.get("source") == "moving_base"], used
                # and the static path takes no manoeuvre of the drive for rest (issue 15,
                # "rest is rest"): no fault at all
                assert used["faults"] == [], used
                # the lever arm is estimated (none configured), reported with its std
                lev = a["lever_arm"]
                assert lev["configured"] is False and len(a["lever_arm_m"]) == 3
                assert len(lev["estimate_m"]) == 3 and len(lev["std_m"]) == 3
                # the gyros in turns against the GNSS course rate, the assumption stated
                turns = a["gyro_turns"]
                assert "no-slip" in turns["assumption"] and turns["faults"] == []
                assert turns["verdict"] in ("ok", "unknown")
                accel_checked = used["f0"]["accel"]["checked"]
                # gpsd goes away: the status says why, the static checks carry on at stops
                gf.terminate()
                gf.wait(10)
                lost = d.wait_for(lambda s: not s["aiding"]["in_use"], timeout_s=20.0)
                assert lost["aiding"]["link"] == "disconnected"
                assert "gpsd" in lost["aiding"]["reason"]
                later = d.wait_for(
                    lambda s: s["f0"]["accel"]["checked"] > accel_checked + 1000,
                    timeout_s=60.0,
                )
                assert later["state"] != "no_data" and not later["aiding"]["in_use"]
            writer.stop()
    finally:
        if gf.poll() is None:
            gf.kill()

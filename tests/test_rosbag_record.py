"""A ROS 1 bag recorded by ROS 1's own recorder, as a user records one: a real ``rosmaster``
on a free loopback port, Debian's ``rosbag record`` (``/usr/lib/rosbag/record``, the C++
recorder of ROS Noetic) subscribed to ``/imu/data``, and a rospy node publishing the real
imucal session (tests/data/real/imucal-ferraris, SOURCE.md there) as
``sensor_msgs/Imu``. The recorder stops by itself after ``LIMIT`` messages (``--limit``);
the publisher sends more (``N``) at the session's own rate, since a subscriber that has
just connected may miss the first few: every recorded sample must be the published
sample of its stamp, value for value, in order. Skipped with the reason where Debian's
``python3-rosbag``, ``python3-rosmaster`` and ``python3-sensor-msgs`` are not installed
(.ci/run installs them where it can)."""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag1 import Reader  # the [test] extra installs rosbags

from imudiag.cli import main
from imudiag.logs import read_log

pytestmark = pytest.mark.realtime  # processes (a ROS master, a recorder) and signals

IMUCAL = Path(__file__).parent / "data" / "real" / "imucal-ferraris" / "session.csv.gz"
EPOCH = 1_650_000_000  # s: the stamps' origin (a Unix time)
N = 600  # messages published: the session's first 5.9 s (about 102 Hz)
LIMIT = 500  # messages the recorder keeps
RECORD = Path("/usr/lib/rosbag/record")
SYSTEM_PYTHON = shutil.which("python3", path="/usr/bin")
MASTER = shutil.which("rosmaster", path="/usr/bin")
PUBLISHER = r"""
import json, sys, time
import rospy
from sensor_msgs.msg import Imu
d = json.load(sys.stdin)
rospy.init_node("imu_publisher", disable_signals=True)
pub = rospy.Publisher("/imu/data", Imu, queue_size=len(d["sec"]))
deadline = time.monotonic() + 60
while pub.get_num_connections() == 0:  # the recorder's subscription
    if time.monotonic() > deadline:
        sys.exit("the recorder never subscribed")
    time.sleep(0.01)
rate = rospy.Rate(d["rate_hz"])
for i, (sec, nsec, g, a) in enumerate(zip(d["sec"], d["nsec"], d["gyro"], d["accel"])):
    m = Imu()
    m.header.seq = i
    m.header.stamp = rospy.Time(sec, nsec)
    m.header.frame_id = "imu_link"
    m.orientation.w = 1.0
    m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z = g
    m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z = a
    pub.publish(m)
    rate.sleep()  # the session's own sample rate, as a driver publishes
while pub.get_num_connections() > 0:  # until the recorder has its messages and leaves
    if time.monotonic() > deadline:
        sys.exit("the recorder never finished")
    time.sleep(0.01)
"""


def _missing() -> str | None:
    if not (SYSTEM_PYTHON and MASTER and RECORD.is_file()):
        return "rosmaster or /usr/lib/rosbag/record not installed"
    probe = subprocess.run(
        [SYSTEM_PYTHON, "-c", "import rospy, sensor_msgs.msg"], capture_output=True, check=False
    )
    return None if probe.returncode == 0 else "the system Python has no rospy / sensor_msgs"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture
def recorded(tmp_path):
    """The bag ``rosbag record`` wrote, and the samples published: (path, t, gyro, accel)."""
    why = _missing()
    if why:
        pytest.skip(f"{why} (apt-get install python3-rosbag python3-rosmaster python3-sensor-msgs)")
    s = read_log(IMUCAL)  # deg/s and m/s^2
    t_ns = EPOCH * 10**9 + np.round(s.t[:N] * 1e9).astype(np.int64)
    gyro, accel = np.radians(s.gyro[:N]), s.accel[:N]
    port = _free_port()
    env = dict(
        os.environ,
        ROS_MASTER_URI=f"http://127.0.0.1:{port}",
        ROS_IP="127.0.0.1",
        ROS_HOME=str(tmp_path / "ros"),
        ROS_LOG_DIR=str(tmp_path / "ros" / "log"),
    )
    bag = tmp_path / "session.bag"
    record: subprocess.Popen[str] | None = None
    master = subprocess.Popen(
        [MASTER, "--core", "-p", str(port)],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        record = subprocess.Popen(
            [str(RECORD), "-O", str(bag), "--limit", str(LIMIT), "/imu/data"],
            env=env,
            cwd=tmp_path,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        data = {
            "sec": (t_ns // 10**9).tolist(),
            "nsec": (t_ns % 10**9).tolist(),
            "gyro": gyro.tolist(),
            "accel": accel.tolist(),
            "rate_hz": float(1 / np.median(np.diff(s.t[:N]))),
        }
        pub = subprocess.run(
            [SYSTEM_PYTHON, "-c", PUBLISHER],
            input=json.dumps(data),
            env=env,
            capture_output=True,
            text=True,
            timeout=120,
            check=False,
        )
        try:
            out, _ = record.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            record.kill()
            out, _ = record.communicate()
        assert pub.returncode == 0, f"publisher: {pub.stderr}\nrecorder: {out}"
        assert record.returncode == 0, out
    finally:
        for proc in (record, master):
            if proc is not None and proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
                try:
                    proc.wait(timeout=30)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()
    return bag, t_ns, gyro, accel


def test_a_bag_recorded_by_rosbag_record_reads_sample_for_sample(recorded, tmp_path):
    bag, t_ns, gyro, accel = recorded
    with Reader(bag) as r:  # what the recorder wrote: its connection carries the publisher
        (conn,) = r.connections
        assert conn.msgtype == "sensor_msgs/msg/Imu" and conn.msgcount == LIMIT
        assert conn.ext.callerid == "/imu_publisher"
    b = read_log(bag)
    assert len(b) == LIMIT and b.meta["skipped_stamps"] == 0
    idx = np.searchsorted(t_ns, np.round(b.t * 1e9).astype(np.int64) - 1000)  # -1 us: float t
    assert np.all(np.abs(t_ns[idx] * 1e-9 - b.t) < 1e-6)  # each stamp is a published one
    assert np.all(np.diff(idx) > 0)  # in the order published
    np.testing.assert_array_equal(b.gyro, gyro[idx])
    np.testing.assert_array_equal(b.accel, accel[idx])
    out = tmp_path / "d.json"
    cert = Path(__file__).parent / "data" / "interop" / "like-si.yaml"
    args = ["diagnose", str(bag), "-c", str(cert), "--json", str(out), "-q", "--no-windows"]
    assert main(args) == 0
    assert json.loads(out.read_text())["samples"] == LIMIT

"""ROS 1 bags written by ROS 1's own writer: Debian's ``python3-rosbag`` (the real
``rosbag.Bag`` of ROS Noetic, with ``python3-sensor-msgs`` and ``python3-geometry-msgs``),
run by the system Python in a subprocess. Skipped with the reason where those packages
are not installed (``apt-get install python3-rosbag python3-sensor-msgs
python3-geometry-msgs``; .ci/run installs them where it can). The samples are the real
imucal session (tests/data/real/imucal-ferraris, SOURCE.md there).
"""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from imudiag.logs import open_log, read_log

IMUCAL = Path(__file__).parent / "data" / "real" / "imucal-ferraris" / "session.csv.gz"
EPOCH = 1_600_000_000
SYSTEM_PYTHON = shutil.which("python3", path="/usr/bin")
WRITER = r"""
import json, sys
import rosbag, rospy
from sensor_msgs.msg import Imu, NavSatFix, NavSatStatus
from geometry_msgs.msg import TwistStamped
d = json.load(sys.stdin)
with rosbag.Bag(d["out"], "w") as bag:
    for i, (t, g, a) in enumerate(zip(d["t"], d["gyro"], d["accel"])):
        m = Imu()
        m.header.seq = i
        m.header.stamp = rospy.Time.from_sec(t)
        m.header.frame_id = "imu_link"
        m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z = g
        m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z = a
        bag.write("/imu/data", m, m.header.stamp + rospy.Duration(0, 1000000))
    for k, t in enumerate(d["fix_t"]):
        f = NavSatFix()
        f.header.stamp = rospy.Time.from_sec(t)
        f.status.status = NavSatStatus.STATUS_FIX
        f.latitude, f.longitude, f.altitude = 48.1 + 1e-6 * k, 11.5, 520.0
        bag.write("/fix", f, f.header.stamp)
        v = TwistStamped()
        v.header.stamp = f.header.stamp
        v.twist.linear.x, v.twist.linear.y, v.twist.linear.z = 3.0, 4.0, 0.0
        bag.write("/vel", v, v.header.stamp)
"""


def _ros1_available() -> str | None:
    if SYSTEM_PYTHON is None:
        return "no system python3"
    probe = "import rosbag, rospy, sensor_msgs.msg, geometry_msgs.msg"
    r = subprocess.run([SYSTEM_PYTHON, "-c", probe], capture_output=True, text=True, check=False)
    if r.returncode != 0:
        return "ROS 1's writer is not installed (apt-get install python3-rosbag " \
            "python3-sensor-msgs python3-geometry-msgs)"  # fmt: skip
    return None


@pytest.fixture(scope="module")
def ros1_bag(tmp_path_factory):
    why = _ros1_available()
    if why:
        pytest.skip(why)
    s = read_log(IMUCAL).slice(0, 500)
    out = tmp_path_factory.mktemp("ros1") / "drive.bag"
    data = {
        "out": str(out),
        "t": (EPOCH + s.t).tolist(),
        "gyro": np.radians(s.gyro).tolist(),
        "accel": s.accel.tolist(),
        "fix_t": (EPOCH + s.t[0] + 0.2 * np.arange(20)).tolist(),
    }
    r = subprocess.run([SYSTEM_PYTHON, "-c", WRITER], input=json.dumps(data), text=True,
                       capture_output=True, check=False, timeout=120)  # fmt: skip
    assert r.returncode == 0, r.stderr
    return out, s


def test_a_bag_written_by_ros1_rosbag_reads_sample_for_sample(ros1_bag):
    path, s = ros1_bag
    assert path.read_bytes().startswith(b"#ROSBAG V2.0")
    got = read_log(path)
    assert len(got) == len(s)
    np.testing.assert_allclose(got.t, EPOCH + s.t, rtol=0, atol=1e-6)  # ROS 1 stamps: ns
    np.testing.assert_array_equal(got.gyro, np.radians(s.gyro))
    np.testing.assert_array_equal(got.accel, s.accel)


def test_its_navsatfix_and_twist_are_the_bags_gnss(ros1_bag):
    path, _ = ros1_bag
    with open_log(path) as r:
        g = r.gnss()
    assert len(g) == 20 and "/fix" in g.source and "velocity /vel" in g.source
    np.testing.assert_allclose(g.vel_ned, [[4.0, 3.0, -0.0]] * 20)  # ENU (3, 4, 0) -> NED
    np.testing.assert_allclose(g.lat_deg, 48.1 + 1e-6 * np.arange(20))

"""A real ROS 1 bag written by ROS's own rosbag tools (tests/data/real/ros1-pr2-joint-states,
SOURCE.md there): a PR2's joint states recorded before ROS Electric, whose stored definitions
name the old ``roslib/Header``. It holds no IMU: imudiag opens it and says so with the topic
it has; its definitions decode every message as the raw ROS 1 bytes say."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag1 import Reader, Writer  # the [test] extra installs rosbags
from rosbags.typesys import Stores, get_typestore

from imudiag.cli import main
from imudiag.logs import LogError, read_log
from imudiag.logs.rosbag import ros1_typestore

BAG = Path(__file__).parent / "data" / "real" / "ros1-pr2-joint-states" / "joint_states_indexed.bag"
MD5 = "3066dcd76a6cfaef579bd0f34173e9fd"  # sensor_msgs/JointState, as stored in the bag
TOPICS = "its topics: joint_states (sensor_msgs/msg/JointState, 1598 messages)"


def test_recorder_written_bag_without_imu_names_its_topics():
    with pytest.raises(LogError) as err:
        read_log(BAG)
    assert f"no sensor_msgs/msg/Imu topic in the bag ({TOPICS})" in str(err.value)
    assert str(BAG) in str(err.value)


@pytest.mark.parametrize("command", ["allan", "convert", "diagnose"])
def test_every_log_command_refuses_it_in_one_line(command, capsys, tmp_path):
    args = {
        "allan": [str(BAG)],
        "convert": [str(BAG), str(tmp_path / "out.csv")],
        "diagnose": [str(BAG), "-c", str(Path(__file__).parent / "data/interop/like-si.yaml")],
    }[command]
    assert main([command, *args]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert TOPICS in err and str(BAG) in err
    assert not (tmp_path / "out.csv").exists()


def test_a_named_topic_that_is_not_there_lists_the_other_topics(capsys):
    assert main(["allan", str(BAG), "--topic", "/imu/data"]) == 2
    err = capsys.readouterr().err
    assert "--topic /imu/data: no sensor_msgs/msg/Imu messages on it (IMU topics: none;" in err
    assert "other topics: joint_states (sensor_msgs/msg/JointState, 1598 messages)" in err


def test_old_roslib_header_definitions_decode_every_message_as_its_bytes_say():
    """The stored definition names ``roslib/Header``: the typestore built from it passes the
    connection's MD5 and decodes seq, stamp and frame of every message exactly as the raw
    ROS 1 serialization (uint32 seq, sec, nsec) and the joint names as the bytes hold them."""
    with Reader(BAG) as r:
        (conn,) = r.connections
        assert conn.msgtype == "sensor_msgs/msg/JointState" and conn.digest == MD5
        assert "MSG: roslib/Header" in conn.msgdef.data
        store = ros1_typestore(r.connections, str(BAG))
        assert store.generate_msgdef(conn.msgtype)[1] == MD5
        count, seqs = 0, []
        for c, _bag_ns, raw in r.messages():
            msg = store.deserialize_ros1(raw, c.msgtype)
            seq, sec, nsec = struct.unpack_from("<III", raw)
            assert (msg.header.seq, msg.header.stamp.sec, msg.header.stamp.nanosec) == (
                seq,
                sec,
                nsec,
            )
            (n_frame,) = struct.unpack_from("<I", raw, 12)
            (n_names,) = struct.unpack_from("<I", raw, 16 + n_frame)
            assert len(msg.name) == n_names == len(msg.position) > 0
            count += 1
            seqs.append(seq)
    assert count == 1598
    assert seqs == list(range(seqs[0], seqs[0] + 1598))  # no message lost or repeated


def test_a_definition_that_does_not_match_its_md5_is_refused(tmp_path):
    bad = tmp_path / "tampered.bag"
    data = BAG.read_bytes()
    assert data.count(f"md5sum={MD5}".encode()) >= 1
    bad.write_bytes(data.replace(f"md5sum={MD5}".encode(), b"md5sum=" + b"0" * 32))
    with pytest.raises(LogError) as err:
        read_log(bad)
    text = str(err.value)
    assert "stored definition of sensor_msgs/msg/JointState does not match its MD5" in text
    assert str(bad) in text


def test_an_imu_bag_with_pre_electric_definitions_reads_its_samples(tmp_path):
    """The IMU path of the old header: a ROS 1 bag whose stored Imu definition names
    ``Header`` / ``roslib/Header`` as bags before ROS Electric do (same MD5 as today's),
    written by rosbags with that definition and the real imucal session's first samples
    (tests/data/real/imucal-ferraris): read sample for sample (rosbags alone refuses it)."""
    session = read_log(Path(__file__).parent / "data/real/imucal-ferraris/session.csv.gz")
    n = 200
    store = get_typestore(Stores.ROS1_NOETIC)
    msgdef, md5 = store.generate_msgdef("sensor_msgs/msg/Imu")
    old = msgdef.replace("std_msgs/Header header", "Header header")
    old = old.replace("MSG: std_msgs/Header", "MSG: roslib/Header")
    assert "roslib/Header" in old and "std_msgs" not in old
    T = store.types
    w = np.radians(session.gyro[:n])  # the session is in deg/s; Imu is rad/s
    a = session.accel[:n]
    path = tmp_path / "old.bag"
    with Writer(path) as bag:
        conn = bag.add_connection("/imu", "sensor_msgs/msg/Imu", msgdef=old, md5sum=md5)
        for i in range(n):
            t_ns = 1_300_000_000 * 10**9 + int(round(session.t[i] * 1e9))
            sec, nsec = divmod(t_ns, 10**9)
            stamp = T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec)
            vec, quat = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"]
            msg = T["sensor_msgs/msg/Imu"](
                header=T["std_msgs/msg/Header"](seq=i, stamp=stamp, frame_id="imu"),
                orientation=quat(x=0.0, y=0.0, z=0.0, w=1.0),
                orientation_covariance=np.zeros(9),
                angular_velocity=vec(x=w[i, 0], y=w[i, 1], z=w[i, 2]),
                angular_velocity_covariance=np.zeros(9),
                linear_acceleration=vec(x=a[i, 0], y=a[i, 1], z=a[i, 2]),
                linear_acceleration_covariance=np.zeros(9),
            )
            bag.write(conn, t_ns, store.serialize_ros1(msg, "sensor_msgs/msg/Imu"))
    b = read_log(path)
    assert len(b) == n
    np.testing.assert_array_equal(b.gyro, w)
    np.testing.assert_array_equal(b.accel, a)
    np.testing.assert_allclose(b.t - 1_300_000_000, session.t[:n], rtol=0, atol=1e-6)

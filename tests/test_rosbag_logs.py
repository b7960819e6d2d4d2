"""ROS bags written by the rosbags library itself (ROS 2 sqlite3 and MCAP, ROS 1), holding a
real recording: the imucal Ferraris session (tests/data/real/imucal-ferraris, SOURCE.md
there) as sensor_msgs/msg/Imu in rad/s and m/s^2, as a ROS driver would publish it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import run_imudiag, run_imudiag_in_process, run_imudiag_without
from rosbags.rosbag1 import Writer as Writer1  # the [test] extra installs rosbags
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from imudiag.logs import LogError, LogOptions, lookup, open_log, read_log

IMUCAL = Path(__file__).parent / "data" / "real" / "imucal-ferraris" / "session.csv.gz"
EPOCH = 1_700_000_000  # s, the stamps' origin (a Unix time)


@pytest.fixture(scope="module")
def session():
    return read_log(IMUCAL)  # deg/s and m/s^2


def _messages(store, s, stamps=True):
    imu = store.types["sensor_msgs/msg/Imu"]
    header, time_t = store.types["std_msgs/msg/Header"], store.types["builtin_interfaces/msg/Time"]
    vec, quat = (
        store.types["geometry_msgs/msg/Vector3"],
        store.types["geometry_msgs/msg/Quaternion"],
    )
    w = np.radians(s.gyro)
    for i in range(len(s)):
        t_ns = EPOCH * 10**9 + int(round(s.t[i] * 1e9))
        sec, nsec = divmod(t_ns, 10**9) if stamps else (0, 0)
        kw = {"stamp": time_t(sec=sec, nanosec=nsec), "frame_id": "imu_link"}
        if "seq" in header.__dataclass_fields__:
            kw["seq"] = i
        msg = imu(
            header=header(**kw),
            orientation=quat(x=0.0, y=0.0, z=0.0, w=1.0),
            orientation_covariance=np.zeros(9),
            angular_velocity=vec(x=w[i, 0], y=w[i, 1], z=w[i, 2]),
            angular_velocity_covariance=np.zeros(9),
            linear_acceleration=vec(x=s.accel[i, 0], y=s.accel[i, 1], z=s.accel[i, 2]),
            linear_acceleration_covariance=np.zeros(9),
        )
        yield t_ns + 2_000_000, msg  # received 2 ms after the stamp


def write_ros2(path: Path, s, plugin=StoragePlugin.SQLITE3, topics=("/imu/data",), stamps=True):
    store = get_typestore(Stores.ROS2_HUMBLE)
    with Writer(path, version=8, storage_plugin=plugin) as w:
        conns = [w.add_connection(t, "sensor_msgs/msg/Imu", typestore=store) for t in topics]
        for t_ns, msg in _messages(store, s, stamps):
            data = store.serialize_cdr(msg, "sensor_msgs/msg/Imu")
            for c in conns:
                w.write(c, t_ns, data)
    return path


def write_ros1(path: Path, s):
    store = get_typestore(Stores.ROS1_NOETIC)
    with Writer1(path) as w:
        conn = w.add_connection("/imu/data", "sensor_msgs/msg/Imu", typestore=store)
        for t_ns, msg in _messages(store, s):
            w.write(conn, t_ns, store.serialize_ros1(msg, "sensor_msgs/msg/Imu"))
    return path


def _same_samples(got, s):
    assert len(got) == len(s)
    np.testing.assert_allclose(got.t - EPOCH, s.t, atol=2e-6)
    np.testing.assert_allclose(got.gyro, np.radians(s.gyro), rtol=1e-12, atol=0)
    np.testing.assert_allclose(got.accel, s.accel, rtol=1e-12, atol=0)


def test_ros2_sqlite_bag_directory(tmp_path, session):
    bag = write_ros2(tmp_path / "session_bag", session)
    assert lookup(bag).name == "rosbag2"
    with open_log(bag) as reader:
        got = next(iter([b for b in reader]))
        meta = dict(reader.meta)
    _same_samples(got, session)
    assert meta["units"] == {"gyro": "rad/s", "accel": "m/s^2"}
    assert meta["source"] == f"sensor_msgs/msg/Imu on /imu/data ({len(session)} messages)"
    # the single .db3 file of the directory reads the same
    db3 = next(bag.glob("*.db3"))
    _same_samples(read_log(db3), session)


def test_ros2_mcap_file(tmp_path, session):
    bag = write_ros2(tmp_path / "mcap_bag", session, plugin=StoragePlugin.MCAP)
    mcap = next(bag.glob("*.mcap"))
    assert lookup(mcap).name == "rosbag2"
    _same_samples(read_log(mcap), session)


def test_ros1_bag(tmp_path, session):
    bag = write_ros1(tmp_path / "session.bag", session)
    assert lookup(bag).name == "rosbag1"
    _same_samples(read_log(bag), session)


def test_commands_read_a_bag_in_blocks_and_convert_keeps_its_source(tmp_path, session):
    bag = write_ros1(tmp_path / "session.bag", session)
    with open_log(bag, block_size=1000) as reader:
        sizes = [len(b) for b in reader]
    assert sizes[0] == 1000 and sum(sizes) == len(session)
    out = tmp_path / "session.csv"
    r = run_imudiag("convert", str(bag), str(out))
    assert r.returncode == 0, r.stderr
    head = [x for x in out.read_text().splitlines()[:6] if x.startswith("#")]
    assert any(x.startswith("# source: sensor_msgs/msg/Imu on /imu/data") for x in head)
    # the conversion above is the real subprocess; allan in process
    r = run_imudiag_in_process("allan", str(bag))
    assert r.returncode == 0, r.stderr
    assert f"{len(session)} samples at 102.39" in r.stdout and " 0 gaps" in r.stdout


def test_several_imu_topics_need_topic_and_list_them(tmp_path, session):
    short = session.slice(0, 300)
    bag = write_ros2(tmp_path / "two", short, topics=("/imu/data", "/imu/raw"))
    with pytest.raises(
        LogError,
        match=r"2 IMU topics: choose one with --topic "
        r"\(/imu/data \(300 messages\), /imu/raw \(300 messages\)\)",
    ):
        open_log(bag)
    with open_log(bag, options=LogOptions(topic="/imu/raw")) as reader:
        assert sum(len(b) for b in reader) == 300
        assert reader.meta["source"].endswith("on /imu/raw (300 messages)")
    # in process: test_not_a_bag_is_exit_2 refuses a bag in a real subprocess
    r = run_imudiag_in_process("allan", str(bag), "--topic", "/imu/other")
    assert r.returncode == 2
    assert "--topic /imu/other: no sensor_msgs/msg/Imu messages on it" in r.stderr
    assert "/imu/data (300 messages)" in r.stderr


def test_unset_stamps_use_the_bag_time_and_say_so(tmp_path, session):
    short = session.slice(0, 200)
    bag = write_ros2(tmp_path / "nostamp", short, stamps=False)
    with open_log(bag) as reader:
        got = next(iter(reader))
        assert "bag receive time (header stamps unset)" in reader.meta["source"]
    np.testing.assert_allclose(got.t - EPOCH, short.t + 0.002, atol=2e-6)


def test_not_a_bag_is_exit_2(tmp_path):
    fake = tmp_path / "fake.bag"
    fake.write_text("hello\n")
    r = run_imudiag("allan", str(fake))
    assert r.returncode == 2 and "not a ROS bag" in r.stderr and str(fake) in r.stderr


def test_missing_rosbags_is_exit_2_with_the_pip_command(tmp_path, session):
    bag = write_ros1(tmp_path / "s.bag", session.slice(0, 100))
    r = run_imudiag_without("rosbags", "allan", str(bag))
    assert r.returncode == 2, r.stderr
    assert "'rosbags'" in r.stderr and "pip install 'imudiag[ros]'" in r.stderr
    assert "Traceback" not in r.stderr


def test_a_repeated_stamp_is_skipped_and_counted_not_reordered(tmp_path, session):
    short = session.slice(0, 200)
    t = short.t.copy()
    t[50] = t[49]  # a driver that stamped two messages alike
    short = type(short)(t=t, gyro=short.gyro, accel=short.accel)
    bag = write_ros2(tmp_path / "repeat", short)
    with open_log(bag) as reader:
        n = sum(len(b) for b in reader)
        assert reader.meta["skipped_stamps"] == 1
    assert n == 199

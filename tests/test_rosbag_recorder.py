"""ROS 2 bags as ``ros2 bag record`` writes them: a sqlite3 ``.db3`` beside a metadata.yaml,
and no message definitions stored in the bag (every recorder from Foxy to Iron).

No recorder-written bag is available from a package registry (Debian carries no rosbag2;
see docs/logs.md), so these bags are written through the lowest real layer: sqlite3 with
the recorder's own schema (Foxy: ``topics`` and ``messages`` only; Humble: schema version 3
with the ``schema`` and ``metadata`` tables), the metadata.yaml the recorder writes
(versions 4 and 5), and CDR bytes from rosbags' serializer. The samples are the real imucal
session (tests/data/real/imucal-ferraris, SOURCE.md there).
"""

from __future__ import annotations

import json
import shutil
import sqlite3
from pathlib import Path

import numpy as np
import pytest
import yaml
from rosbags.typesys import Stores, get_typestore

from imudiag.cli import main
from imudiag.logs import LogOptions, open_log, read_log

IMUCAL = Path(__file__).parent / "data" / "real" / "imucal-ferraris" / "session.csv.gz"
SI_CERT = Path(__file__).parent / "data" / "interop" / "like-si.yaml"
EPOCH_NS = 1_614_592_800 * 10**9
N = 600
QOS = (
    "- history: 3\n  depth: 0\n  reliability: 1\n  durability: 2\n  deadline:\n    sec: "
    "2147483647\n    nsec: 4294967295\n  lifespan:\n    sec: 2147483647\n    nsec: 4294967295\n"
    "  liveliness: 1\n  liveliness_lease_duration:\n    sec: 2147483647\n    nsec: 4294967295\n"
    "  avoid_ros_namespace_conventions: false"
)
FOXY_SCHEMA = [
    "CREATE TABLE topics(id INTEGER PRIMARY KEY,name TEXT NOT NULL,type TEXT NOT NULL,"
    "serialization_format TEXT NOT NULL,offered_qos_profiles TEXT NOT NULL);",
    "CREATE TABLE messages(id INTEGER PRIMARY KEY,topic_id INTEGER NOT NULL,"
    "timestamp INTEGER NOT NULL, data BLOB NOT NULL);",
    "CREATE INDEX timestamp_idx ON messages (timestamp ASC);",
]
HUMBLE_SCHEMA = [
    "CREATE TABLE schema(schema_version INTEGER PRIMARY KEY,ros_distro TEXT NOT NULL);",
    "CREATE TABLE metadata(id INTEGER PRIMARY KEY,metadata_version INTEGER NOT NULL,"
    "metadata TEXT NOT NULL);",
    *FOXY_SCHEMA,
]


@pytest.fixture(scope="module")
def session():
    return read_log(IMUCAL).slice(0, N)  # deg/s, m/s^2


def _messages(session):
    """(topic, type, receive ns, CDR bytes) as a driver publishes them: IMU at 102.4 Hz,
    NavSatFix and a TwistWithCovarianceStamped velocity (ENU) at 5 Hz."""
    st = get_typestore(Stores.ROS2_HUMBLE)
    T = st.types
    time_t, header = T["builtin_interfaces/msg/Time"], T["std_msgs/msg/Header"]
    vec = T["geometry_msgs/msg/Vector3"]

    def hdr(ns):
        return header(stamp=time_t(sec=ns // 10**9, nanosec=ns % 10**9), frame_id="base")

    w = np.radians(session.gyro)
    out = []
    for i in range(len(session)):
        ns = EPOCH_NS + int(round(session.t[i] * 1e9))
        msg = T["sensor_msgs/msg/Imu"](
            header=hdr(ns),
            orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
            orientation_covariance=np.zeros(9),
            angular_velocity=vec(x=w[i, 0], y=w[i, 1], z=w[i, 2]),
            angular_velocity_covariance=np.zeros(9),
            linear_acceleration=vec(*session.accel[i]),
            linear_acceleration_covariance=np.zeros(9),
        )
        out.append(
            (
                "/imu/data",
                "sensor_msgs/msg/Imu",
                ns + 1_000_000,
                st.serialize_cdr(msg, msg.__msgtype__),
            )
        )
    t0 = EPOCH_NS + int(round(session.t[0] * 1e9))
    for k in range(int((session.t[-1] - session.t[0]) * 5)):
        ns = t0 + k * 200_000_000
        status = T["sensor_msgs/msg/NavSatStatus"](status=0, service=1)
        fix = T["sensor_msgs/msg/NavSatFix"](
            header=hdr(ns), status=status, latitude=49.5 + 1e-6 * k, longitude=11.0,
            altitude=300.0, position_covariance=np.zeros(9), position_covariance_type=0,
        )  # fmt: skip
        out.append(
            ("/gnss/fix", fix.__msgtype__, ns + 5_000_000, st.serialize_cdr(fix, fix.__msgtype__))
        )
        cov = np.zeros(36)
        cov[0] = cov[7] = 0.04
        twist = T["geometry_msgs/msg/TwistWithCovarianceStamped"](
            header=hdr(ns),
            twist=T["geometry_msgs/msg/TwistWithCovariance"](
                twist=T["geometry_msgs/msg/Twist"](
                    linear=vec(x=1.0, y=2.0, z=0.5), angular=vec(x=0.0, y=0.0, z=0.0)
                ),
                covariance=cov,
            ),
        )
        out.append(
            (
                "/gnss/fix_velocity",
                twist.__msgtype__,
                ns + 5_000_000,
                st.serialize_cdr(twist, twist.__msgtype__),
            )
        )
    return sorted(out, key=lambda m: m[2])


def write_recorder_bag(folder: Path, session, distro: str) -> Path:
    """A bag as ``ros2 bag record`` of ``distro`` (foxy or humble) writes it: no message
    definitions anywhere, the metadata.yaml the recorder writes on close."""
    folder.mkdir()
    db = folder / f"{folder.name}_0.db3"
    msgs = _messages(session)
    topics = sorted({(m[0], m[1]) for m in msgs})
    con = sqlite3.connect(db)
    for stmt in HUMBLE_SCHEMA if distro == "humble" else FOXY_SCHEMA:
        con.execute(stmt)
    if distro == "humble":
        con.execute("INSERT INTO schema VALUES(3, 'humble')")
    ids = {name: k + 1 for k, (name, _) in enumerate(topics)}
    for (name, typ), k in zip(topics, ids.values(), strict=True):
        con.execute("INSERT INTO topics VALUES(?,?,?,?,?)", (k, name, typ, "cdr", QOS))
    con.executemany(
        "INSERT INTO messages(topic_id, timestamp, data) VALUES(?,?,?)",
        [(ids[m[0]], m[2], m[3]) for m in msgs],
    )
    start, end = msgs[0][2], msgs[-1][2]
    info = {
        "version": 4 if distro == "foxy" else 5,
        "storage_identifier": "sqlite3",
        "relative_file_paths": [db.name],
        "duration": {"nanoseconds": end - start},
        "starting_time": {"nanoseconds_since_epoch": start},
        "message_count": len(msgs),
        "topics_with_message_count": [
            {
                "topic_metadata": {
                    "name": name,
                    "type": typ,
                    "serialization_format": "cdr",
                    "offered_qos_profiles": QOS,
                },
                "message_count": sum(m[0] == name for m in msgs),
            }
            for name, typ in topics
        ],
        "compression_format": "",
        "compression_mode": "",
    }
    if distro == "humble":
        info["files"] = [
            {
                "path": db.name,
                "starting_time": {"nanoseconds_since_epoch": start},
                "duration": {"nanoseconds": end - start},
                "message_count": len(msgs),
            }
        ]
        text = yaml.safe_dump({"rosbag2_bagfile_information": info}, sort_keys=False)
        con.execute("INSERT INTO metadata VALUES(1, 5, ?)", (text,))
    con.commit()
    con.close()
    (folder / "metadata.yaml").write_text(
        yaml.safe_dump({"rosbag2_bagfile_information": info}, sort_keys=False)
    )
    return folder


@pytest.fixture(scope="module")
def bags(tmp_path_factory, session):
    """The same session as a Foxy and as a Humble recorder writes it."""
    return {
        d: write_recorder_bag(tmp_path_factory.mktemp(d) / "rosbag2_2021_03_01", session, d)
        for d in ("foxy", "humble")
    }


@pytest.fixture(params=["foxy", "humble"])
def bag(request, bags):
    return bags[request.param]


def _same(got, s):
    assert len(got) == len(s)
    np.testing.assert_allclose(got.t, EPOCH_NS * 1e-9 + s.t, rtol=0, atol=2e-6)
    np.testing.assert_allclose(got.gyro, np.radians(s.gyro), rtol=1e-12)
    np.testing.assert_allclose(got.accel, s.accel, rtol=1e-12)


@pytest.mark.parametrize(
    ("distro", "which", "topic"),
    [
        ("foxy", "folder", None),
        ("foxy", "folder", "/imu/data"),
        ("foxy", "db3", None),
        ("foxy", "db3", "/imu/data"),
        ("humble", "db3", None),
    ],
)
def test_a_recorder_bag_without_definitions_reads_from_folder_or_db3(
    bags, session, distro, which, topic
):
    bag = bags[distro]
    path = bag if which == "folder" else next(bag.glob("*.db3"))
    with open_log(path, options=LogOptions(topic=topic)) as r:
        got = read_log_of(r)
        assert "ros_distro" in r.meta
    _same(got, session)


def read_log_of(reader):
    from imudiag.samples import SampleBlock

    return SampleBlock.concat(list(reader))


def test_the_distribution_comes_from_the_bag_else_the_option(bag, tmp_path):
    with open_log(bag) as r:
        distro = r.meta["ros_distro"]
    if bag.parent.name.startswith("humble"):
        assert distro.startswith("humble (the .db3's schema table")
    else:
        assert distro.startswith("lyrical (the default")
        with open_log(bag, options=LogOptions(ros_distro="foxy")) as r:
            assert r.meta["ros_distro"] == "foxy (--ros-distro)"


def test_a_lone_db3_without_its_metadata_reads(bags, session, tmp_path):
    bag = bags["humble"]
    db = tmp_path / "copy.db3"
    shutil.copy(next(bag.glob("*.db3")), db)
    with open_log(db) as r:
        _same(read_log_of(r), session)


def test_every_command_reads_the_bag_and_no_library_hint_reaches_the_user(bags, tmp_path, capsys):
    bag = bags["foxy"]
    db = next(bag.glob("*.db3"))
    out = tmp_path / "bag.csv"
    assert main(["convert", str(db), str(out), "--topic", "/imu/data"]) == 0
    _same(read_log(out), read_log(IMUCAL).slice(0, N))
    assert main(["allan", str(bag), "--json", str(tmp_path / "a.json")]) == 0
    rep = tmp_path / "d.json"
    assert main(["diagnose", str(bag), "-c", str(SI_CERT), "--json", str(rep), "-q"]) == 0
    assert json.loads(rep.read_text())["samples"] == N
    code = main(["calibrate", str(bag), "--like", str(SI_CERT), "--out", str(tmp_path / "c.yaml")])
    err = capsys.readouterr().err
    assert code in (0, 2)  # 600 samples of one face may not calibrate: said, not a crash
    assert "default_typestore" not in err and "Traceback" not in err
    assert main(["allan", str(bag), "--ros-distro", "melodic"]) == 2
    assert "--ros-distro: unknown ROS 2 distribution 'melodic'" in capsys.readouterr().err


def test_navsatfix_and_velocity_are_the_bags_gnss(bags):
    bag = bags["foxy"]
    with open_log(bag) as r:
        g = r.gnss()
    assert g is not None and len(g) == 29
    assert "/gnss/fix" in g.source and "/gnss/fix_velocity" in g.source
    assert g.clock.startswith("same clock")
    np.testing.assert_allclose(g.vel_ned, [[2.0, 1.0, -0.5]] * 29)  # ENU (1, 2, 0.5) -> NED
    np.testing.assert_allclose(g.eps, 0.2)
    np.testing.assert_allclose(g.lat_deg, 49.5 + 1e-6 * np.arange(29))

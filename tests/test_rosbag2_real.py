"""Real ROS 2 bags written by rosbag2 itself (tests/data/real/ros2-talker, SOURCE.md there):
the demo talker recorded in 2020 by the Eloquent/Foxy recorder (no message definitions, the
SQLite storage's first schema) and the same recording rewritten by rosbag2 into the schema 4
of Iron and later (a ``schema`` table naming ``rolling``, stored definitions). They hold no
IMU: imudiag opens each, from its folder or its ``.db3``, and says so with the topics they
have; the typestore imudiag picks for a bag without definitions decodes every message the
recorder wrote.

The bags are SQLite databases in WAL mode: opening one writes its ``-shm`` and ``-wal``
files beside it, so the tests read copies (:func:`bags`), never the shipped folders."""

from __future__ import annotations

import re
import shutil
from pathlib import Path
from typing import Any

import pytest
from rosbags.rosbag2 import Reader  # the [test] extra installs rosbags

from imudiag.cli import main
from imudiag.logs import LogError, read_log
from imudiag.logs.rosbag import sqlite_distro, typestore_for

DATA = Path(__file__).parent / "data" / "real" / "ros2-talker"
BAGS = ("2020-foxy", "2023-schema4")
TOPICS = (
    "its topics: /parameter_events (rcl_interfaces/msg/ParameterEvent, 0 messages), "
    "/rosout (rcl_interfaces/msg/Log, 10 messages), /topic (std_msgs/msg/String, 10 messages)"
)


@pytest.fixture(scope="module")
def bags(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Each shipped bag (its metadata.yaml and talker.db3, as shipped) copied to a folder
    of its own name."""
    root = tmp_path_factory.mktemp("ros2-talker")
    for name in BAGS:
        (root / name).mkdir()
        for part in ("metadata.yaml", "talker.db3"):
            shutil.copyfile(DATA / name / part, root / name / part)
    return {name: root / name for name in BAGS}


def _path(bags: dict[str, Path], which: str) -> Path:
    """``2020-foxy`` (the folder) or ``2020-foxy/talker.db3`` (its storage file)."""
    name, _, part = which.partition("/")
    return bags[name] / part if part else bags[name]


def test_the_two_files_are_what_their_source_says(bags):
    foxy, schema4 = bags["2020-foxy"], bags["2023-schema4"]
    assert sqlite_distro(foxy / "talker.db3") is None  # no schema table: before Humble
    assert sqlite_distro(schema4 / "talker.db3") == "rolling"
    for bag in (foxy, schema4):
        with Reader(bag) as r:
            assert {c.topic: c.msgcount for c in r.connections} == {
                "/topic": 10,
                "/rosout": 10,
                "/parameter_events": 0,
            }
            defs = {c.topic: c.msgdef.data for c in r.connections}
        if bag == foxy:
            assert set(defs.values()) == {""}  # the recorder stored no definition
        else:
            assert defs["/topic"] == "string data"


#: each bag as a folder and as its storage file pointed at directly
@pytest.mark.parametrize(
    "which",
    ["2020-foxy", "2020-foxy/talker.db3", "2023-schema4", "2023-schema4/talker.db3"],
)
def test_a_recorder_bag_without_imu_names_its_topics(bags, which):
    path = _path(bags, which)
    with pytest.raises(LogError) as err:
        read_log(path)
    assert f"no sensor_msgs/msg/Imu topic in the bag ({TOPICS})" in str(err.value)
    assert str(path) in str(err.value)


@pytest.mark.parametrize("command", ["allan", "convert", "diagnose", "calibrate"])
@pytest.mark.parametrize("which", ["2020-foxy", "2023-schema4/talker.db3"])
def test_every_log_command_refuses_it_in_one_line(bags, command, which, capsys, tmp_path):
    path = _path(bags, which)
    cert = str(Path(__file__).parent / "data/interop/like-si.yaml")
    args = {
        "allan": [str(path)],
        "convert": [str(path), str(tmp_path / "out.csv")],
        "diagnose": [str(path), "-c", cert],
        "calibrate": [str(path), "--like", cert, "--out", str(tmp_path / "cal.yaml")],
    }[command]
    assert main([command, *args]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert TOPICS in err and str(path) in err
    assert list(tmp_path.iterdir()) == []  # nothing written


@pytest.mark.parametrize("which", BAGS)
def test_a_named_topic_that_is_not_imu_lists_the_others(bags, which, capsys):
    path = _path(bags, which)
    assert main(["allan", str(path), "--topic", "/topic"]) == 2
    err = capsys.readouterr().err
    assert "--topic /topic: no sensor_msgs/msg/Imu messages on it (IMU topics: none;" in err
    assert "other topics: /parameter_events (rcl_interfaces/msg/ParameterEvent, 0 messages)" in err


def test_the_chosen_typestore_decodes_every_message_the_recorder_wrote(bags):
    """No definitions in the 2020 bag and no distribution named: imudiag's choice (the
    default distribution's typestore, :func:`typestore_for`) decodes all 20 messages, and
    the two topics agree: each String the talker published is the one its log line names,
    in order, 0.5 s apart as the talker's timer ran (0.4997 to 0.5304 s)."""
    foxy = bags["2020-foxy"]
    store = typestore_for(sqlite_distro(foxy / "talker.db3"), str(foxy))
    said, logged, stamps = [], [], []
    with Reader(foxy) as r:
        for conn, bag_ns, raw in r.messages():
            msg = store.deserialize_cdr(raw, conn.msgtype)
            if conn.topic == "/topic":
                said.append(msg.data)
                stamps.append(bag_ns)
            else:
                assert conn.topic == "/rosout" and msg.name == "minimal_publisher"
                logged.append(re.fullmatch(r"Publishing: '(.*)'", msg.msg).group(1))
                assert abs(msg.stamp.sec + msg.stamp.nanosec * 1e-9 - bag_ns * 1e-9) < 0.01
    assert said == logged == [f"Hello, world! {i}" for i in range(10)]
    steps = [(b - a) * 1e-9 for a, b in zip(stamps, stamps[1:], strict=False)]
    assert len(steps) == 9 and all(abs(s - 0.5) < 0.05 for s in steps)


def _imu_bag_as_the_2023_talker(folder: Path, n: int, files: int = 1) -> Any:
    """A schema-4 bag (rosbags' writer, as Iron and later record; tests/test_rosbag_logs.py)
    of the real imucal session's first ``n`` samples on /imu/data, whose metadata.yaml then
    states the topic's QoS as the 2023 talker's does (durations 0) while its .db3 keeps the
    writer's; ``files`` > 1: the .db3 copied and listed again (one bag in several files).
    Returns the session's samples written."""
    import yaml

    from tests.test_rosbag_logs import write_ros2

    session = read_log(Path(__file__).parent / "data/real/imucal-ferraris/session.csv.gz")
    written = session.slice(0, n)
    write_ros2(folder, written)
    talker = yaml.safe_load((DATA / "2023-schema4" / "metadata.yaml").read_text())
    qos = talker["rosbag2_bagfile_information"]["topics_with_message_count"][0]
    meta_path = folder / "metadata.yaml"
    meta = yaml.safe_load(meta_path.read_text())
    info = meta["rosbag2_bagfile_information"]
    for topic in info["topics_with_message_count"]:
        topic["topic_metadata"]["offered_qos_profiles"] = qos["topic_metadata"][
            "offered_qos_profiles"
        ]
    (db3,) = folder.glob("*.db3")
    for k in range(1, files):
        copy = folder / f"{folder.name}_{k}.db3"
        copy.write_bytes(db3.read_bytes())
        info["relative_file_paths"].append(copy.name)
    meta_path.write_text(yaml.safe_dump(meta, sort_keys=False))
    return written


def test_an_imu_bag_whose_metadata_yaml_disagrees_with_its_db3_reads_every_sample(tmp_path):
    """rosbags reads no message of a topic whose metadata.yaml record differs from the
    .db3's (the 2023 talker's state, above): the folder read as an empty log. imudiag now
    reads the bag's one storage file itself, every sample, and says so."""
    from tests.test_rosbag_logs import _same_samples

    n = 1500
    folder = tmp_path / "imu_bag"
    written = _imu_bag_as_the_2023_talker(folder, n)
    with Reader(folder) as r:  # the state: rosbags alone reads nothing through the folder
        assert {c.topic: c.msgcount for c in r.connections} == {"/imu/data": n}
        assert next(iter(r.messages()), None) is None
    log = read_log(folder)
    (db3,) = folder.glob("*.db3")
    assert "read from " + db3.name + " itself: the bag's metadata.yaml describes" in str(
        log.meta["source"]
    )
    _same_samples(log, written)


def test_a_several_file_bag_in_that_state_is_refused_saying_why(tmp_path, capsys):
    folder = tmp_path / "imu_bag"
    _imu_bag_as_the_2023_talker(folder, 200, files=2)
    assert main(["allan", str(folder)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert "metadata.yaml counts messages on /imu/data, but none reads through it" in err
    assert "differ from those of its 2 storage files" in err and "ros2 bag reindex" in err

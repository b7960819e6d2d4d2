"""ROS bags: ROS 2 (a bag directory with its metadata.yaml, or one ``.db3`` / ``.mcap``
file) and ROS 1 (``.bag``), through rosbags (extra ``[ros]``; no ROS installation).

The samples are the messages of one ``sensor_msgs/msg/Imu`` topic: the only one,
or the one named by ``--topic`` (several and none named: exit 2 listing them with
their message counts). ``angular_velocity`` is rad/s, ``linear_acceleration``
m/s^2 (the ``units`` metadata says so); ``t`` is the header stamp in s (Unix
time), or the bag's receive time where the stamps are unset (zero), which the
``source`` metadata then says. Messages are read and handed out in blocks as
the bag is iterated (in the bag's order); a message whose stamp does not
advance (repeated or out of order) is skipped and counted
(``meta["skipped_stamps"]``), never reordered in silence.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from ..samples import SampleBlock
from .base import DEFAULT_BLOCK_SIZE, LogError, LogReader, first_violation, make_block
from .extras import require
from .options import LogOptions

#: The message type read (rosbags' name, ROS 1 and ROS 2 alike).
IMU_TYPE = "sensor_msgs/msg/Imu"
#: First bytes of a ROS 1 bag.
ROSBAG1_MAGIC = b"#ROSBAG V2.0"
#: First bytes of an MCAP file.
MCAP_MAGIC = b"\x89MCAP0\r\n"
#: First bytes of a SQLite 3 database (a ROS 2 ``.db3``).
SQLITE_MAGIC = b"SQLite format 3\x00"


def is_bag_directory(path: str | Path) -> bool:
    """Whether ``path`` is a ROS 2 bag directory (it holds a metadata.yaml)."""
    p = Path(path)
    return p.is_dir() and (p / "metadata.yaml").is_file()


class RosbagReader(LogReader):
    """Reader of the ``sensor_msgs/msg/Imu`` messages of one topic of a ROS bag."""

    format = "rosbag"

    def __init__(
        self,
        path: str | Path,
        block_size: int = DEFAULT_BLOCK_SIZE,
        options: LogOptions | None = None,
    ) -> None:
        super().__init__(path, block_size)
        self.options = options or LogOptions()
        highlevel = require("rosbags.highlevel", "ros", "ROS bags")
        self._anyreader = highlevel.AnyReader
        p = Path(self.path)
        if not p.exists():
            raise LogError(self.path, "cannot read: No such file or directory")
        if p.is_file():
            head = self._read_head(16)
            ok = {
                ".bag": head.startswith(ROSBAG1_MAGIC),
                ".mcap": head.startswith(MCAP_MAGIC),
                ".db3": head.startswith(SQLITE_MAGIC),
            }.get(p.suffix.lower(), False)
            if not ok:
                raise LogError(self.path, f"not a ROS bag ({p.suffix} without its file header)")
        topics = self._imu_topics()
        self.topic = self._choose(topics)
        self.meta.update(
            {
                "units": {"gyro": "rad/s", "accel": "m/s^2"},
                "device": f"ROS bag {p.name}, topic {self.topic}",
                "source": f"{IMU_TYPE} on {self.topic} ({topics[self.topic]} messages)",
            }
        )
        self.meta["skipped_stamps"] = 0

    def _open_bag(self) -> Any:
        try:
            reader = self._anyreader([Path(self.path)])
            reader.open()
        except Exception as exc:  # rosbags raises its own errors and plain ones
            raise LogError(self.path, f"not a readable ROS bag: {exc}") from None
        return reader

    def _imu_topics(self) -> dict[str, int]:
        reader = self._open_bag()
        try:
            counts: dict[str, int] = {}
            for c in reader.connections:
                if c.msgtype == IMU_TYPE:
                    counts[c.topic] = counts.get(c.topic, 0) + int(c.msgcount)
            return counts
        finally:
            reader.close()

    def _choose(self, topics: dict[str, int]) -> str:
        listed = ", ".join(f"{t} ({n} messages)" for t, n in sorted(topics.items()))
        wanted = self.options.topic
        if wanted is not None:
            if wanted not in topics:
                raise LogError(
                    self.path,
                    f"--topic {wanted}: no {IMU_TYPE} messages on it "
                    f"(IMU topics: {listed or 'none'})",
                )
            return wanted
        if not topics:
            raise LogError(self.path, f"no {IMU_TYPE} topic in the bag")
        if len(topics) > 1:
            raise LogError(
                self.path, f"{len(topics)} IMU topics: choose one with --topic ({listed})"
            )
        return next(iter(topics))

    def _blocks(self) -> Iterator[SampleBlock]:
        reader = self._open_bag()
        self.meta["skipped_stamps"] = 0
        try:
            conns = [c for c in reader.connections if c.topic == self.topic]
            rows: list[tuple[float, ...]] = []
            last_t: float | None = None
            for conn, bag_ns, raw in reader.messages(connections=conns):
                msg = reader.deserialize(raw, conn.msgtype)
                stamp = msg.header.stamp
                sec = int(stamp.sec)
                nsec = int(getattr(stamp, "nanosec", getattr(stamp, "nsec", 0)))
                if sec == 0 and nsec == 0:
                    t = bag_ns * 1e-9
                    self.meta["source"] = (
                        f"{IMU_TYPE} on {self.topic}, bag receive time (header stamps unset)"
                    )
                else:
                    t = sec + nsec * 1e-9
                if last_t is not None and t <= last_t:
                    self.meta["skipped_stamps"] += 1
                    continue
                last_t = t
                w, a = msg.angular_velocity, msg.linear_acceleration
                rows.append((t, w.x, w.y, w.z, a.x, a.y, a.z))
                if len(rows) == self.block_size:
                    yield self._block(rows)
                    rows = []
            if rows:
                yield self._block(rows)
        finally:
            reader.close()

    def _block(self, rows: list[tuple[float, ...]]) -> SampleBlock:
        m = np.asarray(rows, dtype=float)
        cols = {name: m[:, i] for i, name in enumerate(("t", "gx", "gy", "gz", "ax", "ay", "az"))}
        bad = first_violation(cols, None)
        if bad is not None:
            raise LogError(
                self.path, f"topic {self.topic} message near t = {m[bad[0], 0]}: {bad[1]}"
            )
        return make_block(cols, self.meta)


def is_ros1_bag(head: bytes) -> bool:
    """Whether a file's first bytes are a ROS 1 bag header."""
    return head.startswith(ROSBAG1_MAGIC)


__all__ = ["IMU_TYPE", "RosbagReader", "is_bag_directory", "is_ros1_bag"]

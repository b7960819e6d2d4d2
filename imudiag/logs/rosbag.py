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
(``meta["skipped_stamps"]``), never reordered in silence. A bag directory whose
metadata.yaml describes the topic otherwise than its storage file does (rosbags then reads
none of its messages) is read from its one storage file, which ``source`` says.
"""

from __future__ import annotations

import sqlite3
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from ..samples import SampleBlock
from .base import DEFAULT_BLOCK_SIZE, LogError, LogReader, first_violation, make_block
from .extras import MissingExtra, require
from .gnss_fixes import GnssFixes
from .options import DEFAULT_ROS_DISTRO, ROS2_DISTROS, LogOptions

#: The message type read (rosbags' name, ROS 1 and ROS 2 alike).
IMU_TYPE = "sensor_msgs/msg/Imu"
#: First bytes of a ROS 1 bag.
ROSBAG1_MAGIC = b"#ROSBAG V2.0"
#: First bytes of an MCAP file.
MCAP_MAGIC = b"\x89MCAP0\r\n"
#: First bytes of a SQLite 3 database (a ROS 2 ``.db3``).
SQLITE_MAGIC = b"SQLite format 3\x00"
#: The GNSS messages read from a bag: fixes, and velocities (ENU, REP 103) matched to them.
NAVSATFIX_TYPE = "sensor_msgs/msg/NavSatFix"
VELOCITY_TYPES = (
    "geometry_msgs/msg/TwistWithCovarianceStamped",
    "geometry_msgs/msg/TwistStamped",
    "geometry_msgs/msg/Vector3Stamped",
)


class _PlainReader:
    """rosbags' own ROS 2 or ROS 1 reader with a typestore it is handed: the reader
    interface the IMU and GNSS reads use (connections, messages, deserialize)."""

    def __init__(self, reader: Any, store: Any, ros1: bool = False) -> None:
        self.reader, self.store = reader, store
        self.connections = reader.connections
        self._deserialize = store.deserialize_ros1 if ros1 else store.deserialize_cdr

    def messages(self, connections: Any = ()) -> Any:
        return self.reader.messages(connections=connections)

    def deserialize(self, raw: bytes, msgtype: str) -> Any:
        try:
            return self._deserialize(raw, msgtype)
        except KeyError:
            raise LogError(
                str(self.reader.path), f"no definition of {msgtype} in the typestore"
            ) from None

    def close(self) -> None:
        self.reader.close()


#: The header type of ROS 1 bags recorded before ROS Electric (2011): their stored
#: definitions name ``roslib/Header`` where later ones name ``std_msgs/Header``; the two
#: are the same message (same fields, same MD5), and ROS 1's own rosbag reads both.
OLD_ROS1_HEADER = "roslib/msg/Header"


def ros1_typestore(connections: Any, where: str) -> Any:
    """A typestore of the definitions a ROS 1 bag stores with its connections, each
    checked against the connection's MD5 as ROS 1 does; a bag recorded before ROS
    Electric gets ``std_msgs/msg/Header`` as its stored ``roslib/Header``."""
    typesys = require("rosbags.typesys", "ros", "ROS bags")
    types: dict[str, Any] = {}
    for c in connections:
        if c.msgdef.data:
            types.update(typesys.get_types_from_msg(c.msgdef.data, c.msgtype))
    if OLD_ROS1_HEADER in types:
        types.setdefault("std_msgs/msg/Header", types[OLD_ROS1_HEADER])
    store = typesys.get_typestore(typesys.Stores.EMPTY)
    store.register(types)
    for c in connections:
        if c.digest and c.msgdef.data:
            have = store.generate_msgdef(c.msgtype)[1]
            if have != c.digest:
                raise LogError(
                    where,
                    f"topic {c.topic}: the stored definition of {c.msgtype} does not match "
                    f"its MD5 ({have} != {c.digest})",
                )
    return store


def typestore_for(distro: str | None, where: str) -> Any:
    """rosbags' typestore of a ROS 2 distribution (None: :data:`DEFAULT_ROS_DISTRO`), built
    once per distribution."""
    typesys = require("rosbags.typesys", "ros", "ROS bags")
    name = (distro or DEFAULT_ROS_DISTRO).lower()
    store = getattr(typesys.Stores, f"ROS2_{name.upper()}", None)
    if store is None:
        raise LogError(
            where,
            f"ROS distribution {name!r}: no message definitions for it "
            f"(known: {', '.join(ROS2_DISTROS)}; an older rosbags may lack the newest: "
            "pip install -U rosbags)",
        )
    if name not in _STORES:
        _STORES[name] = typesys.get_typestore(store)
    return _STORES[name]


_STORES: dict[str, Any] = {}


def sqlite_distro(db3: Path) -> str | None:
    """The ``ros_distro`` a ROS 2 ``.db3`` names in its ``schema`` table (Humble and later;
    None for older bags)."""
    try:
        con = sqlite3.connect(f"file:{db3}?mode=ro", uri=True)
        try:
            row = con.execute("SELECT ros_distro FROM schema").fetchone()
        finally:
            con.close()
    except sqlite3.Error:
        return None
    return str(row[0]) if row and row[0] else None


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
        self._bag = self._bag_path(p)
        self._store = self._typestore(p)
        self._other_topics = ""  # the bag's topics of other types, for the messages
        topics = self._imu_topics()
        self.topic = self._choose(topics)
        read_from = ""
        if self._bag.is_dir() and topics[self.topic] > 0 and not self._topic_reads():
            self._bag = self._storage_file()
            topics = self._imu_topics()
            if topics.get(self.topic, 0) == 0:
                raise LogError(self.path, f"{self._bag.name} holds no message of {self.topic}")
            read_from = (
                f", read from {self._bag.name} itself: the bag's metadata.yaml describes its "
                "topics otherwise than the file does (rosbags reads none through it)"
            )
        self.meta.update(
            {
                "units": {"gyro": "rad/s", "accel": "m/s^2"},
                "device": f"ROS bag {p.name}, topic {self.topic}",
                "source": f"{IMU_TYPE} on {self.topic} ({topics[self.topic]} messages){read_from}",
            }
        )
        self.meta["skipped_stamps"] = 0

    def _topic_reads(self) -> bool:
        """Whether the chosen topic's first message reads through the bag directory.

        rosbags pairs each topic of metadata.yaml with the storage file's topic of the same
        name, type, serialization and QoS; where the two disagree (a .db3 rewritten without
        its metadata.yaml, as in rosbag2's own test bags) it reads no message of that topic
        and says nothing."""
        reader = self._open_bag()
        try:
            conns = [c for c in reader.connections if c.topic == self.topic]
            return next(iter(reader.messages(connections=conns)), None) is not None
        finally:
            reader.close()

    def _storage_file(self) -> Path:
        """The bag's one storage file, read by itself (its topics from its own tables);
        several: exit 2 saying why and what to do."""
        files = sorted(f for f in self._bag.iterdir() if f.suffix.lower() in (".db3", ".mcap"))
        if len(files) != 1:
            raise LogError(
                self.path,
                f"metadata.yaml counts messages on {self.topic}, but none reads through it: "
                f"its topic records (type, serialization, QoS) differ from those of its "
                f"{len(files)} storage files; rebuild it with `ros2 bag reindex`, or give "
                "one storage file",
            )
        return files[0]

    def _bag_path(self, p: Path) -> Path:
        """What rosbags opens: a ROS 1 ``.bag``; a ROS 2 bag directory; for one ``.db3`` /
        ``.mcap`` its directory when that holds its metadata.yaml naming it, else the lone
        file (rosbags reads the topics from the storage file itself)."""
        if p.is_dir() or p.suffix.lower() == ".bag":
            return p
        meta = p.parent / "metadata.yaml"
        if meta.is_file():
            try:
                info = yaml.safe_load(meta.read_text())["rosbag2_bagfile_information"]
                files = [Path(str(f)).name for f in info.get("relative_file_paths", [])]
            except Exception:  # a broken metadata.yaml: rosbags names the problem
                files = [p.name]
            if p.name in files:
                return p.parent
        return p  # rosbags reads a lone storage file, its topics from its own tables

    def _typestore(self, p: Path) -> Any:
        """The message definitions for a bag that stores none: the distribution the bag
        names (metadata.yaml ``ros_distro``, or the .db3's ``schema`` table), else
        ``--ros-distro``, else :data:`DEFAULT_ROS_DISTRO`; ``ros_distro`` metadata says which."""
        if self._bag.suffix.lower() == ".bag":
            return None  # a ROS 1 bag stores each connection's definition
        named, how = None, ""
        try:
            info = yaml.safe_load((self._bag / "metadata.yaml").read_text())
            named = info["rosbag2_bagfile_information"].get("ros_distro")
            how = "the bag's metadata.yaml"
        except Exception:  # rosbags reports a broken metadata.yaml when the bag is opened
            pass
        if not named:
            dbs = [self._bag / n for n in sorted(x.name for x in self._bag.glob("*.db3"))]
            named = sqlite_distro(dbs[0]) if dbs else None
            how = "the .db3's schema table"
        given = self.options.ros_distro
        if named and str(named).lower() in ROS2_DISTROS:
            distro = str(named).lower()
        elif given:
            distro, how = given, "--ros-distro"
        else:
            distro = DEFAULT_ROS_DISTRO
            how = "the default (current LTS; --ros-distro for another)"
            if named:
                how = f"the default: the bag names {named!r}, which rosbags has no types of"
        self.meta["ros_distro"] = f"{distro} ({how})"
        return typestore_for(distro, self.path)

    def _open_bag(self) -> Any:
        """An open reader of the bag: rosbags' own ROS 2 reader with the distribution's
        typestore for a bag that stores no definitions (the typestore built once), else
        rosbags' AnyReader with the bag's own definitions (MCAP); a ROS 1 bag through
        rosbags' ROS 1 reader with its stored definitions (:func:`ros1_typestore`)."""
        try:
            if self._bag.suffix.lower() == ".bag":
                rosbag1 = require("rosbags.rosbag1", "ros", "ROS bags")
                plain1 = rosbag1.Reader(self._bag)
                plain1.open()
                try:
                    store = ros1_typestore(plain1.connections, self.path)
                except BaseException:
                    plain1.close()
                    raise
                return _PlainReader(plain1, store, ros1=True)
            if self._store is not None:
                rosbag2 = require("rosbags.rosbag2", "ros", "ROS bags")
                plain = rosbag2.Reader(self._bag)
                plain.open()
                if all(not c.msgdef.data for c in plain.connections):
                    return _PlainReader(plain, self._store)
                plain.close()
            reader = self._anyreader([self._bag], default_typestore=self._store)
            reader.open()
        except (MissingExtra, LogError):
            raise
        except Exception as exc:  # rosbags raises its own errors and plain ones
            text = str(exc)
            if "default_typestore" in text:  # rosbags' hint to a programmer, not a user
                text = "the bag stores no message definitions and none could be chosen"
            raise LogError(self.path, f"not a readable ROS bag: {text}") from None
        return reader

    def _imu_topics(self) -> dict[str, int]:
        reader = self._open_bag()
        try:
            every: dict[tuple[str, str], int] = {}
            for c in reader.connections:
                every[c.topic, c.msgtype] = every.get((c.topic, c.msgtype), 0) + int(c.msgcount)
            self._other_topics = ", ".join(
                f"{t} ({m}, {n} messages)" for (t, m), n in sorted(every.items()) if m != IMU_TYPE
            )
            return {t: n for (t, m), n in every.items() if m == IMU_TYPE}
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
                    f"(IMU topics: {listed or 'none'}; "
                    f"other topics: {self._other_topics or 'none'})",
                )
            return wanted
        if not topics:
            raise LogError(
                self.path,
                f"no {IMU_TYPE} topic in the bag (its topics: {self._other_topics or 'none'})",
            )
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

    @staticmethod
    def _stamp(msg: Any, bag_ns: int) -> float:
        """A message's header stamp, s (the bag's receive time where it is unset)."""
        st = msg.header.stamp
        sec, nsec = int(st.sec), int(getattr(st, "nanosec", getattr(st, "nsec", 0)))
        return bag_ns * 1e-9 if sec == 0 and nsec == 0 else sec + nsec * 1e-9

    def gnss(self) -> GnssFixes | None:
        """The bag's ``sensor_msgs/msg/NavSatFix`` fixes (the first topic by name) with the
        velocity of a TwistWithCovarianceStamped / TwistStamped / Vector3Stamped topic (ENU,
        REP 103; a topic named ``*vel*`` first) nearest each fix within half a fix period;
        stamped in the IMU's own clock (header stamps), so no clock mapping is needed."""
        reader = self._open_bag()
        try:
            fix_topics = sorted(
                {c.topic for c in reader.connections if c.msgtype == NAVSATFIX_TYPE}
            )
            if not fix_topics:
                return None
            vel = sorted(
                {c.topic for c in reader.connections if c.msgtype in VELOCITY_TYPES},
                key=lambda t: ("vel" not in t.lower(), t),
            )
            want = {fix_topics[0], *vel[:1]}
            fixes: list[tuple[float, ...]] = []
            vels: list[tuple[float, ...]] = []
            conns = [c for c in reader.connections if c.topic in want]
            for conn, bag_ns, raw in reader.messages(connections=conns):
                msg = reader.deserialize(raw, conn.msgtype)
                t = self._stamp(msg, bag_ns)
                if conn.msgtype == NAVSATFIX_TYPE:
                    st = int(msg.status.status)
                    mode = 1 if st < 0 else (3 if np.isfinite(msg.altitude) else 2)
                    nan4 = (np.nan,) * 4  # velocity and its accuracy: from the velocity topic
                    pos = (msg.latitude, msg.longitude, msg.altitude)
                    fixes.append((t, np.nan, *pos, *nan4, mode, 2 if st > 0 else 1))
                else:
                    v, sd = msg, np.nan
                    if hasattr(v, "twist"):
                        v = v.twist
                        if hasattr(v, "covariance"):
                            cov = np.asarray(v.covariance, dtype=float)
                            sd = float(np.sqrt(max(cov[0], cov[7]))) if cov[0] > 0 else np.nan
                        v = v.twist if hasattr(v, "twist") else v
                    lin = v.linear if hasattr(v, "linear") else v.vector
                    vels.append((t, lin.y, lin.x, -lin.z, sd))  # ENU -> NED
        finally:
            reader.close()
        if not fixes:
            return None
        m = np.asarray(fixes, dtype=float)
        if vels:
            v = np.asarray(sorted(vels), dtype=float)
            period = float(np.median(np.diff(m[:, 0]))) if len(m) > 1 else 1.0
            j = np.clip(np.searchsorted(v[:, 0], m[:, 0]), 1, max(1, len(v) - 1))
            j0 = np.clip(j - 1, 0, len(v) - 1)
            j = np.clip(j, 0, len(v) - 1)
            k = np.where(np.abs(v[j0, 0] - m[:, 0]) <= np.abs(v[j, 0] - m[:, 0]), j0, j)
            near = np.abs(v[k, 0] - m[:, 0]) <= 0.5 * period
            m[near, 5:9] = v[k[near], 1:5]
        velocity = f" + velocity {vel[0]}" if vel else " (no velocity topic)"
        return GnssFixes.from_rows(
            [tuple(r) for r in m],
            f"ROS {NAVSATFIX_TYPE} {fix_topics[0]}{velocity}",
            "same clock: the fixes' header stamps are in the IMU messages' clock",
        )

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


__all__ = ["IMU_TYPE", "RosbagReader", "is_bag_directory", "is_ros1_bag", "ros1_typestore"]

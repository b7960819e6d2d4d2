"""A fake Linux IIO IMU: a sysfs tree and a FIFO laid out as the kernel lays them out.

:class:`FakeIIODevice` makes ``ROOT/iio:deviceN/`` (``name``,
``sampling_frequency``, ``buffer/enable``, ``buffer/length``, ``scan_elements/``
with ``in_<channel>_en``, ``_index`` and ``_type`` for each channel, and
``in_<type>_scale`` / ``_offset``) and a FIFO ``DEVDIR/iio:deviceN`` standing for
the buffered character device (Documentation/ABI/testing/sysfs-bus-iio). The
channels and their types are the caller's (:class:`Channel`); a temperature
channel is there (enabled) so a reader must switch it off. :meth:`write` sends
packed records the caller made; :func:`pack_records` is this module's own encoder
(each element at the next multiple of its size, the record padded to the largest).
:meth:`unplug` closes the FIFO and removes the device; :meth:`plug` lays it out again.
Point a reader at it with ``IMUDIAG_IIO_ROOT`` / ``IMUDIAG_IIO_DEV`` or the URL's
``root=`` / ``devdir=``. It never imports the driver it stands in for.
"""

from __future__ import annotations

import math
import os
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np


@dataclass(frozen=True)
class Channel:
    """One scan element: ``in_<name>`` with its index, type text, scale and offset."""

    name: str  #: e.g. ``accel_x``, ``anglvel_z``, ``timestamp``, ``temp0``
    index: int
    type: str  #: e.g. ``le:s16/16>>0``
    scale: float | None = None  #: written as in_<name>_scale (None: not written)
    offset: float | None = None  #: written as in_<name>_offset (None: not written)
    enabled: bool = False  #: the _en file's value before a reader configures it


#: an ADIS16475-2's 32-bit outputs as the kernel's adis16475 driver scales them (the
#: data sheet's 1/40 deg/s and 0.25 mg per 16-bit LSB, over 65536): rad/s per LSB
ADIS16475_2_GYRO_SCALE = math.pi / 180.0 / 40.0 / 65536.0
#: m/s^2 per LSB of the ADIS16475-2's 32-bit accelerometer output
ADIS16475_2_ACCEL_SCALE = 9.80665 * 0.25e-3 / 65536.0


def imu_channels(gyro_scale: float, accel_scale: float, temperature: bool = False) -> list[Channel]:
    """An IMU's scan elements as a 32-bit ADIS driver lays them out: ``anglvel_x/y/z``
    (index 0-2) and ``accel_x/y/z`` (3-5) as ``le:s32/32>>0`` with their ``scale`` (rad/s
    and m/s^2 per LSB), with ``temperature`` a ``temp0`` channel (6) left enabled for the
    reader to switch off, and the ``timestamp`` (ns, ``le:s64/64>>0``) last."""
    out = [
        *(
            Channel(f"anglvel_{a}", i, "le:s32/32>>0", scale=gyro_scale)
            for i, a in enumerate("xyz")
        ),
        *(
            Channel(f"accel_{a}", 3 + i, "le:s32/32>>0", scale=accel_scale)
            for i, a in enumerate("xyz")
        ),
    ]
    if temperature:
        out.append(Channel("temp0", 6, "le:s16/16>>0", scale=100.0, enabled=True))
    out.append(Channel("timestamp", len(out), "le:s64/64>>0"))
    return out


class FakeIIODevice:
    """A fake IIO device under ``root`` with its FIFO in ``devdir``."""

    def __init__(
        self,
        root: str | os.PathLike[str],
        devdir: str | os.PathLike[str],
        name: str,
        channels: list[Channel],
        number: int = 0,
        sampling_frequency: float = 2000.0,
        shared: dict[str, float] | None = None,
    ) -> None:
        self.root = Path(root)
        self.devdir = Path(devdir)
        self.name = name
        self.channels = channels
        self.number = number
        self.sampling_frequency = sampling_frequency
        #: attributes shared by a channel type, e.g. ``{"in_accel_scale": 0.0023}``
        self.shared = dict(shared or {})
        self._fd: int | None = None
        self.plug()

    @property
    def dir(self) -> Path:
        """The device's sysfs directory."""
        return self.root / f"iio:device{self.number}"

    @property
    def node(self) -> Path:
        """The FIFO standing for ``/dev/iio:deviceN``."""
        return self.devdir / f"iio:device{self.number}"

    def plug(self) -> None:
        """Lay the device out (again) and open the FIFO's writing end."""
        d = self.dir
        (d / "buffer").mkdir(parents=True, exist_ok=True)
        (d / "scan_elements").mkdir(exist_ok=True)
        self.devdir.mkdir(parents=True, exist_ok=True)
        (d / "name").write_text(self.name + "\n")
        (d / "sampling_frequency").write_text(f"{self.sampling_frequency:g}\n")
        (d / "buffer" / "enable").write_text("0\n")
        (d / "buffer" / "length").write_text("1024\n")
        for ch in self.channels:
            scan = d / "scan_elements"
            (scan / f"in_{ch.name}_en").write_text("1\n" if ch.enabled else "0\n")
            (scan / f"in_{ch.name}_index").write_text(f"{ch.index}\n")
            (scan / f"in_{ch.name}_type").write_text(ch.type + "\n")
            if ch.scale is not None:
                (d / f"in_{ch.name}_scale").write_text(f"{ch.scale:.12g}\n")
            if ch.offset is not None:
                (d / f"in_{ch.name}_offset").write_text(f"{ch.offset:.12g}\n")
        for attr, value in self.shared.items():
            (d / attr).write_text(f"{value:.12g}\n")
        if not self.node.exists():
            os.mkfifo(self.node)
        # read-write: never blocks, and the reader sees no end of file while it is open
        self._fd = os.open(self.node, os.O_RDWR | os.O_NONBLOCK)

    @property
    def fd(self) -> int:
        """The FIFO's writing end (for a writer thread of packed records)."""
        assert self._fd is not None, "the device is unplugged"
        return self._fd

    def enabled(self) -> dict[str, bool]:
        """Each channel's ``_en`` as a reader left it."""
        scan = self.dir / "scan_elements"
        return {
            ch.name: (scan / f"in_{ch.name}_en").read_text().strip() == "1" for ch in self.channels
        }

    def buffer_enabled(self) -> bool:
        """``buffer/enable`` as a reader left it."""
        return (self.dir / "buffer" / "enable").read_text().strip() == "1"

    def write(self, data: bytes) -> None:
        """Send packed records (the kernel's side of the character device), blocking."""
        import select

        assert self._fd is not None, "the device is unplugged"
        view = memoryview(data)
        while view:
            select.select([], [self._fd], [], 0.1)
            try:
                n = os.write(self._fd, view)
            except BlockingIOError:
                continue
            view = view[n:]

    def unplug(self) -> None:
        """The device goes away: the FIFO is closed and removed, the sysfs tree too."""
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None
        if self.node.exists():
            self.node.unlink()
        shutil.rmtree(self.dir, ignore_errors=True)

    def close(self) -> None:
        """Unplug and forget; safe to call twice."""
        self.unplug()


def pack_records(channels: list[Channel], columns: dict[str, np.ndarray]) -> bytes:
    """Records of the enabled ``channels`` (index order), values from ``columns`` (raw
    integers per channel name), each element at the next multiple of its size."""
    order = sorted(channels, key=lambda c: c.index)
    fields = []
    pos = largest = 0
    for ch in order:
        end, rest = ch.type.split(":")
        sign, rest = rest[0], rest[1:]
        storage = int(rest.split("/")[1].split(">>")[0].split("X")[0])
        shift = int(ch.type.split(">>")[1])
        size = storage // 8
        pos = -(-pos // size) * size
        fields.append(
            (
                ch.name,
                pos,
                f"{'>' if end == 'be' else '<'}{'i' if sign == 's' else 'u'}{size}",
                shift,
            )
        )
        pos += size
        largest = max(largest, size)
    record = -(-pos // largest) * largest
    n = len(next(iter(columns.values())))
    dt = np.dtype(
        {
            "names": [f[0] for f in fields],
            "formats": [f[2] for f in fields],
            "offsets": [f[1] for f in fields],
            "itemsize": record,
        }
    )
    recs = np.zeros(n, dtype=dt)
    for name, _, _, shift in fields:
        recs[name] = np.asarray(columns[name]).astype(np.int64) << shift
    return recs.tobytes()

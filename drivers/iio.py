"""``iio://NAME_OR_DEVICE``: an IMU through the Linux kernel's IIO buffered interface.

Pure Python, no libiio: the sysfs files of Documentation/ABI/testing/sysfs-bus-iio and
the buffered character device. ``iio://adis16475`` finds the device whose ``name`` is
``adis16475`` (or, when that is unique, starts with ``adis16475-``) under the IIO root;
``iio://iio:device0`` names the device directly.

On open the source disables the buffer, enables the ``in_accel_{x,y,z}``,
``in_anglvel_{x,y,z}`` and ``in_timestamp`` scan elements and disables every other
one, sets ``sampling_frequency`` (``rate=``), enables the buffer and reads packed
records from ``/dev/iio:deviceN``. Each enabled element sits at the next multiple of
its own size (storage bytes x repeat), in ``index`` order; the record is padded to
its largest element. A channel's ``type`` (``le:s16/16>>0``, ``be:u32/32>>0``,
``le:s12/16X2>>4``: endianness, sign, real bits / storage bits, repeat, shift) says
how to read it; the value is the kernel's ``(raw + offset) * scale`` with
``in_<ch>_scale`` / ``in_<type>_scale`` and ``..._offset`` (0 when absent): m/s^2 and
rad/s. The timestamp element (nanoseconds) is the sample time (time 0 at the first
sample); without it, the sample count over the sampling frequency.

Records carry no checksum: there is nothing to resynchronise on, so a partial record
at a reconnect is counted as skipped bytes; repeated time stamps are duplicates,
gaps of more than 1.5 sample periods count lost samples.

Query keys: ``rate`` (Hz, written to ``sampling_frequency``), ``root`` (the IIO
devices directory; default ``$IMUDIAG_IIO_ROOT`` or ``/sys/bus/iio/devices``),
``devdir`` (where the ``iio:deviceN`` nodes are; default ``$IMUDIAG_IIO_DEV`` or
``/dev``).
"""

from __future__ import annotations

import math
import os
import re
import select
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from imudiag.samples import SampleBlock

from .base import Source, SourceError, SourceURL, register
from .devicestream import DeviceDecoder, Timeline
from .wire import Counters

DEFAULT_ROOT = "/sys/bus/iio/devices"
DEFAULT_DEVDIR = "/dev"
ROOT_ENV = "IMUDIAG_IIO_ROOT"
DEVDIR_ENV = "IMUDIAG_IIO_DEV"
AXES = ("x", "y", "z")
#: the scan elements read, in the order of the sample arrays
WANTED = tuple(f"{kind}_{a}" for kind in ("anglvel", "accel") for a in AXES)
_TYPE_RE = re.compile(r"^(le|be):([su])(\d+)/(\d+)(?:X(\d+))?>>(\d+)$")
_MAX_READ = 1 << 16  #: bytes per read at most


@dataclass(frozen=True)
class ScanType:
    """A scan element's ``type``: ``[be|le]:[s|u]bits/storagebits[Xrepeat]>>shift``."""

    big_endian: bool
    signed: bool
    real_bits: int
    storage_bits: int
    repeat: int
    shift: int

    @classmethod
    def parse(cls, text: str, where: str) -> ScanType:
        """Parse ``text``; SourceError naming ``where`` (the file) when it is not a type."""
        m = _TYPE_RE.match(text.strip())
        if not m:
            raise SourceError(f"{where}: not an IIO scan type: {text.strip()!r}")
        end, sign, bits, storage, repeat, shift = m.groups()
        st = cls(end == "be", sign == "s", int(bits), int(storage), int(repeat or 1), int(shift))
        if st.storage_bits not in (8, 16, 32, 64) or not 0 < st.real_bits <= st.storage_bits:
            raise SourceError(f"{where}: unsupported scan type {text.strip()!r}")
        return st

    @property
    def size(self) -> int:
        """Bytes the element takes in a record (storage bytes x repeat)."""
        return self.storage_bits // 8 * self.repeat

    def decode(self, raw: np.ndarray) -> np.ndarray:
        """Values (int64) of the storage words ``raw`` (unsigned, native order)."""
        v = raw.astype(np.uint64) >> np.uint64(self.shift)
        if self.real_bits < 64:
            v &= np.uint64((1 << self.real_bits) - 1)
        out = v.astype(np.int64)
        if self.signed and self.real_bits < 64:
            sign = np.int64(1 << (self.real_bits - 1))
            out = out - ((out & sign) << np.int64(1))
        return out


@dataclass(frozen=True)
class Element:
    """An enabled scan element: name, index, type, offset in the record, scale, offset."""

    name: str
    index: int
    type: ScanType
    offset: int
    scale: float
    value_offset: float


def record_layout(elements: list[tuple[str, int, ScanType]]) -> tuple[list[tuple[str, int]], int]:
    """(name, byte offset) of each element in index order, and the record size in bytes:
    each element aligned to its own size, the record padded to the largest."""
    pos = 0
    largest = 1
    out = []
    for name, _index, st in sorted(elements, key=lambda e: e[1]):
        size = st.size
        pos = -(-pos // size) * size
        out.append((name, pos))
        pos += size
        largest = max(largest, size)
    return out, -(-pos // largest) * largest


def _read_text(path: Path) -> str | None:
    try:
        return path.read_text().strip()
    except OSError:
        return None


def _write_text(path: Path, value: str) -> None:
    try:
        path.write_text(value + "\n")
    except OSError as exc:
        raise SourceError(f"{path}: cannot write {value!r}: {exc.strerror or exc}") from None


def find_device(root: Path, target: str) -> Path:
    """The device directory for ``target`` (``iio:deviceN`` or a device name)."""
    target = target.strip("/")
    if not target:
        raise SourceError("iio://: no device (iio://adis16475 or iio://iio:device0)")
    if not root.is_dir():
        raise SourceError(f"iio://{target}: no IIO devices directory {root}")
    if target.startswith("iio:device"):
        path = root / target
        if not (path / "name").is_file():
            raise SourceError(f"iio://{target}: no such device under {root}")
        return path
    names = {}
    for dev in sorted(root.glob("iio:device*")):
        name = _read_text(dev / "name")
        if name is not None:
            names[dev] = name
    exact = [d for d, n in names.items() if n.lower() == target.lower()]
    prefix = [d for d, n in names.items() if n.lower().startswith(target.lower() + "-")]
    found = exact or prefix
    if len(found) == 1:
        return found[0]
    listed = ", ".join(f"{d.name} ({n})" for d, n in names.items()) or "none"
    why = "several devices match" if found else "no device of that name"
    raise SourceError(f"iio://{target}: {why} under {root}; devices: {listed}")


class IIORecordDecoder(DeviceDecoder):
    """Packed IIO records -> samples in m/s^2 and rad/s (see the module doc)."""

    units = {"gyro": "rad/s", "accel": "m/s^2"}

    def __init__(self, counters: Counters | None = None) -> None:
        super().__init__(counters)
        self.record_size = 0
        self.elements: dict[str, Element] = {}
        self.rate_hz: float | None = None
        self.timeline = Timeline(1e-9, None, None, origin_first=True)
        self._count = 0
        self._dtype = np.dtype([])
        self._plain: dict[str, bool] = {}

    def configure(
        self, elements: dict[str, Element], record_size: int, rate_hz: float | None
    ) -> None:
        """The layout of the records to come (after every (re)open)."""
        self.elements = elements
        self.record_size = record_size
        self.rate_hz = rate_hz
        self.timeline.nominal_dt_s = 1.0 / rate_hz if rate_hz else None
        names, formats, offsets = [], [], []
        for el in elements.values():
            st = el.type
            # a channel that fills its storage unshifted is read as a signed/unsigned integer
            # directly; the others as unsigned storage words, then shifted and masked
            plain = st.shift == 0 and st.real_bits == st.storage_bits and st.repeat == 1
            kind = "i" if plain and st.signed else "u"
            end = ">" if st.big_endian else "<"
            names.append(el.name)
            formats.append(f"{end}{kind}{st.storage_bits // 8}")
            offsets.append(el.offset)
        self._plain = {
            el.name: el.type.shift == 0 and el.type.real_bits == el.type.storage_bits
            for el in elements.values()
        }
        self._dtype = np.dtype(
            {"names": names, "formats": formats, "offsets": offsets, "itemsize": record_size}
        )

    def _values(self, recs: np.ndarray, name: str) -> np.ndarray:
        col = recs[name]
        return col if self._plain[name] else self.elements[name].type.decode(col)

    def _decode(self, buf: bytes) -> tuple[SampleBlock, int]:
        size = self.record_size
        if not size:
            return SampleBlock.empty(), 0
        m = len(buf) // size
        if m == 0:
            return SampleBlock.empty(), 0
        self.frame_bytes += m * size
        recs = np.frombuffer(buf, dtype=self._dtype, count=m)
        out = np.empty((m, 6), dtype=np.float64)
        for j, name in enumerate(WANTED):
            el = self.elements[name]
            if el.value_offset:
                out[:, j] = (self._values(recs, name) + el.value_offset) * el.scale
            else:
                np.multiply(self._values(recs, name), el.scale, out=out[:, j])
        gyro = out[:, :3]
        accel = out[:, 3:]
        if "timestamp" in self.elements:
            ticks = self._values(recs, "timestamp")
        else:
            period_ns = 1e9 / (self.rate_hz or 1.0)
            ticks = np.rint((self._count + np.arange(m)) * period_ns).astype(np.int64)
        self._count += m
        keep, t = self.timeline.place(ticks, self.counters)
        if t.shape[0] != m:
            gyro, accel = gyro[keep], accel[keep]
        return self._block(t, gyro, accel, None, np.zeros(t.shape[0], np.uint16)), m * size


@register("iio")
class IIOSource(Source):
    """A Linux IIO device's buffer (see the module docstring for the URL)."""

    url_keys = ("rate", "root", "devdir")

    def __init__(self, url: SourceURL, **options: Any) -> None:
        super().__init__(url, **options)
        self.root = Path(
            options.get("root") or url.get("root") or os.environ.get(ROOT_ENV) or DEFAULT_ROOT
        )
        self.devdir = Path(
            options.get("devdir")
            or url.get("devdir")
            or os.environ.get(DEVDIR_ENV)
            or DEFAULT_DEVDIR
        )
        rate = url.get("rate", None, float)
        if rate is not None and not (rate > 0 and math.isfinite(rate)):
            raise SourceError(f"{url.url}: bad value for 'rate': {rate}")
        self.rate_hz: float | None = rate
        if not url.target.strip("/"):
            raise SourceError(f"{url.url}: no device (iio://adis16475 or iio://iio:device0)")
        self.decoder = IIORecordDecoder(self.counters)
        self.device_info = self.decoder.device_info
        self.is_open = False
        self._fd: int | None = None
        self._dev: Path | None = None

    # -- sysfs ---------------------------------------------------------------

    def _buffer_enable(self, dev: Path) -> Path:
        for sub in ("buffer0", "buffer"):
            path = dev / sub / "enable"
            if path.exists():
                return path
        raise SourceError(f"{self.url.url}: {dev} has no buffer/enable (no buffered capture)")

    def _scan_dir(self, dev: Path) -> Path:
        for sub in ("buffer0", "scan_elements"):
            path = dev / sub
            if (path / "in_timestamp_en").exists() or list(path.glob("in_*_en")):
                return path
        raise SourceError(f"{self.url.url}: {dev} has no scan_elements")

    def _attr(self, dev: Path, channel: str, kind: str, what: str) -> float | None:
        """``in_<channel>_<what>``, else the shared ``in_<kind>_<what>``, as a number."""
        for name in (f"in_{channel}_{what}", f"in_{kind}_{what}"):
            text = _read_text(dev / name)
            if text is not None:
                try:
                    return float(text)
                except ValueError:
                    raise SourceError(f"{dev / name}: not a number: {text!r}") from None
        return None

    def _setup(self, dev: Path) -> None:
        scan = self._scan_dir(dev)
        enable = self._buffer_enable(dev)
        _write_text(enable, "0")
        wanted = {f"in_{n}_en" for n in WANTED} | {"in_timestamp_en"}
        found: list[tuple[str, int, ScanType]] = []
        for en in sorted(scan.glob("in_*_en")):
            on = en.name in wanted
            _write_text(en, "1" if on else "0")
            if not on:
                continue
            channel = en.name[3:-3]
            index_text = _read_text(scan / f"in_{channel}_index")
            type_text = _read_text(scan / f"in_{channel}_type")
            if index_text is None or type_text is None:
                raise SourceError(f"{scan}: in_{channel}_index or _type missing")
            found.append(
                (
                    channel,
                    int(index_text),
                    ScanType.parse(type_text, str(scan / f"in_{channel}_type")),
                )
            )
        names = {c for c, _, _ in found}
        missing = [n for n in WANTED if n not in names]
        if missing:
            raise SourceError(
                f"{self.url.url}: {dev.name} ({_read_text(dev / 'name')}) has no "
                f"{', '.join('in_' + n for n in missing)} scan element: not an IMU"
            )
        layout, size = record_layout(found)
        types = {c: st for c, _, st in found}
        index = {c: i for c, i, _ in found}
        elements = {}
        for channel, offset in layout:
            kind = channel.split("_")[0]
            if channel == "timestamp":
                scale, value_offset = 1.0, 0.0
            else:
                scale_v = self._attr(dev, channel, kind, "scale")
                if scale_v is None:
                    raise SourceError(f"{dev}: no in_{channel}_scale nor in_{kind}_scale")
                scale = scale_v
                value_offset = self._attr(dev, channel, kind, "offset") or 0.0
            elements[channel] = Element(
                channel, index[channel], types[channel], offset, scale, value_offset
            )
        freq = dev / "sampling_frequency"
        if self.rate_hz is not None:
            _write_text(freq, f"{self.rate_hz:g}")
        rate_text = _read_text(freq)
        rate = float(rate_text) if rate_text else self.rate_hz
        self.decoder.configure(elements, size, rate)
        name = _read_text(dev / "name") or dev.name
        self.device_info.update(
            vendor="Analog Devices" if name.lower().startswith(("adis", "adxrs")) else None,
            product=name.upper(),
            serial=_read_text(dev / "serial_number"),
            firmware=_read_text(dev / "firmware_revision"),
            datasheet=_datasheet_key(name),
            rate_hz=rate,
            iio_device=dev.name,
            record_bytes=size,
        )
        _write_text(enable, "1")

    # -- Source ---------------------------------------------------------------

    def open(self) -> None:
        """Find the device, configure its buffer and open its character device."""
        if self.is_open:
            return
        self.decoder.drop_pending()
        dev = find_device(self.root, self.url.target)
        self._setup(dev)
        node = self.devdir / dev.name
        try:
            self._fd = os.open(node, os.O_RDONLY | os.O_NONBLOCK)
        except OSError as exc:
            raise SourceError(f"{self.url.url}: cannot open {node}: {exc.strerror}") from None
        self._dev = dev
        self.is_open = True

    def read(self, timeout_s: float = 0.1) -> SampleBlock:
        """Samples of the records that arrived within ``timeout_s`` seconds."""
        if not self.is_open or self._fd is None:
            raise SourceError(f"{self.url.url}: read on a source that is not open")
        fd = self._fd
        try:
            try:
                data = os.read(fd, _MAX_READ)
            except BlockingIOError:
                data = None
            if not data:
                ready, _, _ = select.select([fd], [], [], max(0.0, timeout_s))
                if not ready:
                    return SampleBlock.empty()
                try:
                    data = os.read(fd, _MAX_READ)
                except BlockingIOError:
                    return SampleBlock.empty()
                if not data:
                    raise SourceError(f"{self.url.url}: device gone (end of {self.devdir})")
        except OSError as exc:
            self.close()
            raise SourceError(f"{self.url.url}: device gone: {exc.strerror or exc}") from None
        except SourceError:
            self.close()
            raise
        return self.decoder.feed(data)

    def close(self) -> None:
        """Disable the buffer (if the device is still there) and close; safe to call twice."""
        if not self.is_open:
            return
        self.is_open = False
        fd, self._fd = self._fd, None
        if fd is not None:
            os.close(fd)
        dev, self._dev = self._dev, None
        if dev is not None:
            try:
                self._buffer_enable(dev).write_text("0\n")
            except (OSError, SourceError):
                pass

    def write_command(self, line: str) -> None:
        """The IIO buffer takes no device commands."""
        raise ValueError(f"iio://: unknown device command {line.strip()!r} (it takes none)")


def _datasheet_key(name: str) -> str | None:
    """The bundled data-sheet certificate of an IIO device name, if there is one."""
    from imudiag.certificate import CertificateError, datasheet_path

    key = name.strip().lower()
    try:
        datasheet_path(key)
    except CertificateError:
        return None
    return key

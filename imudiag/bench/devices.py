"""Fake devices: the project's simulator behind a pty, in a device's own protocol.

As gpsd keeps ``gpsfake`` apart from the daemon, the fake devices live here, never in the
sources they feed. A :class:`DeviceEncoder` turns blocks of simulated samples into the
bytes a device sends (and answers what the host sends it); :class:`DeviceWriter` writes
them into a :class:`~imudiag.bench.pty.PtyPair` at a pace set in sample time::

    board = SimulatedBoard(cert, motion, ...)            # counts, the project's simulator
    encoder = make_encoder("mavlink", cert)              # a fake PX4 autopilot
    writer = DeviceWriter(pair, encoder, blocks_of(board), speed=10)
    # the host reads mavlink://<pair.slave_path>; its certificate: encoder.certificate

Every device is given the simulator's raw outputs in the scenario certificate's output
units (counts for the bundled one). A device whose protocol carries physical units (MAVLink
HIGHRES_IMU) applies the certificate's nominal bias and scale factor, as an autopilot
applies its calibration: :func:`calibrated_certificate` is the certificate its output then
obeys (the same sensor, so every decision of the monitor comes at the same sample time).

Adding a device is one entry in :data:`ENCODERS` (docs/devices.md, "Fake devices").
"""

from __future__ import annotations

import copy
import errno
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from imudiag import units
from imudiag.certificate import Certificate
from imudiag.drivers.mavlink import load_pymavlink
from imudiag.drivers.wire import SAMPLE_FRAME_SIZE, TYPE_SAMPLE, encode_samples
from imudiag.errors import BenchError
from imudiag.samples import SampleBlock
from imudiag.sim.board import SimulatedBoard

from . import fake_iio, fake_isensor, fake_witmotion
from .pty import PtyPair, read_available, write_all
from .transport import corrupt_sample_frames, frame_spans

#: the SI units of a calibrated physical output per triad
SI_UNITS = {"gyro": "rad/s", "accel": "m/s^2"}


class DeviceEncoder(Protocol):
    """A fake device's protocol side: samples in, the device's bytes out."""

    name: str
    #: the certificate the encoded samples obey (what the host must monitor them with)
    certificate: Certificate
    #: bytes a transport fault may insert as garbage without making a frame start
    garbage_alphabet: bytes
    #: the host configures the device before it streams: whoever serves the device
    #: answers the host (:meth:`answer`) while it waits for the host to connect
    dialogue: bool

    def encode(self, block: SampleBlock) -> bytes:
        """The device's bytes for ``block`` (raw outputs in the scenario certificate's
        output units, ``t`` in s)."""
        ...

    def answer(self, data: bytes) -> bytes:
        """The device's reply to bytes the host sent (b"" when nothing is answered)."""
        ...

    def idle(self) -> bytes:
        """What the device sends while it waits for a host (b"": nothing)."""
        ...

    def split(self, data: bytes) -> list[tuple[bytes, bool]]:
        """The frames of ``data`` (whole frames this encoder made): (bytes, is a sample)."""
        ...

    def corrupt(self, frame: bytes) -> bytes | None:
        """``frame`` with a payload byte changed so that its checksum fails and no frame
        start appears inside it (None when no byte allows that)."""
        ...


def calibrated_certificate(cert: Certificate) -> Certificate:
    """The certificate of ``cert``'s sensor whose outputs are calibrated with its nominal
    bias and scale factor into SI input units: ``x = (U - B) / S`` in rad/s and m/s^2.

    Bias 0, scale factor 1, scale-factor error E/S, the same misalignment and F0 limit;
    noise, bias and scale-factor limits divided by S (and multiplied by the unit's factor
    to SI). Refused for extended models (temperature, nonlinearity, g-sensitivity).
    """
    out = copy.deepcopy(cert)
    for name in ("gyro", "accel"):
        tri = out.triad(name)
        if tri.temperature is not None or tri.nonlinearity is not None:
            raise BenchError(f"a calibrated device needs a linear {name} model in the certificate")
        if tri.g_sensitivity is not None:
            raise BenchError("a calibrated device needs a certificate without g_sensitivity")
        k = tri.unit_to_si  # input unit -> SI
        per_si = k / tri.scale_factor  # output counts -> SI input units, per axis
        tri.scale_factor_error = tri.scale_factor_error / tri.scale_factor
        tri.limits.scale_factor_error = tri.limits.scale_factor_error / tri.scale_factor
        tri.limits.bias = tri.limits.bias * per_si
        if tri.noise is not None:
            for field in ("density", "bias_random_walk", "quantization", "bias_instability"):
                v = getattr(tri.noise, field)
                if v is not None:
                    setattr(tri.noise, field, v * per_si)
            for field in ("rate_ramp", "gauss_markov_sigma"):
                v = getattr(tri.noise, field)
                if v is not None:
                    setattr(tri.noise, field, v * per_si)
        tri.bias = np.zeros(3)
        tri.scale_factor = np.ones(3)
        tri.input_unit = SI_UNITS[name]
        tri.output_unit = SI_UNITS[name]
    out.device = {**cert.device, "model": f"{cert.device.get('model', 'IMU')} (calibrated SI)"}
    return out


def calibrate(block: SampleBlock, cert: Certificate) -> tuple[np.ndarray, np.ndarray]:
    """``block``'s raw outputs through ``cert``'s nominal bias and scale factor: (gyro rad/s,
    accel m/s^2), each (N, 3)."""
    g, a = cert.gyro, cert.accel
    gyro = (block.gyro - g.bias) / g.scale_factor * g.unit_to_si
    accel = (block.accel - a.bias) / a.scale_factor * a.unit_to_si
    return gyro, accel


class NativeEncoder:
    """The project's own board (spec/wire-protocol.md): sample frames in counts."""

    name = "native"
    garbage_alphabet = bytes(b for b in range(256) if b != 0xAA)
    dialogue = False

    def __init__(self, cert: Certificate, **_: Any) -> None:
        self.certificate = cert
        self._seq = 1

    def encode(self, block: SampleBlock) -> bytes:
        """Sample frames of ``block`` (whole counts), seq counting on."""
        n = len(block)
        if not n:
            return b""
        data = encode_samples(
            self._seq,
            np.rint(block.t * 1e6),
            np.hstack([block.gyro, block.accel]),
            block.temp,
            block.flags,
        )
        self._seq += n
        return data

    def answer(self, data: bytes) -> bytes:
        """The simulated board ignores commands (allowed by the spec)."""
        return b""

    def idle(self) -> bytes:
        """The board sends nothing before it streams."""
        return b""

    def split(self, data: bytes) -> list[tuple[bytes, bool]]:
        """Frames of the wire protocol, sample frames flagged."""
        return [
            (data[p : p + n], t == TYPE_SAMPLE and n == SAMPLE_FRAME_SIZE)
            for p, t, n in frame_spans(data)
        ]

    def corrupt(self, frame: bytes) -> bytes | None:
        """A sample frame with its CRC broken (:func:`.transport.corrupt_sample_frames`)."""
        bad, k = corrupt_sample_frames(frame)
        return bad if k else None


class MavlinkEncoder:
    """A fake PX4 autopilot: HEARTBEAT every second, HIGHRES_IMU for every sample (the
    certificate's nominal calibration applied, SI units; ``message="scaled"``: SCALED_IMU in
    mg and mrad/s, whole numbers, time in ms), VIBRATION at 10 Hz; answers
    COMMAND_LONG (SET_MESSAGE_INTERVAL accepted, REQUEST_MESSAGE of AUTOPILOT_VERSION with
    that message) and everything else with MAV_RESULT_UNSUPPORTED. Everything is encoded by
    pymavlink (never by the source's decoder)."""

    name = "mavlink"
    garbage_alphabet = bytes(b for b in range(256) if b not in (0xFD, 0xFE))
    dialogue = False  # the source asks for rates and identity but streams without answers

    def __init__(
        self,
        cert: Certificate,
        sysid: int = 1,
        compid: int = 1,
        uid: int = 0x0033_0021_3130_5111,
        fields_updated: int = 0x103F,
        mavlink1: bool = False,
        message: str = "highres",
    ) -> None:
        if message not in ("highres", "scaled"):
            raise BenchError(f"fake autopilot: message must be highres or scaled, got {message!r}")
        self.message = message
        self.dialect = dialect = load_pymavlink()
        self.scenario_certificate = cert
        self.certificate = calibrated_certificate(cert)
        self.mav = dialect.MAVLink(None, sysid, compid)
        self._host = dialect.MAVLink(None, 255, 0)
        self._host.robust_parsing = True
        self.uid = uid
        self.fields_updated = fields_updated
        self.mavlink1 = mavlink1
        self.commands: list[Any] = []  #: COMMAND_LONG messages the host sent
        self.heartbeats_received = 0
        self._next_heartbeat: float | None = None  # sample time, s
        self._next_vibration: float | None = None
        self._vib: list[list[float]] = []
        self._mg = units.factor("accel", "m/s^2", "mg")
        self._mrad = units.factor("gyro", "rad/s", "mrad/s")

    def pack(self, msg: Any) -> bytes:
        """One message's frame, as this autopilot sends it (the link sequence counting on)."""
        frame = bytes(msg.pack(self.mav, force_mavlink1=self.mavlink1))
        self.mav.seq = (self.mav.seq + 1) % 256  # pymavlink counts in send(), not pack()
        return frame

    def heartbeat(self) -> bytes:
        """A PX4 quadrotor's HEARTBEAT (MAV_TYPE_QUADROTOR, MAV_AUTOPILOT_PX4, standby)."""
        return self.pack(self.mav.heartbeat_encode(2, 12, 0, 0, 3))

    def encode(self, block: SampleBlock) -> bytes:
        """HEARTBEATs (1 Hz), one HIGHRES_IMU per sample and VIBRATIONs (10 Hz: the standard
        deviation of the accelerations since the last one), in time order."""
        if not len(block):
            return b""
        gyro, accel = calibrate(block, self.scenario_certificate)
        temp = block.temp if block.temp is not None else np.full(len(block), 25.0)
        enc = self.mav.highres_imu_encode
        zeros = (0.0,) * 6  # magnetometer and pressures: not simulated
        out: list[bytes] = []
        rows = zip(block.t.tolist(), gyro.tolist(), accel.tolist(), temp.tolist(), strict=True)
        for t, g, a, tc in rows:
            if self._next_heartbeat is None or t >= self._next_heartbeat:
                self._next_heartbeat = (self._next_heartbeat or t) + 1.0
                out.append(self.heartbeat())
            t_us = int(round(t * 1e6))
            if self.message == "scaled":  # SCALED_IMU: mg, mrad/s and cdegC in int16
                ia = [int(round(v * self._mg)) for v in a]
                ig = [int(round(v * self._mrad)) for v in g]
                imu = self.mav.scaled_imu_encode(
                    t_us // 1000, *ia, *ig, 0, 0, 0, int(round(tc * 100)) or 1
                )
                out.append(self.pack(imu))
            else:
                out.append(self.pack(enc(t_us, *a, *g, *zeros, tc, self.fields_updated)))
            self._vib.append(a)
            if self._next_vibration is None:
                self._next_vibration = t + 0.1
            elif t >= self._next_vibration:
                self._next_vibration += 0.1
                rms = np.std(np.array(self._vib), axis=0).tolist()
                self._vib = []
                out.append(self.pack(self.mav.vibration_encode(t_us, *rms, 0, 0, 0)))
        return b"".join(out)

    def idle(self) -> bytes:
        """A HEARTBEAT: an autopilot announces itself whether or not anyone listens."""
        return self.heartbeat()

    def split(self, data: bytes) -> list[tuple[bytes, bool]]:
        """MAVLink frames by their length fields; the IMU messages are the samples."""
        out: list[tuple[bytes, bool]] = []
        pos = 0
        while pos < len(data):
            if data[pos] == 0xFD:
                signed = data[pos + 2] & 1
                size = 10 + data[pos + 1] + 2 + (13 if signed else 0)
                msgid = data[pos + 7] | (data[pos + 8] << 8) | (data[pos + 9] << 16)
            elif data[pos] == 0xFE:
                size, msgid = 6 + data[pos + 1] + 2, data[pos + 5]
            else:
                raise BenchError(f"fake autopilot: no frame at byte {pos}")
            out.append((data[pos : pos + size], msgid in (105, 26, 116, 129, 27)))
            pos += size
        return out

    def corrupt(self, frame: bytes) -> bytes | None:
        """The frame with one payload byte inverted, when neither it nor any other byte after
        the first is a frame start (0xFD, 0xFE)."""
        if any(b in (0xFD, 0xFE) for b in frame[1:]):
            return None
        head = 10 if frame[0] == 0xFD else 6
        for i in range(head, len(frame) - 2):
            flipped = frame[i] ^ 0xFF
            if flipped not in (0xFD, 0xFE):
                return frame[:i] + bytes([flipped]) + frame[i + 1 :]
        return None

    def autopilot_version(self) -> bytes:
        """AUTOPILOT_VERSION of a PX4 v1.14.3 release on a Holybro board."""
        return self.pack(
            self.mav.autopilot_version_encode(
                0xE4EF,
                0x010E03FF,
                0,
                0,
                0x00380000,
                list(b"\x1a\x2b\x3c\x4d\x5e\x6f\x70\x81"),
                [0] * 8,
                [0] * 8,
                0x3162,
                0x0035,
                self.uid,
            )
        )

    def answer(self, data: bytes) -> bytes:
        """COMMAND_ACKs (and AUTOPILOT_VERSION) for the host's commands."""
        out: list[bytes] = []
        try:
            msgs = self._host.parse_buffer(data) or []
        except Exception:  # a garbled request is not answered, as an autopilot would not
            return b""
        d = self.dialect
        for m in msgs:
            kind = m.get_type()
            if kind == "HEARTBEAT":
                self.heartbeats_received += 1
            if kind != "COMMAND_LONG":
                continue
            self.commands.append(m)
            if m.command == d.MAV_CMD_SET_MESSAGE_INTERVAL:
                result = d.MAV_RESULT_ACCEPTED
            elif m.command == d.MAV_CMD_REQUEST_MESSAGE and int(m.param1) == 148:
                result = d.MAV_RESULT_ACCEPTED
            else:
                result = d.MAV_RESULT_UNSUPPORTED
            out.append(self.pack(self.mav.command_ack_encode(m.command, result, 0, 0, 255, 0)))
            if m.command == d.MAV_CMD_REQUEST_MESSAGE and result == d.MAV_RESULT_ACCEPTED:
                out.append(self.autopilot_version())
        return b"".join(out)


def device_units(block: SampleBlock, cert: Certificate, out: dict[str, str]) -> SampleBlock:
    """``block``'s raw outputs calibrated with ``cert``'s nominal bias and scale factor
    (:func:`calibrate`) in a device's physical units ``out`` (e.g. deg/s and g)."""
    gyro, accel = calibrate(block, cert)
    return SampleBlock(
        t=block.t,
        gyro=gyro * units.factor("gyro", "rad/s", out["gyro"]),
        accel=accel * units.factor("accel", "m/s^2", out["accel"]),
        temp=block.temp,
        flags=block.flags,
    )


class WitmotionEncoder:
    """A fake WitMotion WT901 (the frames of :func:`.fake_witmotion.encode_frames`): per
    sample a time frame, an acceleration frame (g) and an angular-rate frame (deg/s), the
    certificate's nominal calibration applied (the device's output is calibrated).

    One sample's three frames are one unit of :meth:`split` (the device's lost and
    repeated samples are seen by its clock, not by a frame counter); :meth:`corrupt` turns
    a sample into its angular-rate frame alone with a payload byte changed, so a corrupted
    sample is one checksum error of 11 skipped bytes and one lost sample."""

    name = "witmotion"
    garbage_alphabet = bytes(b for b in range(256) if b != fake_witmotion.HEAD)
    dialogue = False
    units = {"gyro": "deg/s", "accel": "g"}

    def __init__(self, cert: Certificate, with_time: bool = True) -> None:
        self.scenario_certificate = cert
        self.certificate = calibrated_certificate(cert)
        self.with_time = with_time
        self._size = 11 * (3 if with_time else 2)

    def encode(self, block: SampleBlock) -> bytes:
        """The frames of ``block``, sample by sample."""
        if not len(block):
            return b""
        dev = device_units(block, self.scenario_certificate, self.units)
        return fake_witmotion.encode_frames(dev, self.with_time)

    def answer(self, data: bytes) -> bytes:
        """The WT901 streams whatever the host sends (its set-up is done beforehand)."""
        return b""

    def idle(self) -> bytes:
        """Nothing: the fake streams only samples."""
        return b""

    def split(self, data: bytes) -> list[tuple[bytes, bool]]:
        """One unit per sample: its time, acceleration and angular-rate frames."""
        size = self._size
        return [(data[p : p + size], True) for p in range(0, len(data), size)]

    def corrupt(self, frame: bytes) -> bytes | None:
        """The sample's angular-rate frame with a payload byte inverted (None when a frame
        start byte 0x55 would appear after the first byte)."""
        rate = frame[-11:]
        head = fake_witmotion.HEAD
        if head in rate[1:]:
            return None
        for i in range(2, 10):
            flipped = rate[i] ^ 0xFF
            if flipped != head:
                return rate[:i] + bytes([flipped]) + rate[i + 1 :]
        return None


class ISensorEncoder:
    """A fake iSensor SPI Buffer board with an ADIS1647x behind it: the board's command
    line (:class:`.fake_isensor.ISensorBoardCLI`) answers the host's set-up, and while its
    buffered capture runs each sample is one entry line
    (:func:`.fake_isensor.entry_lines`: 16-bit burst, the part's LSB sizes), the
    certificate's nominal calibration applied. Samples taken while the capture is off are
    not sent (the IMU's data counter runs on: the host counts them lost).

    Garbage is blank lines (``\\n``): a line protocol can skip nothing else byte for byte
    without the entry that follows it."""

    name = "isensor"
    garbage_alphabet = b"\n"
    dialogue = True

    def __init__(
        self, cert: Certificate, model: str = "adis16475-2", self_test_fails: bool = False
    ) -> None:
        if model not in fake_isensor.ISENSOR_LSB:
            known = ", ".join(fake_isensor.ISENSOR_LSB)
            raise BenchError(f"fake iSensor board: model {model!r} not one of {known}")
        part, _, dash = model.removeprefix("adis").partition("-")
        self.board = fake_isensor.ISensorBoardCLI(
            prod_id=int(part), range_model=int(dash or 3), self_test_fails=self_test_fails
        )
        self.model = model
        self.gyro_lsb, self.accel_lsb = fake_isensor.ISENSOR_LSB[model]
        self.units = {"gyro": "deg/s", "accel": "g"}
        self.scenario_certificate = cert
        self.certificate = calibrated_certificate(cert)
        self._count = 1  # the IMU's DATA_CNTR of the next sample

    def encode(self, block: SampleBlock) -> bytes:
        """Entry lines of ``block`` while the capture runs (b"" otherwise)."""
        n = len(block)
        if not n:
            return b""
        first = self._count
        self._count += n
        if not self.board.capturing:
            return b""
        dev = device_units(block, self.scenario_certificate, self.units)
        lines = fake_isensor.entry_lines(dev, self.gyro_lsb, self.accel_lsb, first_count=first)
        return b"".join(self.board.entries(lines))

    def answer(self, data: bytes) -> bytes:
        """The board's answers (echo, register reads) to the host's command lines."""
        return self.board.receive(data)

    def idle(self) -> bytes:
        """Nothing: the board speaks when spoken to."""
        return b""

    def split(self, data: bytes) -> list[tuple[bytes, bool]]:
        """The entry lines (each a sample)."""
        lines = data.split(b"\n")
        out = [(ln + b"\n", True) for ln in lines[:-1]]
        if lines[-1]:
            out.append((lines[-1], False))
        return out

    def corrupt(self, frame: bytes) -> bytes | None:
        """The line with one hex digit of its gyro x word changed: the signature and the
        burst checksum fail."""
        i = 7 * 5  # word 7 (DATA_2: X_GYRO_OUT), 4 digits and a comma per word
        if len(frame) < i + 4:
            return None
        digit = b"1" if frame[i : i + 1] == b"0" else b"0"
        return frame[:i] + digit + frame[i + 1 :]


class IIOPort:
    """A fake IIO device (:class:`.fake_iio.FakeIIODevice`) as the port a feeder writes
    to: its sysfs tree at ``LINK-sys``, its FIFO (``/dev/iio:device0``) in ``LINK-dev``;
    closing it unplugs the device (the FIFO and the tree go away)."""

    def __init__(self, link: Path, encoder: IIOEncoder) -> None:
        self.device = fake_iio.FakeIIODevice(
            iio_root(link), iio_devdir(link), encoder.model, encoder.channels, 0
        )

    @property
    def master_fd(self) -> int:
        """The FIFO's writing end."""
        return self.device.fd

    @property
    def master_open(self) -> bool:
        """True while the device is plugged."""
        return self.device._fd is not None

    def close(self) -> None:
        """Unplug the device."""
        self.device.unplug()


def iio_root(link: Path) -> Path:
    """The fake IIO devices directory of a bench run whose device path is ``link``."""
    return Path(f"{link}-sys")


def iio_devdir(link: Path) -> Path:
    """The directory of the fake ``iio:device0`` FIFO for ``link``."""
    return Path(f"{link}-dev")


class IIOEncoder:
    """A fake Linux IIO IMU, an ADIS16475-2 as the kernel's adis16475 driver presents it:
    the scan elements ``anglvel_x/y/z`` and ``accel_x/y/z`` as ``le:s32/32>>0`` (the
    32-bit burst outputs) with their ``scale`` (rad/s and m/s^2 per LSB: the part's 1/40
    deg/s and 0.25 mg per 16-bit LSB over 65536), ``timestamp`` (ns, ``le:s64/64>>0``)
    and a temperature channel the reader must switch off; each sample one packed record
    (:func:`.fake_iio.pack_records`), the certificate's nominal calibration applied.

    A kernel buffer has no framing and no checksum: garbage and corrupted records cannot
    happen on it (a scenario with them is refused for this device); lost and repeated
    records are seen by the time stamps, an unplug removes the device."""

    name = "iio"
    garbage_alphabet = b""
    dialogue = False
    units = {"gyro": "rad/s", "accel": "m/s^2"}
    GYRO_SCALE = fake_iio.ADIS16475_2_GYRO_SCALE  #: rad/s per LSB of the 32-bit output
    ACCEL_SCALE = fake_iio.ADIS16475_2_ACCEL_SCALE  #: m/s^2 per LSB

    def __init__(self, cert: Certificate, model: str = "adis16475-2") -> None:
        self.model = model
        self.scenario_certificate = cert
        self.certificate = calibrated_certificate(cert)
        self.channels = fake_iio.imu_channels(self.GYRO_SCALE, self.ACCEL_SCALE, temperature=True)
        #: the records of the channels the reader enables (its six and the time stamp)
        self._read = [c for c in self.channels if c.name != "temp0"]
        self.record_size = len(fake_iio.pack_records(self._read, self._columns(None)))

    def _columns(self, block: SampleBlock | None) -> dict[str, np.ndarray]:
        if block is None:  # one record of zeros (its size)
            return {c.name: np.zeros(1) for c in self._read}
        dev = device_units(block, self.scenario_certificate, self.units)
        cols = {
            f"anglvel_{a}": np.rint(dev.gyro[:, i] / self.GYRO_SCALE) for i, a in enumerate("xyz")
        }
        cols.update(
            {f"accel_{a}": np.rint(dev.accel[:, i] / self.ACCEL_SCALE) for i, a in enumerate("xyz")}
        )
        cols["timestamp"] = np.rint(np.asarray(block.t) * 1e9)
        return cols

    def encode(self, block: SampleBlock) -> bytes:
        """One packed record per sample, outputs clipped to the 32-bit range."""
        if not len(block):
            return b""
        cols = self._columns(block)
        for name in cols:
            if name != "timestamp":
                cols[name] = np.clip(cols[name], -(2**31), 2**31 - 1)
        return fake_iio.pack_records(self._read, cols)

    def answer(self, data: bytes) -> bytes:
        """Nothing is sent to a kernel buffer."""
        return b""

    def idle(self) -> bytes:
        """Nothing before the buffer is enabled."""
        return b""

    def split(self, data: bytes) -> list[tuple[bytes, bool]]:
        """The records (each a sample)."""
        size = self.record_size
        return [(data[p : p + size], True) for p in range(0, len(data), size)]

    def corrupt(self, frame: bytes) -> bytes | None:
        """None: a record has no checksum to break."""
        return None

    def open_port(self, link: Path) -> IIOPort:
        """Lay the fake device out for a bench run whose device path is ``link``."""
        return IIOPort(link, self)


#: the fake devices by name: ``device:`` of a bench scenario, ``make_encoder(name)``
ENCODERS: dict[str, Callable[..., DeviceEncoder]] = {
    "native": NativeEncoder,
    "mavlink": MavlinkEncoder,
    "witmotion": WitmotionEncoder,
    "isensor": ISensorEncoder,
    "iio": IIOEncoder,
}
#: the source URL of each device for a port ``path`` and the sample ``rate`` (Hz); the IIO
#: device is a sysfs tree and a FIFO beside ``path`` (:class:`IIOPort`)
SOURCE_URLS: dict[str, str] = {
    "native": "serial://{path}",
    "mavlink": "mavlink://{path}",
    "witmotion": "witmotion://{path}?rate={rate:g}",
    "isensor": "isensor://{path}",
    "iio": "iio://iio:device0?root={path}-sys&devdir={path}-dev&rate={rate:g}",
}


def make_encoder(name: str, cert: Certificate, **options: Any) -> DeviceEncoder:
    """The fake device ``name`` (:data:`ENCODERS`) for samples of ``cert``'s sensor."""
    try:
        factory = ENCODERS[name]
    except KeyError:
        raise BenchError(f"unknown device {name!r}; known: {', '.join(sorted(ENCODERS))}") from None
    return factory(cert, **options)


def blocks_of(board: SimulatedBoard, chunk_s: float = 0.05) -> Iterator[SampleBlock]:
    """The board's simulated samples (its raw outputs) in blocks of ``chunk_s`` s."""
    n = max(1, int(round(chunk_s * board.rate_hz)))
    while not board.exhausted:
        _, block = board.generate(n)
        if len(block):
            yield block


class DeviceWriter(threading.Thread):
    """Writes a fake device's bytes into a pty master, paced in sample time.

    Block i is written when ``(t_first_of_block - t0) / speed`` s of wall time have passed
    (``speed`` 0: as fast as the host reads). Between blocks the host's bytes are read and
    the encoder's answers written. ``before`` (optional) is called with each block before it
    is encoded and may return bytes to send first (a transport fault: garbage, a corrupted
    frame). With ``wait_host_s`` the device first sends only :meth:`DeviceEncoder.idle`
    (every 0.1 s) until the host has sent it something or that many seconds have passed
    (opening a port flushes what arrived before). Stops at the end of the blocks, on
    :meth:`stop`, or when the pty goes away (an unplug: :meth:`PtyPair.close_master` stops
    it); :attr:`remaining` then holds the block iterator, for a writer on the replugged pty
    to continue with.
    """

    def __init__(
        self,
        pair: PtyPair,
        encoder: DeviceEncoder,
        blocks: Iterable[SampleBlock],
        speed: float = 1.0,
        before: Callable[[SampleBlock], bytes] | None = None,
        wait_host_s: float | None = None,
    ) -> None:
        super().__init__(daemon=True, name=f"DeviceWriter-{encoder.name}")
        self.wait_host_s = wait_host_s
        self.host_spoke = False  #: the host has sent the device something
        self.pair = pair
        self.fd = pair.master_fd
        pair.add_writer(self)  # close_master stops it
        self.encoder = encoder
        self.remaining: Iterator[SampleBlock] = iter(blocks)
        self.speed = float(speed)
        self.before = before
        self.bytes_written = 0
        self.samples_written = 0
        self.t_last: float | None = None  #: sample time of the last sample written, s
        self.error: OSError | None = None
        self._stop_event = threading.Event()

    def run(self) -> None:
        t0: float | None = None
        try:
            if self.wait_host_s is not None:
                end = time.monotonic() + self.wait_host_s
                while not self.host_spoke and time.monotonic() < end:
                    if self._stop_event.wait(0.1):
                        return
                    write_all(self.fd, self.encoder.idle(), self._stop_event)
                    self._answer()
            start = time.monotonic()
            for block in self.remaining:
                if t0 is None:
                    t0 = float(block.t[0])
                if self.speed > 0:
                    delay = start + (float(block.t[0]) - t0) / self.speed - time.monotonic()
                    if delay > 0 and self._stop_event.wait(delay):
                        break
                if self._stop_event.is_set():
                    break
                self._answer()
                data = self.before(block) if self.before is not None else b""
                data += self.encoder.encode(block)
                self.bytes_written += write_all(self.fd, data, self._stop_event)
                self.samples_written += len(block)
                self.t_last = float(block.t[-1])
                if self._stop_event.is_set():
                    break
            self._answer()
        except OSError as e:  # EIO/EBADF when the pty went away
            if e.errno not in (errno.EIO, errno.EBADF, errno.EPIPE):
                raise
            self.error = e

    def _answer(self) -> None:
        """Read what the host sent and write the device's answers."""
        data = read_available(self.fd)
        if data:
            self.host_spoke = True
            reply = self.encoder.answer(data)
            if reply:
                self.bytes_written += write_all(self.fd, reply, self._stop_event)

    def stop(self, timeout_s: float = 2.0) -> None:
        """Stop writing and wait up to ``timeout_s`` seconds for the thread."""
        self._stop_event.set()
        if self.is_alive() and threading.current_thread() is not self:
            self.join(timeout_s)
        self.pair.remove_writer(self)


__all__ = [
    "ENCODERS",
    "SOURCE_URLS",
    "DeviceEncoder",
    "DeviceWriter",
    "IIOEncoder",
    "IIOPort",
    "ISensorEncoder",
    "MavlinkEncoder",
    "NativeEncoder",
    "WitmotionEncoder",
    "blocks_of",
    "calibrate",
    "calibrated_certificate",
    "device_units",
    "iio_devdir",
    "iio_root",
    "make_encoder",
]

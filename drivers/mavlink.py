"""MAVLink flight controllers (PX4, ArduPilot) as IMU sources (extra ``[mavlink]``: pymavlink).

::

    mavlink:///dev/ttyACM0?baud=115200&imu=0&rate=250   USB or telemetry serial port
    mavlink+udp://:14550                                a router's UDP endpoint (listen)
    mavlink+udp://192.168.1.5:14550?mode=connect        send to a router (it answers us)

Query keys: ``baud`` (bit/s, serial only, default 115200; USB CDC ignores it), ``imu``
(instance, default 0), ``message`` (``auto``, ``highres``, ``scaled``, ``raw``; default
``auto``), ``rate`` (Hz asked with MAV_CMD_SET_MESSAGE_INTERVAL, default 250; ``0`` asks
nothing), ``sysid`` (the autopilot's system id; default the first autopilot heard),
``exclusive`` (serial), ``mode`` (UDP: ``listen`` or ``connect``).

The samples are one IMU message kind, in its own units (declared in ``meta["units"]`` and
``device_info["units"]``; :mod:`imudiag.units` conforms them to the certificate):

- HIGHRES_IMU (#105, instance = field ``id``): m/s^2 and rad/s, preferred; a message whose
  ``fields_updated`` lacks any of the six accel/gyro bits is not a sample (counted in
  ``device_info["not_updated"]``);
- SCALED_IMU, SCALED_IMU2, SCALED_IMU3 (#26, #116, #129 for instances 0, 1, 2): mg and mrad/s;
- RAW_IMU (#27, instance = ``id``): counts (for a certificate in counts).

With ``message=auto`` the kind is HIGHRES_IMU as soon as one arrives, else after
:data:`CHOOSE_S` seconds of device time the best kind heard; samples of the chosen kind
heard meanwhile are kept. ``t`` is the message's time stamp (``time_usec`` or
``time_boot_ms``) in s; a repeated stamp is a duplicate, a stamp going backwards (a reboot)
re-anchors the timeline as the native decoder does.

Framing is this module's (both MAVLink 1 and 2, signed frames accepted unchecked), with the
native decoder's counters (:class:`~imudiag.drivers.wire.Counters`): bytes that are not a
frame of a known message with a good X.25 CRC are ``skipped_bytes`` (a bad frame is
rescanned from its second byte), ``crc_errors`` counts complete frames of a known message
whose CRC fails, ``lost`` the gaps in the autopilot's 8-bit sequence, ``duplicates`` a frame
repeated byte for byte. The message definitions (lengths, CRC extras) and the encoding of
what is sent come from pymavlink's ``ardupilotmega`` dialect (a superset of ``common``).

Sent to the autopilot, driven by its HEARTBEATs (no wall clock): a HEARTBEAT of our own
(an onboard controller, sysid 255, compid 191) for each of the autopilot's,
MAV_CMD_SET_MESSAGE_INTERVAL for the IMU message and for VIBRATION (10 Hz), and
MAV_CMD_REQUEST_MESSAGE for AUTOPILOT_VERSION, each repeated on the next HEARTBEATs until
acknowledged (at most :data:`REQUEST_TRIES` times).

``device_info`` (docs/devices.md): ``vendor``, ``product``, ``serial``, ``firmware``,
``datasheet`` (the shared keys), then ``autopilot``, ``vehicle_type``, ``sysid``, ``compid``,
``protocol``, ``message``, ``imu``, ``units``, ``rate_hz`` (measured from the time stamps),
``rate_request`` and ``vibration`` = ``{"accel_rms": [x, y, z], "unit": "m/s^2",
"clipping": [c0, c1, c2], "t": s}`` (VIBRATION #241: the vibration levels and the clipping
events of accelerometers 0, 1, 2 since boot).
"""

from __future__ import annotations

import binascii
import importlib
import re
import socket
import struct
from types import ModuleType
from typing import Any, ClassVar

import numpy as np

from imudiag.certificate import FLIGHT_CONTROLLER_DATASHEET
from imudiag.samples import SampleBlock

from .base import SourceError, SourceURL, register
from .bytesource import ByteSource
from .serial_port import SerialSource
from .wire import Counters

EXTRA = "mavlink"  #: the optional extra that installs pymavlink
DIALECT = "pymavlink.dialects.v20.ardupilotmega"

STX_V1 = 0xFE
STX_V2 = 0xFD
HEADER_V1 = 6  #: STX, len, seq, sysid, compid, msgid
HEADER_V2 = 10  #: STX, len, incompat, compat, seq, sysid, compid, msgid (3 bytes)
CRC_SIZE = 2
SIGNATURE_SIZE = 13
IFLAG_SIGNED = 0x01

MSG_HEARTBEAT = 0
MSG_SCALED_IMU = 26
MSG_RAW_IMU = 27
MSG_COMMAND_ACK = 77
MSG_HIGHRES_IMU = 105
MSG_SCALED_IMU2 = 116
MSG_SCALED_IMU3 = 129
MSG_AUTOPILOT_VERSION = 148
MSG_VIBRATION = 241
CMD_SET_MESSAGE_INTERVAL = 511
CMD_REQUEST_MESSAGE = 512

#: IMU message kinds, best first: (name, units, data-sheet key stem)
KINDS = ("highres", "scaled", "raw")
KIND_MESSAGES = {"highres": "HIGHRES_IMU", "scaled": "SCALED_IMU", "raw": "RAW_IMU"}
KIND_UNITS: dict[str, dict[str, str]] = {
    "highres": {"gyro": "rad/s", "accel": "m/s^2"},
    "scaled": {"gyro": "mrad/s", "accel": "mg"},
    "raw": {"gyro": "count", "accel": "count"},
}
#: the bundled data-sheet certificate (config/datasheets/) for samples in physical units:
#: a flight controller's MEMS IMU does not name its part over MAVLink, so one generic
#: certificate (docs/devices.md); none for RAW_IMU counts (their scale is the board's)
DATASHEET_PHYSICAL = FLIGHT_CONTROLLER_DATASHEET
SCALED_IDS = {0: MSG_SCALED_IMU, 1: MSG_SCALED_IMU2, 2: MSG_SCALED_IMU3}
HIGHRES_UPDATED = 0x3F  #: fields_updated bits of xacc..zacc and xgyro..zgyro
CHOOSE_S = 1.0  #: s of device time ``message=auto`` waits for HIGHRES_IMU
DEFAULT_RATE_HZ = 250.0  #: IMU message rate asked by default, Hz
VIBRATION_RATE_HZ = 10.0  #: VIBRATION rate asked, Hz
REQUEST_TRIES = 3  #: each request is sent on up to this many autopilot HEARTBEATs
OWN_SYSID = 255
OWN_COMPID = 191  #: MAV_COMP_ID_ONBOARD_COMPUTER
RATE_WINDOW_US = 1_000_000  #: device time, us, over which the obtained rate is measured
AUTOPILOTS = {3: "ArduPilot", 12: "PX4", 0: "generic", 8: "invalid"}
RESULTS = {
    0: "accepted",
    1: "temporarily rejected",
    2: "denied",
    3: "unsupported",
    4: "failed",
    5: "in progress",
    6: "cancelled",
}
#: USB vendor ids of AUTOPILOT_VERSION.vendor_id seen on flight controllers
USB_VENDORS = {
    0x26AC: "3D Robotics",
    0x2DAE: "CubePilot (Hex)",
    0x3162: "Holybro",
    0x1209: "pid.codes (ArduPilot)",
    0x0483: "STMicroelectronics",
    0x27AC: "Vertical Technologies",
    0x35A7: "ARK Electronics",
}

_HIGHRES = struct.Struct("<Q13fHB")
_SCALED = struct.Struct("<I10h")
_RAW = struct.Struct("<Q9hBh")
_STX = re.compile(b"[\xfd\xfe]")
_REV8 = bytes(int(f"{i:08b}"[::-1], 2) for i in range(256))


def _rev16(c: int) -> int:
    return _REV8[c >> 8] | (_REV8[c & 0xFF] << 8)


#: every 16-bit value bit-reversed: a stored checksum in the form :meth:`MavlinkDecoder._scan`
#: computes it (the CRC register on bit-reversed bytes)
_REV16 = [_rev16(c) for c in range(1 << 16)]


def x25_crc(data: bytes) -> int:
    """MAVLink's X.25 checksum (CRC-16/MCRF4XX: reflected poly 0x1021, init 0xFFFF) of
    ``data``, through the standard library's CRC-CCITT on bit-reversed bytes."""
    return _rev16(binascii.crc_hqx(bytes(data).translate(_REV8), 0xFFFF))


def load_pymavlink() -> ModuleType:
    """pymavlink's ``ardupilotmega`` dialect, or SourceError naming the extra to install."""
    try:
        return importlib.import_module(DIALECT)
    except ImportError:
        raise SourceError(
            "mavlink:// needs the Python package 'pymavlink', not installed: "
            f"pip install 'imudiag[{EXTRA}]'"
        ) from None


def _version_text(v: int) -> str:
    """A MAVLink software version (0xMMmmPPTT) as ``major.minor.patch[-type]``."""
    major, minor, patch, kind = (v >> 24) & 0xFF, (v >> 16) & 0xFF, (v >> 8) & 0xFF, v & 0xFF
    tag = {0: "dev", 64: "alpha", 128: "beta", 192: "rc", 255: ""}.get(kind, f"type{kind}")
    return f"{major}.{minor}.{patch}" + (f"-{tag}" if tag else "")


class _Request:
    """One request to the autopilot, repeated on its HEARTBEATs until acknowledged."""

    def __init__(self, command: int, params: tuple[float, ...], what: str) -> None:
        self.command = command
        self.params = params
        self.what = what
        self.sent = 0
        self.result: str | None = None  #: the COMMAND_ACK's result, or None


class MavlinkDecoder:
    """MAVLink bytes in, samples of one IMU message kind out (see the module docstring).

    Feed chunks of any size; frames may straddle chunks. :meth:`take_outgoing` hands the
    bytes to send to the autopilot (requests, our heartbeat). Byte accounting as the native
    decoder's: ``counters.bytes == frame_bytes + counters.skipped_bytes + pending_bytes``.
    """

    def __init__(
        self,
        counters: Counters | None = None,
        imu: int = 0,
        message: str = "auto",
        rate_hz: float = DEFAULT_RATE_HZ,
        sysid: int | None = None,
    ) -> None:
        if message not in ("auto", *KINDS):
            raise ValueError(f"message must be auto, highres, scaled or raw, got {message!r}")
        if imu not in SCALED_IDS:
            raise ValueError(f"imu instance must be 0, 1 or 2, got {imu}")
        self.dialect = load_pymavlink()
        self._map: dict[int, Any] = self.dialect.mavlink_map
        self._mav = self.dialect.MAVLink(None, OWN_SYSID, OWN_COMPID)
        self._mav.robust_parsing = True
        self.counters = counters if counters is not None else Counters()
        self.imu = imu
        self.wanted = message
        self.kind: str | None = None if message == "auto" else message
        self.rate_hz = rate_hz
        self.target_sysid = sysid
        self.target_compid: int | None = None
        self.device_info: dict[str, Any] = {"vendor": None, "product": None, "serial": None}
        self.device_info.update({"firmware": None, "datasheet": None, "imu": imu})
        self.frame_bytes = 0  #: bytes of good frames (any message)
        self.messages = 0  #: good frames of any message
        self.not_updated = 0  #: HIGHRES_IMU messages whose fields_updated lacks accel/gyro
        self.other_imu = 0  #: IMU messages of another kind or instance, not samples
        self.restarts = 0  #: time stamps going backwards (an autopilot reboot)
        self.heartbeats = 0
        self._pending = b""
        self._out: list[bytes] = []
        self._requests: list[_Request] = []
        self._last_seq: int | None = None
        self._last_crc: int | None = None
        self._t_last_us: int | None = None  # raw stamp of the last sample, us
        self._t_abs_us = 0  # unwrapped time of the last sample, us
        self._dt_us = 0  # last positive sample interval, us
        self._n = 0  # samples delivered
        self._held: dict[str, list[tuple[float, ...]]] = {k: [] for k in KINDS}
        self._first_imu_us: int | None = None
        self._rate_mark: tuple[int, int] | None = None  # (t us, samples) a window began
        self._lengths = {mid: cls.unpacker.size for mid, cls in self._map.items()}
        #: each message's CRC extra byte, bit-reversed as :meth:`_scan` takes its CRCs
        self._extras = {mid: bytes([_REV8[cls.crc_extra]]) for mid, cls in self._map.items()}
        self._v1 = False  # the autopilot's HEARTBEAT came as MAVLink 1: answer in kind

    # -- public ---------------------------------------------------------------

    @property
    def pending_bytes(self) -> int:
        """Bytes held back waiting for the rest of a frame."""
        return len(self._pending)

    def feed(self, data: bytes | bytearray | memoryview) -> SampleBlock:
        """Decode ``data`` (plus held-back bytes); the samples of the chosen IMU kind."""
        data = bytes(data)
        self.counters.bytes += len(data)
        buf = self._pending + data if self._pending else data
        rows: list[tuple[float, ...]] = []
        self._pending = buf[self._scan(buf, rows) :]
        return self._block(rows)

    def finish(self) -> SampleBlock:
        """End of stream: the held-back bytes are counted as skipped."""
        self.counters.skipped_bytes += len(self._pending)
        self._pending = b""
        return SampleBlock.empty()

    def drop_pending(self) -> None:
        """A new connection: drop held-back bytes (skipped), forget the link sequence, ask
        for the rate and the identity again."""
        self.counters.skipped_bytes += len(self._pending)
        self._pending = b""
        self._last_seq = None
        self._last_crc = None
        self._requests = []

    def take_outgoing(self) -> bytes:
        """Bytes to send to the autopilot since the last call (b"" if none)."""
        out, self._out = self._out, []
        return b"".join(out)

    def hello(self) -> bytes:
        """Our HEARTBEAT: an onboard controller (MAV_TYPE 18) that is no autopilot (8)."""
        frame = self._mav.heartbeat_encode(18, 8, 0, 0, 4).pack(self._mav, force_mavlink1=self._v1)
        self._mav.seq = (self._mav.seq + 1) % 256  # pymavlink counts in send(), not pack()
        return bytes(frame)

    def request_rate(self, rate_hz: float) -> None:
        """Ask the autopilot for ``rate_hz`` of the IMU message (sent on its next HEARTBEAT)."""
        self.rate_hz = float(rate_hz)
        self._requests = [r for r in self._requests if r.what != "rate"]

    def request_identity(self) -> None:
        """Ask for AUTOPILOT_VERSION again (sent on the autopilot's next HEARTBEAT)."""
        self._requests = [r for r in self._requests if r.what != "identity"]

    # -- framing --------------------------------------------------------------

    def _scan(self, buf: bytes, rows: list[tuple[float, ...]]) -> int:
        """Frames of ``buf`` handled in order; returns the position consumed up to."""
        c = self.counters
        n = len(buf)
        rbuf = buf.translate(_REV8)  # CRCs are taken on bit-reversed bytes (x25_crc)
        lengths, extras = self._lengths, self._extras
        crc_hqx = binascii.crc_hqx
        pos = 0
        rev16 = _REV16
        while pos < n:
            i = pos
            if buf[i] != STX_V2 and buf[i] != STX_V1:
                m = _STX.search(buf, pos)
                if m is None:
                    c.skipped_bytes += n - pos
                    return n
                i = m.start()
                c.skipped_bytes += i - pos
                pos = i
            if buf[i] == STX_V2:
                if n - i < HEADER_V2:
                    return i
                length, iflags = buf[i + 1], buf[i + 2]
                msgid = buf[i + 7] | (buf[i + 8] << 8) | (buf[i + 9] << 16)
                head = HEADER_V2
                full = lengths.get(msgid, -1)
                ok = 0 <= length <= full and not (iflags & ~IFLAG_SIGNED)
                total = head + length + CRC_SIZE + (SIGNATURE_SIZE if iflags & 1 else 0)
            else:
                if n - i < HEADER_V1:
                    return i
                length, msgid = buf[i + 1], buf[i + 5]
                head = HEADER_V1
                full = lengths.get(msgid, -1)
                ok = 0 <= length <= full
                total = head + length + CRC_SIZE
            if not ok:  # not the start of a frame of a message we know
                c.skipped_bytes += 1
                pos = i + 1
                continue
            if n - i < total:
                return i
            end = i + head + length
            # the register on bit-reversed bytes, against the stored checksum reversed
            crc = crc_hqx(extras[msgid], crc_hqx(rbuf[i + 1 : end], 0xFFFF))
            if crc != rev16[buf[end] | (buf[end + 1] << 8)]:
                c.crc_errors += 1
                c.skipped_bytes += 1
                pos = i + 1
                continue
            self.frame_bytes += total
            self.messages += 1
            payload = buf[i + head : end]
            if length < full:  # MAVLink 2 trims trailing zero bytes
                payload += bytes(full - length)
            seq, sysid, compid = (
                buf[i + head - 6 : i + head - 3] if head == HEADER_V2 else buf[i + 2 : i + 5]
            )
            self._message(msgid, seq, sysid, compid, payload, crc, buf[i : i + total], rows)
            pos = i + total
        return pos

    # -- messages -------------------------------------------------------------

    def _from_target(self, msgid: int, sysid: int, compid: int, payload: bytes) -> bool:
        """Whether a frame comes from the autopilot followed (chosen on its first HEARTBEAT,
        or the first IMU message before any)."""
        if sysid == self.target_sysid and compid == self.target_compid:
            return True
        if self.target_sysid is None:
            if msgid == MSG_HEARTBEAT:
                autopilot = payload[5]
                if autopilot == 8 or compid != 1:  # MAV_AUTOPILOT_INVALID: a GCS, a camera
                    return False
            elif msgid not in (MSG_HIGHRES_IMU, MSG_RAW_IMU, *SCALED_IDS.values()):
                return False
            self.target_sysid = sysid
        if sysid != self.target_sysid:
            return False
        if self.target_compid is None:
            self.target_compid = compid
        return compid == self.target_compid

    def _message(
        self,
        msgid: int,
        seq: int,
        sysid: int,
        compid: int,
        payload: bytes,
        crc: int,
        frame: bytes,
        rows: list[tuple[float, ...]],
    ) -> None:
        if not self._from_target(msgid, sysid, compid, payload):
            return
        c = self.counters
        last = self._last_seq
        if last is not None:
            step = (seq - last) & 0xFF
            if step == 0:
                if crc == self._last_crc:
                    c.duplicates += 1
                    return
            elif step > 1:
                c.lost += step - 1
        self._last_seq, self._last_crc = seq, crc
        if msgid == MSG_HIGHRES_IMU:
            v = _HIGHRES.unpack(payload)
            if v[15] != self.imu:
                self.other_imu += 1
            elif v[14] & HIGHRES_UPDATED != HIGHRES_UPDATED:
                self.not_updated += 1
                self.device_info["not_updated"] = self.not_updated
            else:  # t us, gyro rad/s, accel m/s^2, temp degC
                self._imu("highres", (v[0], v[4], v[5], v[6], v[1], v[2], v[3], v[13]), rows)
        elif msgid in (MSG_SCALED_IMU, MSG_SCALED_IMU2, MSG_SCALED_IMU3):
            if msgid != SCALED_IDS[self.imu]:
                self.other_imu += 1
                return
            v = _SCALED.unpack(payload)
            temp = v[10] * 0.01 if v[10] else np.nan  # cdegC; 0: no temperature
            self._imu("scaled", (v[0] * 1000, v[4], v[5], v[6], v[1], v[2], v[3], temp), rows)
        elif msgid == MSG_RAW_IMU:
            v = _RAW.unpack(payload)
            if v[10] != self.imu:
                self.other_imu += 1
                return
            temp = v[11] * 0.01 if v[11] else np.nan
            self._imu("raw", (v[0], v[4], v[5], v[6], v[1], v[2], v[3], temp), rows)
        elif msgid == MSG_HEARTBEAT:
            self._v1 = frame[0] == STX_V1
            self._heartbeat(self._decode(frame))
        elif msgid == MSG_VIBRATION:
            m = self._decode(frame)
            if m is not None:
                self.device_info["vibration"] = {
                    "accel_rms": [float(m.vibration_x), float(m.vibration_y), float(m.vibration_z)],
                    "unit": "m/s^2",
                    "clipping": [int(m.clipping_0), int(m.clipping_1), int(m.clipping_2)],
                    "t": m.time_usec * 1e-6,
                }
        elif msgid == MSG_AUTOPILOT_VERSION:
            self._version(self._decode(frame))
        elif msgid == MSG_COMMAND_ACK:
            self._ack(self._decode(frame))

    def _decode(self, frame: bytes) -> Any:
        """A low-rate message (a whole good frame) decoded by pymavlink, or None."""
        try:
            return self._mav.decode(bytearray(frame))
        except Exception:  # pymavlink raises its own MAVError and struct errors
            return None

    # -- samples --------------------------------------------------------------

    def _imu(self, kind: str, row: tuple[float, ...], rows: list[tuple[float, ...]]) -> None:
        """One IMU message of ``kind``: a sample if it is the chosen kind (or held back while
        ``message=auto`` chooses)."""
        if kind == self.kind:
            self._sample(row, rows)
            return
        if self.kind is None:
            t_us = int(row[0])
            if kind == "highres":
                self._choose("highres", rows)
                self._sample(row, rows)
            else:
                held = self._held[kind]
                held.append(row)
                if self._first_imu_us is None:
                    self._first_imu_us = t_us
                if t_us - self._first_imu_us >= CHOOSE_S * 1e6:
                    self._choose(next(k for k in KINDS if self._held[k]), rows)
            return
        self.other_imu += 1

    def _choose(self, kind: str, rows: list[tuple[float, ...]]) -> None:
        self.kind = kind
        held = self._held[kind]
        self._held = {k: [] for k in KINDS}
        for row in held:
            self._sample(row, rows)
        self._describe_kind()
        if kind != "highres":  # the rate was asked for HIGHRES_IMU: ask for this one's
            self._requests = [r for r in self._requests if r.what != "rate"]

    def _describe_kind(self) -> None:
        info = self.device_info
        assert self.kind is not None
        name = KIND_MESSAGES[self.kind]
        if self.kind == "scaled" and self.imu:
            name += str(self.imu + 1)
        info["message"] = name
        info["units"] = dict(KIND_UNITS[self.kind])
        if self.heartbeats:
            info["datasheet"] = DATASHEET_PHYSICAL if self.kind != "raw" else None

    def _sample(self, row: tuple[float, ...], rows: list[tuple[float, ...]]) -> None:
        t_us = int(row[0])
        last = self._t_last_us
        if last is not None:
            dt = t_us - last
            if dt == 0:  # the same sample sent again (a stream faster than the sensor)
                self.counters.duplicates += 1
                return
            if dt < 0:  # a reboot: continue the timeline by the last interval
                self.restarts += 1
                dt = self._dt_us or 1
            else:
                self._dt_us = dt
            self._t_abs_us += dt
        else:
            self._t_abs_us = t_us
        self._t_last_us = t_us
        self._n += 1
        rows.append((self._t_abs_us * 1e-6, *row[1:]))

    def _block(self, rows: list[tuple[float, ...]]) -> SampleBlock:
        if not rows:
            return SampleBlock.empty()
        a = np.array(rows, dtype=np.float64)
        k = a.shape[0]
        self.counters.frames += k
        t_end = self._t_abs_us
        if self._rate_mark is None:
            self._rate_mark = (t_end, self._n)
        elif t_end - self._rate_mark[0] >= RATE_WINDOW_US:  # samples per second of stamps
            t0, n0 = self._rate_mark
            self.device_info["rate_hz"] = round((self._n - n0) * 1e6 / (t_end - t0), 1)
            self._rate_mark = (t_end, self._n)
        temp = a[:, 7]
        assert self.kind is not None
        return SampleBlock(
            t=a[:, 0],
            gyro=a[:, 1:4],
            accel=a[:, 4:7],
            temp=None if np.isnan(temp).any() else temp,
            flags=np.zeros(k, np.uint16),
            seq=np.arange(self._n - k + 1, self._n + 1, dtype=np.int64),
            meta={"units": KIND_UNITS[self.kind]},
        )

    # -- identity and requests -----------------------------------------------------

    def _heartbeat(self, m: Any) -> None:
        if m is None:
            return
        self.heartbeats += 1
        info = self.device_info
        info["autopilot"] = AUTOPILOTS.get(m.autopilot, f"MAV_AUTOPILOT {m.autopilot}")
        try:
            vtype = self.dialect.enums["MAV_TYPE"][m.type].name.removeprefix("MAV_TYPE_")
        except KeyError:
            vtype = str(m.type)
        info["vehicle_type"] = vtype.lower()
        info["sysid"], info["compid"] = self.target_sysid, self.target_compid
        info["protocol"] = "mavlink1" if self._v1 else "mavlink2"
        if info.get("firmware") is None:
            info["firmware"] = info["autopilot"]
        if self.kind is not None:
            self._describe_kind()
        self._out.append(self.hello())
        self._send_requests()

    def _send_requests(self) -> None:
        """(Re)send what is not acknowledged yet; build the requests on first need."""
        wanted: list[tuple[str, int, tuple[float, ...]]] = []
        if self.rate_hz > 0:
            msg = MSG_HIGHRES_IMU
            if self.kind == "scaled":
                msg = SCALED_IDS[self.imu]
            elif self.kind == "raw":
                msg = MSG_RAW_IMU
            wanted.append(("rate", CMD_SET_MESSAGE_INTERVAL, (msg, 1e6 / self.rate_hz)))
            wanted.append(
                ("vibration", CMD_SET_MESSAGE_INTERVAL, (MSG_VIBRATION, 1e6 / VIBRATION_RATE_HZ))
            )
        wanted.append(("identity", CMD_REQUEST_MESSAGE, (MSG_AUTOPILOT_VERSION,)))
        have = {r.what for r in self._requests}
        for what, command, params in wanted:
            if what not in have:
                self._requests.append(_Request(command, params, what))
        for r in self._requests:
            if r.result is None and r.sent < REQUEST_TRIES:
                p = [*r.params, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0][:7]
                self._send(
                    self._mav.command_long_encode(
                        self.target_sysid or 0, self.target_compid or 0, r.command, r.sent, *p
                    )
                )
                r.sent += 1
        self._rate_status()

    def _rate_status(self) -> None:
        for r in self._requests:
            if r.what == "rate":
                result = r.result or ("no answer" if r.sent >= REQUEST_TRIES else "asked")
                self.device_info["rate_request"] = {
                    "message": self._map[int(r.params[0])].msgname,
                    "requested_hz": round(1e6 / r.params[1], 3),
                    "result": result,
                }

    def _ack(self, m: Any) -> None:
        if m is None:
            return
        for r in self._requests:
            if r.command == m.command and r.result is None:
                r.result = RESULTS.get(m.result, f"MAV_RESULT {m.result}")
                if r.result == "in progress":
                    r.result = None
                    continue
                break
        self._rate_status()

    def _version(self, m: Any) -> None:
        if m is None:
            return
        info = self.device_info
        vendor = USB_VENDORS.get(m.vendor_id)
        info["vendor"] = f"0x{m.vendor_id:04x}" + (f" {vendor}" if vendor else "")
        info["product"] = f"0x{m.product_id:04x} (board version {m.board_version})"
        uid2 = bytes(m.uid2)
        info["serial"] = f"{m.uid:016x}" if m.uid else (uid2.hex() if any(uid2) else None)
        git = bytes(m.flight_custom_version).hex()
        name = info.get("autopilot") or "autopilot"
        info["firmware"] = f"{name} {_version_text(m.flight_sw_version)}" + (
            f" ({git})" if any(m.flight_custom_version) else ""
        )
        for r in self._requests:
            if r.what == "identity":
                r.result = r.result or "accepted"

    def _send(self, msg: Any) -> None:
        self._out.append(bytes(msg.pack(self._mav, force_mavlink1=self._v1)))
        self._mav.seq = (self._mav.seq + 1) % 256


# -- transports -----------------------------------------------------------------------------

_URL_KEYS = ("imu", "message", "rate", "sysid")
DEFAULT_BAUD = 115200  #: bit/s (USB CDC ignores it; telemetry radios use 57600)


def _decoder(url: SourceURL, counters: Counters) -> MavlinkDecoder:
    imu = url.get("imu", 0, int)
    rate = url.get("rate", DEFAULT_RATE_HZ, float)
    if not (rate >= 0 and np.isfinite(rate)):
        raise SourceError(f"{url.url}: bad value for 'rate': {rate} (Hz, >= 0)")
    try:
        return MavlinkDecoder(
            counters,
            imu=imu,
            message=url.get("message", "auto"),
            rate_hz=rate,
            sysid=url.get("sysid", None, int),
        )
    except ValueError as exc:
        raise SourceError(f"{url.url}: {exc}") from None


class _MavlinkMixin(ByteSource):
    """What both MAVLink transports add to a byte source: the MAVLink decoder, and the
    requests it makes sent back on the same link."""

    decoder: MavlinkDecoder

    def _make_decoder(self) -> MavlinkDecoder:
        return _decoder(self.url, self.counters)

    def read(self, timeout_s: float = 0.1) -> SampleBlock:
        """Samples of the chosen IMU message; the decoder's requests are sent meanwhile."""
        block = super().read(timeout_s)
        out = self.decoder.take_outgoing()
        if out:
            self._write_bytes(out)
        return block

    def write_command(self, line: str) -> None:
        """``RATE <hz>`` asks for that IMU message rate, ``INFO`` for AUTOPILOT_VERSION;
        ``START`` and ``STOP`` are ignored (the autopilot streams on its own)."""
        words = line.strip().split()
        if words[:1] == ["RATE"] and len(words) == 2:
            self.decoder.request_rate(float(words[1]))
        elif words == ["INFO"]:
            self.decoder.request_identity()
        elif words not in (["START"], ["STOP"]):
            raise ValueError(f"unknown device command {line!r}: expected RATE <hz> or INFO")


@register("mavlink")
class MavlinkSerialSource(_MavlinkMixin, SerialSource):
    """``mavlink:///dev/ttyACM0?baud=115200``: an autopilot on a serial or USB CDC port."""

    url_keys: ClassVar[tuple[str, ...] | None] = ("baud", "exclusive", *_URL_KEYS)

    def __init__(self, url: SourceURL, **options: Any) -> None:
        if url.scheme == "mavlink":
            if "baud" not in url.params and "baud" not in options:
                options = {**options, "baud": DEFAULT_BAUD}
            url = SourceURL(url.url, "serial", url.target, url.params)
        super().__init__(url, **options)
        self.url = SourceURL(url.url, "mavlink", url.target, url.params)


@register("mavlink+udp")
class MavlinkUdpSource(_MavlinkMixin, ByteSource):
    """``mavlink+udp://HOST:PORT``: a MAVLink router's UDP endpoint.

    ``mode=listen`` (default): bind HOST:PORT (empty host: every interface) and answer the
    address the datagrams come from; ``mode=connect``: send to HOST:PORT (our HEARTBEAT
    first, so the router learns where we are) and read its answers. UDP has no connection:
    a silent autopilot is ``no_data``, never a lost device.
    """

    url_keys: ClassVar[tuple[str, ...] | None] = ("mode", *_URL_KEYS)

    def __init__(self, url: SourceURL, **options: Any) -> None:
        super().__init__(url, **options)
        host, sep, port = url.target.rstrip("/").rpartition(":")
        try:
            if not sep:
                raise ValueError
            self.address = (host.strip("[]"), int(port))
        except ValueError:
            raise SourceError(f"{url.url}: expected mavlink+udp://HOST:PORT") from None
        self.mode = url.get("mode", "listen")
        if self.mode not in ("listen", "connect"):
            raise SourceError(f"{url.url}: bad value for 'mode': {self.mode!r} (listen, connect)")
        self._sock: socket.socket | None = None
        self._peer: tuple[Any, ...] | None = None

    def _open_transport(self) -> None:
        host, port = self.address
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        try:
            sock = socket.socket(family, socket.SOCK_DGRAM)
            if self.mode == "listen":
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                sock.bind((host, port))
            else:
                self._peer = (host, port)
        except OSError as exc:
            raise SourceError(f"{self.url.url}: cannot open UDP {host}:{port}: {exc}") from exc
        sock.setblocking(False)
        self._sock = sock
        if self.mode == "connect":  # make ourselves known before the autopilot's heartbeat
            self._write_bytes(self.decoder.hello())

    def _read_bytes(self, timeout_s: float) -> bytes:
        import select

        sock = self._sock
        assert sock is not None
        ready, _, _ = select.select([sock], [], [], max(0.0, timeout_s))
        if not ready:
            return b""
        parts = []
        while True:
            try:
                data, peer = sock.recvfrom(65535)
            except BlockingIOError:
                break
            except OSError as exc:
                raise SourceError(f"{self.url.url}: UDP receive failed: {exc}") from exc
            parts.append(data)
            if self.mode == "listen":
                self._peer = peer
        return b"".join(parts)

    def _write_bytes(self, data: bytes) -> bool:
        if self._sock is None or self._peer is None:
            return False
        try:
            self._sock.sendto(data, self._peer)
        except OSError:  # nobody listening yet: UDP requests are repeated on heartbeats
            return False
        return True

    def _close_transport(self) -> None:
        sock, self._sock = self._sock, None
        if sock is not None:
            sock.close()


__all__ = [
    "MavlinkDecoder",
    "MavlinkSerialSource",
    "MavlinkUdpSource",
    "load_pymavlink",
    "x25_crc",
]

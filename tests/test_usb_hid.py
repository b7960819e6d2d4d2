"""usb:// through the real pyusb core with a backend emulating the board; HID report unpacking.

The pyusb test backend subclasses ``usb.backend.IBackend`` and plays the
board's part (descriptors, string descriptors, a bulk-IN endpoint streaming
wire frames, a bulk-OUT endpoint taking commands), so ``usb.core.find``,
``set_configuration``, interface claiming and ``read`` all run for real.
"""

from __future__ import annotations

import array
import errno
import os
import struct
import time
from types import SimpleNamespace

import numpy as np
import pytest
import usb.backend
import usb.core

from imudiag.drivers import SourceError, open_source
from imudiag.drivers.hid import HID_REPORT_SIZE, pack_reports, unpack_reports
from imudiag.drivers.reconnect import ReconnectingSource
from imudiag.drivers.wire import Decoder, encode_info, encode_samples
from tests.helpers import read_samples

VID, PID = 0x0483, 0x5740
EP_IN, EP_OUT = 0x81, 0x01


def board_bytes(n: int, seq_start: int = 0, seed: int = 0) -> tuple[bytes, np.ndarray]:
    rng = np.random.default_rng(seed)
    raw = rng.integers(20000, 45000, (n, 6))
    return encode_samples(seq_start, 5000 * (seq_start + np.arange(n)), raw), raw


class EmulatedBoardBackend(usb.backend.IBackend):
    """The IMU board on a USB bus: one configuration, one vendor interface, bulk IN/OUT."""

    def __init__(self, serial: str = "0001", packet: int = 64) -> None:
        super().__init__()
        self.serial = serial
        self.packet = packet
        self.pending = bytearray()  # what the board has queued on its bulk-IN endpoint
        self.received = bytearray()  # what the host sent on bulk-OUT
        self.plugged = True
        self.configuration = 0
        self.claimed: set[int] = set()
        self.opened = 0

    # -- the board side -----------------------------------------------------
    def send(self, data: bytes) -> None:
        self.pending += data

    # -- descriptors ----------------------------------------------------------
    def enumerate_devices(self):
        if self.plugged:
            yield "imu-board"

    def get_device_descriptor(self, dev):
        return SimpleNamespace(
            bLength=18, bDescriptorType=1, bcdUSB=0x0200, bDeviceClass=0, bDeviceSubClass=0,
            bDeviceProtocol=0, bMaxPacketSize0=64, idVendor=VID, idProduct=PID,
            bcdDevice=0x0104, iManufacturer=1, iProduct=2, iSerialNumber=3,
            bNumConfigurations=1, address=7, bus=1, port_number=2, port_numbers=(2,), speed=2,
        )  # fmt: skip

    def get_configuration_descriptor(self, dev, config):
        if config != 0:
            raise IndexError(config)
        return SimpleNamespace(
            bLength=9, bDescriptorType=2, wTotalLength=32, bNumInterfaces=1,
            bConfigurationValue=1, iConfiguration=0, bmAttributes=0x80, bMaxPower=50,
            extra_descriptors=[],
        )  # fmt: skip

    def get_interface_descriptor(self, dev, intf, alt, config):
        if intf != 0 or alt != 0:
            raise IndexError((intf, alt))
        return SimpleNamespace(
            bLength=9, bDescriptorType=4, bInterfaceNumber=0, bAlternateSetting=0,
            bNumEndpoints=2, bInterfaceClass=0xFF, bInterfaceSubClass=0, bInterfaceProtocol=0,
            iInterface=0, extra_descriptors=[],
        )  # fmt: skip

    def get_endpoint_descriptor(self, dev, ep, intf, alt, config):
        address = (EP_IN, EP_OUT)[ep]
        return SimpleNamespace(
            bLength=7, bDescriptorType=5, bEndpointAddress=address, bmAttributes=0x02,
            wMaxPacketSize=self.packet, bInterval=0, bRefresh=0, bSynchAddress=0,
            extra_descriptors=[],
        )  # fmt: skip

    def ctrl_transfer(self, handle, bmRequestType, bRequest, wValue, wIndex, data, timeout):
        self._check_plugged()
        if bRequest == 0x06 and wValue >> 8 == 3:  # GET_DESCRIPTOR, string
            index = wValue & 0xFF
            if index == 0:
                desc = bytes([4, 3, 0x09, 0x04])  # LANGID en-US
            else:
                text = {1: "imudiag", 2: "IMU-USB board", 3: self.serial}[index]
                body = text.encode("utf-16-le")
                desc = bytes([2 + len(body), 3]) + body
            n = min(len(desc), len(data))
            data[:n] = array.array("B", desc[:n])
            return n
        raise usb.core.USBError("Pipe error", errno=errno.EPIPE)

    # -- device handle ----------------------------------------------------------
    def _check_plugged(self):
        if not self.plugged:
            raise usb.core.USBError(
                "No such device (it may have been disconnected)", 4, errno.ENODEV
            )

    def open_device(self, dev):
        self._check_plugged()
        self.opened += 1
        return SimpleNamespace(dev=dev)

    def close_device(self, handle):
        pass

    def set_configuration(self, handle, value):
        self._check_plugged()
        self.configuration = value

    def get_configuration(self, handle):
        return self.configuration

    def claim_interface(self, handle, intf):
        self._check_plugged()
        self.claimed.add(intf)

    def release_interface(self, handle, intf):
        self.claimed.discard(intf)
        self._check_plugged()

    def is_kernel_driver_active(self, handle, intf):
        return False

    def bulk_read(self, handle, ep, intf, buff, timeout):
        self._check_plugged()
        assert ep == EP_IN and intf in self.claimed
        if not self.pending:
            time.sleep(min(timeout, 5) / 1000.0)
            raise usb.core.USBTimeoutError("Operation timed out", 7, errno.ETIMEDOUT)
        # a bulk transfer ends at a short packet; the board sends whole 64-byte packets
        n = min(len(buff), len(self.pending))
        buff[:n] = array.array("B", bytes(self.pending[:n]))
        del self.pending[:n]
        return n

    def bulk_write(self, handle, ep, intf, data, timeout):
        self._check_plugged()
        assert ep == EP_OUT
        self.received += bytes(data)
        return len(data)


# -- usb:// -------------------------------------------------------------------------


def test_usb_reads_bulk_in_through_pyusb_core():
    board = EmulatedBoardBackend(serial="0001")
    data, raw = board_bytes(2000, seq_start=100)
    board.send(encode_info(99, 0, {"serial": "0001", "rate_hz": 200}) + data)
    src = open_source(f"usb://{VID:04x}:{PID:04x}?serial=0001", backend=board)
    with src:
        assert board.configuration == 1 and board.claimed == {0}
        out = read_samples(src, 2000, timeout_s=3.0)
        src.write_command("INFO")
        src.write_command("RATE 100")
    np.testing.assert_array_equal(out.gyro, raw[:, :3])
    np.testing.assert_array_equal(out.seq, 100 + np.arange(2000))
    assert src.device_info == {"serial": "0001", "rate_hz": 200}
    assert bytes(board.received) == b"INFO\nRATE 100\n"
    assert board.claimed == set()  # released on close
    assert src.counters.frames == 2000 and src.counters.skipped_bytes == 0


def test_usb_device_selection_errors():
    board = EmulatedBoardBackend(serial="0001")
    with pytest.raises(SourceError, match="no USB device 0483:5740 serial 9999 found"):
        open_source("usb://0483:5740?serial=9999", backend=board).open()
    with pytest.raises(SourceError, match="no USB device 0483:0001"):
        open_source("usb://0483:0001", backend=board).open()
    with pytest.raises(SourceError, match="no bulk-IN endpoint 0x82"):
        open_source("usb://0483:5740?endpoint=0x82", backend=board).open()


@pytest.mark.realtime
def test_usb_unplug_and_replug_with_reconnect():
    board = EmulatedBoardBackend()
    data1, raw1 = board_bytes(300, seq_start=0, seed=1)
    board.send(data1)
    src = ReconnectingSource(
        f"usb://{VID:04x}:{PID:04x}", min_backoff_s=0.01, max_backoff_s=0.05, backend=board
    )
    src.open()
    first = read_samples(src, 300, timeout_s=3.0)
    np.testing.assert_array_equal(first.accel, raw1[:, 3:])
    board.plugged = False  # unplug
    src.read(0.02)
    assert src.state == "reconnecting"
    assert "gone" in src.last_error
    src.read(0.05)
    assert src.state == "reconnecting"
    board.plugged = True  # replug; the board carries on at seq 310
    data2, raw2 = board_bytes(200, seq_start=310, seed=2)
    board.send(data2)
    second = read_samples(src, 200, timeout_s=3.0)
    assert src.state == "connected" and src.reconnects == 1
    np.testing.assert_array_equal(second.accel, raw2[:, 3:])
    assert src.counters.frames == 500 and src.counters.lost == 10
    src.close()


# -- HID ------------------------------------------------------------------------------


def test_hid_report_unpacking_many_reports():
    data, raw = board_bytes(500, seed=3)
    frames = [data[i : i + 40] for i in range(0, len(data), 40)]
    reports = bytearray(pack_reports(frames))
    assert len(reports) == 500 * HID_REPORT_SIZE
    # idle reports (0 frames), a wrong report ID and a bad count are interleaved
    idle = bytes([0x01, 0]) + bytes(62)
    wrong_id = bytes([0x02, 1]) + frames[0] + bytes(22)
    bad_count = bytes([0x01, 3]) + frames[0] + bytes(22)
    stream = (
        idle + bytes(reports[: 64 * 250]) + wrong_id + idle + bad_count + bytes(reports[64 * 250 :])
    )
    payload, bad = unpack_reports(stream)
    assert payload == data
    assert bad == 2
    # as a (K, 64) array too
    arr = np.frombuffer(bytes(reports), np.uint8).reshape(-1, 64)
    assert unpack_reports(arr) == (data, 0)
    out = Decoder().feed(payload)
    np.testing.assert_array_equal(out.gyro, raw[:, :3])


def test_hid_report_with_corrupt_length_is_resynchronised():
    data, raw = board_bytes(3, seed=4)
    frames = [data[i : i + 40] for i in range(0, len(data), 40)]
    reports = bytearray(pack_reports(frames))
    reports[64 + 5] = 0xF0  # frame 1's length byte: 62 bytes taken, CRC fails
    payload, bad = unpack_reports(bytes(reports))
    assert bad == 0 and len(payload) == 40 + 62 + 40
    dec = Decoder()
    out = dec.feed(payload)
    assert len(out) == 2 and dec.counters.lost == 1
    with pytest.raises(ValueError, match="multiple of 64"):
        unpack_reports(b"\x01" * 65)


def test_hid_open_failure_names_the_device():
    pytest.importorskip("hid")
    with pytest.raises(SourceError, match=r"cannot open HID device 0483:5740 serial X1"):
        open_source("hid://0483:5740?serial=X1").open()


# -- a real kernel HID device through /dev/uhid, where the kernel offers it -------------

UHID_DESTROY, UHID_CREATE2, UHID_INPUT2 = 1, 11, 12
UHID_EVENT_SIZE = 4 + 4372  # type + the largest request (create2)
REPORT_DESCRIPTOR = bytes.fromhex(
    "0600ff"  # usage page (vendor 0xFF00)
    "0901a101"  # usage 1, collection (application)
    "8501"  # report ID 1
    "150026ff00750895"  # logical 0..255, 8-bit fields, count:
    "3f"  # 63 bytes after the ID
    "09028102"  # usage 2, input (data, var, abs)
    "c0"  # end collection
)


@pytest.mark.realtime
@pytest.mark.skipif(
    not os.access("/dev/uhid", os.W_OK),
    reason="/dev/uhid is not available here (no uhid kernel module or no permission): "
    "the real virtual-HID-device test cannot run; report unpacking is tested above",
)
def test_hid_source_reads_a_uhid_virtual_device():  # pragma: no cover - needs /dev/uhid
    fd = os.open("/dev/uhid", os.O_RDWR)
    try:
        create = struct.pack(
            "<I128s64s64sHHIIII4096s",
            UHID_CREATE2, b"imudiag test board", b"", b"U0001", len(REPORT_DESCRIPTOR),
            0x03, VID, PID, 0x0104, 0, REPORT_DESCRIPTOR,
        )  # fmt: skip
        os.write(fd, create.ljust(UHID_EVENT_SIZE, b"\0"))
        time.sleep(0.5)  # the kernel binds hid-generic and creates /dev/hidrawN
        data, raw = board_bytes(100, seed=5)
        src = open_source(f"hid://{VID:04x}:{PID:04x}")
        with src:
            time.sleep(0.2)
            for i in range(0, len(data), 40):
                report = pack_reports([data[i : i + 40]])
                os.write(fd, struct.pack("<IH4096s", UHID_INPUT2, 64, report).ljust(
                    UHID_EVENT_SIZE, b"\0"))  # fmt: skip
            out = read_samples(src, 100, timeout_s=3.0)
        np.testing.assert_array_equal(out.gyro, raw[:, :3])
    finally:
        os.write(fd, struct.pack("<I", UHID_DESTROY).ljust(UHID_EVENT_SIZE, b"\0"))
        os.close(fd)

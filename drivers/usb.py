"""usb://VID:PID?serial=S&interface=0&endpoint=0x81 — the raw USB bulk-IN endpoint (pyusb).

Finds the device with ``usb.core.find``, sets its configuration, detaches a
kernel driver where one is bound, claims the interface and reads the wire
byte stream from its bulk-IN endpoint (the first one, or ``endpoint``). Host
commands go to the interface's bulk-OUT endpoint when there is one.

Options: ``backend`` (a pyusb backend object, e.g. ``usb.backend.libusb1.get_backend()``
or a test backend emulating the board), ``serial``, ``interface`` (number,
default 0), ``endpoint`` (bulk-IN address). An unplugged device raises SourceError.
"""

from __future__ import annotations

import errno
from typing import Any

from .base import SourceError, SourceURL, register
from .bytesource import ByteSource, parse_vid_pid

READ_SIZE = 16384  #: bytes asked for per bulk transfer
MAX_TRANSFERS_PER_READ = 64
WRITE_TIMEOUT_MS = 200


def _int_auto(text: str) -> int:
    return int(text, 0)


@register("usb")
class UsbSource(ByteSource):
    """Wire frames from a USB bulk-IN endpoint through pyusb (``pip install pyusb``)."""

    url_keys = ("serial", "interface", "endpoint")

    def __init__(self, url: SourceURL, **options: Any) -> None:
        super().__init__(url, **options)
        self.vid, self.pid = parse_vid_pid(url)
        self.serial: str | None = options.get("serial", url.get("serial"))
        self.interface = int(options.get("interface", url.get("interface", 0, _int_auto)))
        ep = options.get("endpoint", url.get("endpoint", None, _int_auto))
        self.endpoint: int | None = None if ep is None else int(ep)
        self.backend = options.get("backend")
        self._dev: Any = None
        self._ep_in: Any = None
        self._ep_out: Any = None

    def _describe(self) -> str:
        serial = f" serial {self.serial}" if self.serial else ""
        return f"USB device {self.vid:04x}:{self.pid:04x}{serial}"

    def _open_transport(self) -> None:
        try:
            import usb.core
            import usb.util
        except ImportError as e:
            raise SourceError(f"{self.url.url}: pyusb is not installed ({e})") from e

        def serial_matches(dev: Any) -> bool:
            if self.serial is None:
                return True
            try:
                return dev.serial_number == self.serial
            except (ValueError, usb.core.USBError):
                return False

        try:
            dev = usb.core.find(
                idVendor=self.vid,
                idProduct=self.pid,
                backend=self.backend,
                custom_match=serial_matches,
            )
        except usb.core.NoBackendError as e:
            raise SourceError(f"{self.url.url}: no libusb backend available ({e})") from e
        except usb.core.USBError as e:
            raise SourceError(f"{self.url.url}: cannot enumerate USB devices: {e}") from e
        if dev is None:
            raise SourceError(f"{self.url.url}: no {self._describe()} found")
        try:
            self._setup(dev)
        except usb.core.USBError as e:
            usb.util.dispose_resources(dev)
            raise SourceError(f"{self.url.url}: cannot open {self._describe()}: {e}") from e
        self._dev = dev

    def _setup(self, dev: Any) -> None:
        import usb.core
        import usb.util

        try:
            if dev.is_kernel_driver_active(self.interface):
                dev.detach_kernel_driver(self.interface)
        except (NotImplementedError, usb.core.USBError):
            pass  # not supported by the backend or OS, or nothing bound
        try:
            dev.set_configuration()
        except usb.core.USBError as e:
            if e.errno != errno.EBUSY:  # already configured and in use by us is fine
                raise
        cfg = dev.get_active_configuration()
        intf = usb.util.find_descriptor(cfg, bInterfaceNumber=self.interface)
        if intf is None:
            raise SourceError(
                f"{self.url.url}: {self._describe()} has no interface {self.interface}"
            )

        def bulk(direction: int) -> Any:
            def match(e: Any) -> bool:
                return (
                    usb.util.endpoint_direction(e.bEndpointAddress) == direction
                    and usb.util.endpoint_type(e.bmAttributes) == usb.util.ENDPOINT_TYPE_BULK
                    and (
                        direction != usb.util.ENDPOINT_IN
                        or self.endpoint is None
                        or e.bEndpointAddress == self.endpoint
                    )
                )

            return usb.util.find_descriptor(intf, custom_match=match)

        self._ep_in = bulk(usb.util.ENDPOINT_IN)
        if self._ep_in is None:
            which = f"endpoint 0x{self.endpoint:02x}" if self.endpoint is not None else "endpoint"
            raise SourceError(
                f"{self.url.url}: interface {self.interface} of {self._describe()} "
                f"has no bulk-IN {which}"
            )
        self._ep_out = bulk(usb.util.ENDPOINT_OUT)
        usb.util.claim_interface(dev, intf)

    def _read_bytes(self, timeout_s: float) -> bytes:
        import usb.core

        dev, addr = self._dev, self._ep_in.bEndpointAddress
        chunks: list[bytes] = []
        timeout_ms = max(1, int(timeout_s * 1000))
        try:
            for _ in range(MAX_TRANSFERS_PER_READ):
                try:
                    data = dev.read(addr, READ_SIZE, timeout_ms)
                except usb.core.USBTimeoutError:
                    break
                if not len(data):
                    break
                chunks.append(data.tobytes())
                timeout_ms = 1  # collect what is already queued, then return
        except usb.core.USBError as e:
            raise SourceError(f"{self.url.url}: {self._describe()} gone: {e}") from e
        return b"".join(chunks)

    def _write_bytes(self, data: bytes) -> bool:
        import usb.core

        if self._ep_out is None:
            return False
        try:
            self._dev.write(self._ep_out.bEndpointAddress, data, WRITE_TIMEOUT_MS)
        except usb.core.USBError as e:
            raise SourceError(f"{self.url.url}: write to {self._describe()} failed: {e}") from e
        return True

    def _close_transport(self) -> None:
        import usb.core
        import usb.util

        dev, self._dev = self._dev, None
        if dev is None:
            return
        try:
            usb.util.release_interface(dev, self.interface)
        except usb.core.USBError:
            pass  # unplugged: nothing to release
        usb.util.dispose_resources(dev)

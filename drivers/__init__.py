"""Driver layer: the wire codec and the transports behind one URL-chosen interface.

Installed as ``imudiag.drivers``. ``open_source(url)`` picks the transport by
URL scheme from a registry, like pyserial's ``serial_for_url`` and
python-can's interface registry::

    serial:///dev/ttyACM0?baud=921600   CDC-ACM serial port (pyserial; also loop://, socket://)
    hid://VID:PID                       USB HID input reports (hidapi)
    usb://VID:PID                       raw USB bulk-IN endpoint (pyusb)
    mavlink:///dev/ttyACM0?imu=0        a PX4/ArduPilot autopilot's IMU messages (pymavlink)
    mavlink+udp://:14550                the same through a MAVLink router's UDP endpoint
    replay://PATH?speed=1               a recorded log (.csv, .csv.gz, .npz, .bin)
    sim://SCENARIO?seed=N               the simulated board

``replay://`` and ``sim://`` live above this layer (:mod:`imudiag.sources`) and are found
through the ``imudiag.sources`` entry points; the test and bench harness of pty pairs is
:mod:`imudiag.bench.pty`, outside the production driver package.
"""

from .base import (
    Counters,
    EndOfStream,
    Source,
    SourceError,
    open_source,
    parse_url,
    register,
    registered_schemes,
)

__all__ = [
    "Counters",
    "EndOfStream",
    "Source",
    "SourceError",
    "open_source",
    "parse_url",
    "register",
    "registered_schemes",
]

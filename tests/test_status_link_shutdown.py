"""Issue 12 item 3: a stuck socket:// status link (a receiver that never reads) closes
without AttributeError (pyserial's socket handler has no cancel_write)."""

from __future__ import annotations

import socket
import threading
import time

import pytest

from imudiag.service.nmea import SerialStatusSink

pytestmark = pytest.mark.realtime  # tests/conftest.py: the two tiers


def test_stuck_socket_status_link_closes_cleanly():
    server = socket.socket()
    server.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    server.bind(("127.0.0.1", 0))
    server.listen(1)
    port = server.getsockname()[1]
    accepted: list[socket.socket] = []
    threading.Thread(target=lambda: accepted.append(server.accept()[0]), daemon=True).start()
    sink = SerialStatusSink(
        f"socket://127.0.0.1:{port}", rate_hz=1e6, queue_size=4, write_timeout_s=30.0
    )
    sock = sink.port._socket  # type: ignore[union-attr]
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4096)
    status = {
        "t": 1.0,
        "state": "fault",
        "faults": [{"triad": "accel", "cause": "f0"}] * 20,
        "counters": {},
        "f0": {},
    }
    # the receiver never reads: fill the kernel buffers until the writer is stuck (nothing
    # more written while the queue stays full)
    deadline = time.monotonic() + 60.0
    i, last_written, still = 0, -1, 0
    while still < 200:
        assert time.monotonic() < deadline, "the link never filled up"
        i += 1
        sink.publish(dict(status, t=float(i)), now_s=float(i))
        if sink.written == last_written and sink.pending >= 4:
            still += 1
            time.sleep(0.005)
        else:
            last_written, still = sink.written, 0
    errors: list[BaseException] = []
    t = threading.Thread(target=lambda: _close(sink, errors))
    t.start()
    t.join(30.0)
    assert not t.is_alive() and errors == []
    server.close()
    for c in accepted:
        c.close()


def _close(sink: SerialStatusSink, errors: list[BaseException]) -> None:
    try:
        sink.close(timeout_s=0.2)
    except BaseException as exc:  # noqa: BLE001 - the test records anything
        errors.append(exc)

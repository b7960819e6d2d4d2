"""A real pty pair standing in for the board's CDC-ACM port, read by pyserial and serial://."""

from __future__ import annotations

import os
import time

import numpy as np
import pytest
import serial

from imudiag.bench.pty import BoardWriter, PtyPair, chunked
from imudiag.drivers import SourceError, open_source
from imudiag.drivers.wire import encode_samples
from tests.helpers import read_samples

pytestmark = pytest.mark.realtime  # tests/conftest.py: the two tiers


def frames(n: int, seq_start: int = 0, seed: int = 0) -> tuple[bytes, np.ndarray]:
    rng = np.random.default_rng(seed)
    raw = rng.integers(20000, 45000, (n, 6))
    return encode_samples(seq_start, 5000 * (seq_start + np.arange(n)), raw), raw


def test_pyserial_reads_pty_fed_in_real_time():
    data, _ = frames(100)
    with PtyPair() as pair:
        port = serial.Serial(pair.slave_path, baudrate=921600, timeout=0.05)
        writer = BoardWriter(pair, chunked(data, 40), rate_hz=200.0)  # one frame per 5 ms
        t0 = time.monotonic()
        writer.start()
        got = bytearray()
        arrivals = []  # (wall s since the start, bytes received so far)
        while len(got) < len(data) and time.monotonic() - t0 < 30:
            got += port.read(4096)
            arrivals.append((time.monotonic() - t0, len(got)))
        writer.join(30)
        port.close()
    assert bytes(got) == data  # binary-clean: raw mode, no echo, no CR/LF mangling
    assert writer.bytes_written == len(data) and writer.chunks_written == 100
    # paced, not dumped at once: no frame arrives before its slot (frame k is written 5 ms
    # after frame k - 1), a bound a loaded machine cannot break (it only makes frames later)
    for wall_s, n in arrivals:
        assert n // 40 - 1 <= wall_s / 0.005 + 1, (wall_s, n)


def test_serial_url_decodes_pty_stream_and_sends_commands():
    data, raw = frames(400, seq_start=7, seed=1)
    with PtyPair() as pair:
        src = open_source(f"serial://{pair.slave_path}?baud=921600")
        with src:
            writer = BoardWriter(pair, chunked(data, 40 * 8), rate_hz=400.0)
            writer.start()
            src.write_command("START")
            src.write_command("RATE 200")
            out = read_samples(src, 400)
            # the board sees the commands (this one ignores them and keeps streaming)
            assert pair.read_commands(timeout_s=1.0) == ["START", "RATE 200"]
            with pytest.raises(ValueError, match="unknown device command"):
                src.write_command("REBOOT")
        writer.stop()
    np.testing.assert_array_equal(out.gyro, raw[:, :3])
    np.testing.assert_array_equal(out.seq, 7 + np.arange(400))
    assert src.counters.frames == 400 and src.counters.skipped_bytes == 0


def test_closing_master_is_an_unplug():
    data, _ = frames(2000)
    pair = PtyPair()
    try:
        port = serial.Serial(pair.slave_path, timeout=0.05)
        src = open_source(f"serial://{pair.slave_path}")
        src.open()
        writer = BoardWriter(pair, chunked(data, 40 * 4), rate_hz=100.0)
        writer.start()
        assert len(read_samples(src, 20)) >= 20
        path = pair.slave_path
        pair.close_master()  # stops the writer, then hangs up
        assert not writer.is_alive()
        assert not os.path.exists(path)
        with pytest.raises(serial.SerialException):
            for _ in range(20):
                port.read(100)
        with pytest.raises(SourceError, match="device gone"):
            for _ in range(20):
                src.read(0.05)
        assert not src.is_open  # the source closed itself
        port.close()
        with pytest.raises(SourceError, match="cannot open"):
            open_source(f"serial://{path}").open()
    finally:
        pair.close()


def test_replug_through_a_symlink(tmp_path):
    link = tmp_path / "ttyIMU0"
    first = PtyPair(link=link)
    assert os.path.realpath(link) == first.slave_path
    first.close()
    second = PtyPair(link=link)  # "replug": same name, new pty
    try:
        assert os.path.realpath(link) == second.slave_path
        data, raw = frames(50, seed=2)
        with open_source(f"serial://{link}") as src:
            second.write(data)
            out = read_samples(src, 50)
        np.testing.assert_array_equal(out.accel, raw[:, 3:])
    finally:
        second.close()


def test_writer_as_fast_as_possible_on_raw_fd():
    data, _ = frames(3000, seed=3)
    with PtyPair() as pair:
        port = serial.Serial(pair.slave_path, timeout=0.05)
        writer = BoardWriter(pair.master_fd, chunked(data, 4096), rate_hz=None)
        writer.start()
        got = bytearray()
        t0 = time.monotonic()
        while len(got) < len(data) and time.monotonic() - t0 < 5:
            got += port.read(65536)
        writer.join(2)
        port.close()
    assert bytes(got) == data

"""Byte transports end to end: pyserial loop:// and socket://, replay of logs, reconnecting."""

from __future__ import annotations

import socket
import threading
import time

import numpy as np
import pytest

from imudiag.bench.pty import BoardWriter, PtyPair, chunked
from imudiag.drivers import EndOfStream, SourceError, open_source, registered_schemes
from imudiag.drivers.reconnect import ReconnectingSource
from imudiag.drivers.wire import encode_info, encode_samples
from imudiag.samples import SampleBlock
from tests.helpers import read_samples

INFO = {"model": "ADXRS300/ADXL202", "serial": "0042", "fw": "1.4", "rate_hz": 200}


def board_bytes(n: int, seq_start: int = 0, seed: int = 0) -> tuple[bytes, np.ndarray]:
    rng = np.random.default_rng(seed)
    raw = rng.integers(20000, 45000, (n, 6))
    t = 5000 * (seq_start + np.arange(n))
    return encode_samples(seq_start, t, raw, np.full(n, 30.25)), raw


def test_schemes_registered():
    assert {"serial", "loop", "socket", "hid", "usb", "replay"} <= set(registered_schemes())
    with pytest.raises(SourceError, match="bad device id"):
        open_source("usb://zz:12")


# -- pyserial URL handlers ---------------------------------------------------------


def test_loop_round_trip_and_ignored_commands():
    data, raw = board_bytes(500, seq_start=3)
    with open_source("loop://") as src:
        blocks = []
        written = 0
        for piece in chunked(data, 4000):  # pyserial's loop buffer holds 4096 bytes
            src.write_bytes(piece)
            written += len(piece)
            # drained before the next write (a full loop buffer blocks the write for good):
            # pyserial's loop read stops at its timeout on the wall clock, so on a loaded
            # machine one read may return part of the piece; read until every byte is in
            while src.counters.bytes < written:
                blocks.append(src.read(0.05))
        out = SampleBlock.concat(blocks)
        np.testing.assert_array_equal(out.gyro, raw[:, :3])
        np.testing.assert_array_equal(out.accel, raw[:, 3:])
        np.testing.assert_allclose(out.temp, 30.25)
        # a loopback is a board that ignores commands: they come back as garbage
        src.write_command("INFO")
        src.write_bytes(data[-40:])  # the last frame again
        more, _ = board_bytes(10, seq_start=503, seed=9)
        src.write_bytes(more)
        out2 = read_samples(src, 10)
    assert len(out2) == 10 and out2.seq[0] == 503
    c = src.counters
    assert c.skipped_bytes == len(b"INFO\n")
    assert c.duplicates == 1
    assert (c.frames, c.lost, c.crc_errors) == (510, 0, 0)


@pytest.mark.realtime
def test_socket_stream_and_disconnect():
    data, raw = board_bytes(1000, seed=1)
    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]
    opened, read_all = threading.Event(), threading.Event()

    def serve():
        conn, _ = server.accept()
        # pyserial's open() discards whatever arrived before it finished: send once it has
        assert opened.wait(10), "the client never finished opening"
        with conn:
            conn.sendall(encode_info(65535, 0, INFO))  # seq wraps to the first sample's 0
            for piece in chunked(data, 777):
                conn.sendall(piece)
            read_all.wait(10)
        # closing the connection = the bench server going away

    th = threading.Thread(target=serve, daemon=True)
    th.start()
    src = open_source(f"socket://127.0.0.1:{port}")
    src.open()
    opened.set()
    try:
        out = read_samples(src, 1000)
        read_all.set()
        assert len(out) == 1000
        assert src.device_info == INFO
        np.testing.assert_array_equal(out.gyro, raw[:, :3])
        with pytest.raises(SourceError):
            for _ in range(100):
                src.read(0.05)
    finally:
        read_all.set()
        src.close()
        server.close()
        th.join(2)


def test_serial_open_errors_name_the_device(tmp_path):
    missing = tmp_path / "ttyNOPE"
    with pytest.raises(SourceError, match="ttyNOPE"):
        open_source(f"serial://{missing}").open()
    with pytest.raises(SourceError, match="no device path"):
        open_source("serial://")
    with pytest.raises(SourceError, match="baud"):
        open_source("serial:///dev/null?baud=fast")


# -- replay --------------------------------------------------------------------


def write_capture(path, n: int = 1200) -> np.ndarray:
    data, raw = board_bytes(n, seq_start=65000, seed=2)
    with open(path, "wb") as fh:
        fh.write(b"\x00\x01garbage")
        fh.write(encode_info(64999, 0, INFO))
        fh.write(data[: 40 * (n // 2)])
        fh.write(data[40 * (n // 2 + 1) :])  # one frame lost
    return np.delete(raw, n // 2, axis=0)


def test_replay_bin_as_fast_as_possible(tmp_path):
    path = tmp_path / "capture.bin"
    raw = write_capture(path)
    src = open_source(f"replay://{path}?speed=0&block_size=100")
    blocks = []
    with src:
        with pytest.raises(EndOfStream):
            for _ in range(1000):
                blocks.append(src.read())
    out = SampleBlock.concat(blocks)
    np.testing.assert_array_equal(out.gyro, raw[:, :3])
    assert src.device_info == INFO
    c = src.counters
    assert (c.frames, c.lost, c.skipped_bytes, c.crc_errors) == (1199, 1, 9, 0)
    assert np.all(np.diff(out.t) > 0) and out.seq[0] == 65000


@pytest.mark.realtime
def test_replay_paced_by_sample_time(tmp_path):
    path = tmp_path / "capture.bin"
    write_capture(path, n=400)  # 2 s of samples at 200 Hz
    src = open_source(f"replay://{path}?speed=8")
    sizes = []
    ahead = []  # sample time delivered beyond what 8x the elapsed wall time allows, s
    first_t = None
    t0 = time.monotonic()
    with src:
        with pytest.raises(EndOfStream):
            while True:
                block = src.read(0.02)
                sizes.append(len(block))
                if len(block):
                    first_t = float(block.t[0]) if first_t is None else first_t
                    span = float(block.t[-1]) - first_t
                    ahead.append(span - 8.0 * (time.monotonic() - t0))
    assert sum(sizes) == 399
    # paced by sample time: never ahead of 8x the wall time since the first read;
    # a loaded machine only delivers later, so this cannot fail for being slow
    assert max(ahead) <= 0.005, max(ahead)  # (one sample period of slack)
    assert sum(1 for s in sizes if s) >= 5  # delivered progressively, not in one go


def test_replay_csv_and_npz_via_logs(tmp_path):
    logs = pytest.importorskip("imudiag.logs")
    rng = np.random.default_rng(4)
    n = 700
    block = SampleBlock(
        t=0.005 * np.arange(n),
        gyro=rng.normal(32768, 50, (n, 3)),
        accel=rng.normal(32768, 50, (n, 3)),
        temp=np.full(n, 25.5),
    )
    for name in ("log.csv", "log.csv.gz", "log.npz"):
        path = tmp_path / name
        logs.write_log(path, block, meta={"device": "bench"})
        src = open_source(f"replay://{path}", speed=0, block_size=256)
        blocks = []
        with src:
            assert src.device_info.get("device") == "bench"
            with pytest.raises(EndOfStream):
                for _ in range(100):
                    blocks.append(src.read())
        out = SampleBlock.concat(blocks)
        np.testing.assert_allclose(out.gyro, block.gyro)
        np.testing.assert_allclose(out.t, block.t)
        assert src.counters.frames == n


def test_replay_errors(tmp_path):
    with pytest.raises(SourceError, match="no such file"):
        open_source(f"replay://{tmp_path}/missing.bin").open()
    with pytest.raises(SourceError, match="speed"):
        open_source(f"replay://{tmp_path}/x.bin?speed=-1")


# -- reconnecting -------------------------------------------------------------


@pytest.mark.realtime
def test_reconnect_after_unplug_and_replug(tmp_path):
    link = tmp_path / "ttyIMU"
    first = PtyPair(link=link)
    data1, _ = board_bytes(3000, seq_start=0, seed=5)
    w1 = BoardWriter(first, chunked(data1, 40 * 5), rate_hz=200.0)  # 1000 samples/s
    src = ReconnectingSource(f"serial://{link}", min_backoff_s=0.02, max_backoff_s=0.1)
    second = None
    try:
        src.open()
        assert src.state == "connected"
        w1.start()
        before = read_samples(src, 100)
        assert len(before) >= 100
        first.close_master()  # unplug mid-stream
        states = {src.state}
        for _ in range(40):
            src.read(0.02)
            states.add(src.state)
            if src.state == "reconnecting":
                break
        assert src.state == "reconnecting"
        assert "gone" in (src.last_error or "")
        src.read(0.1)  # retries fail while nothing is plugged in
        assert src.state == "reconnecting" and src.attempts >= 1
        # replug: a new pty under the same name, the board carrying on
        frames_before = src.counters.frames
        second = PtyPair(link=link)
        for _ in range(50):
            if src.state == "connected":
                break
            src.read(0.02)
        assert src.state == "connected"
        assert src.reconnects == 1
        # (the board starts after the port is open: pyserial's open flushes the input)
        data2, raw2 = board_bytes(300, seq_start=5000, seed=6)
        w2 = BoardWriter(second, chunked(data2, 40 * 5), rate_hz=200.0)
        w2.start()
        after = read_samples(src, 300)
        assert len(after) == 300
        np.testing.assert_array_equal(after.gyro[-len(raw2) :], raw2[-len(after) :, :3])
        # counters survived: everything before plus after, and the gap in seq is lost
        assert src.counters.frames == frames_before + len(after)
        assert src.counters.lost == 5000 - frames_before  # seq 0 .. frames_before-1 arrived
    finally:
        src.close()
        first.close()
        if second is not None:
            second.close()


@pytest.mark.realtime
def test_reconnect_starts_before_device_and_backs_off(tmp_path):
    link = tmp_path / "ttyLATE"
    src = ReconnectingSource(f"serial://{link}", min_backoff_s=0.01, max_backoff_s=0.04)
    src.open()  # no device yet: no exception
    assert src.state == "reconnecting" and src.attempts == 1
    backoffs = []
    while src.attempts < 5:
        src.read(0.01)
        backoffs.append(src.backoff_s)
    assert backoffs[-1] == pytest.approx(0.04)
    assert 0.02 in backoffs and set(backoffs) <= {0.01, 0.02, 0.04}  # doubled, capped
    with PtyPair(link=link) as pair:
        for _ in range(50):
            if src.state == "connected":
                break
            src.read(0.02)
        assert src.state == "connected" and src.reconnects == 0  # a first connect
        data, raw = board_bytes(50, seed=7)
        pair.write(data)
        out = read_samples(src, 50, timeout_s=3.0)
        np.testing.assert_array_equal(out.accel, raw[:, 3:])
    src.close()
    with pytest.raises(ValueError, match="back-off"):
        ReconnectingSource("loop://", min_backoff_s=1.0, max_backoff_s=0.5)

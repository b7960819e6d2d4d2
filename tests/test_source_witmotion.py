"""``witmotion://``: WitMotion WT901 frames over a real pty, written by this test's own
encoder from the WitMotion protocol document (11-byte frames 0x55, type, 4 x int16 LE,
sum checksum; 0x50 time, 0x51 acceleration v/32768 x 16 g, 0x52 rate v/32768 x 2000 deg/s).
"""

from __future__ import annotations

import datetime as dt
import struct

import numpy as np
import pytest

from imudiag.bench.pty import BoardWriter, PtyPair, chunked
from imudiag.certificate import datasheet_path, load
from imudiag.drivers.base import open_source
from imudiag.drivers.reconnect import ReconnectingSource
from imudiag.samples import FLAG_ACCEL_SATURATED, SampleBlock
from tests.device_sessions import DaemonThread, judge_session, session_samples
from tests.helpers import read_samples, read_until_state

#: the real-time tier (tests/conftest.py): ptys and a daemon thread against a fake WitMotion
pytestmark = pytest.mark.realtime

START = dt.datetime(2026, 11, 28, 12, 0, 0)


def frame(ftype: int, payload: bytes) -> bytes:
    """One frame: header, type, 8 payload bytes, low byte of the sum of the first ten."""
    assert len(payload) == 8
    body = bytes([0x55, ftype]) + payload
    return body + bytes([sum(body) & 0xFF])


def time_frame(t_s: float) -> bytes:
    when = START + dt.timedelta(milliseconds=round(t_s * 1000))
    return frame(
        0x50,
        struct.pack(
            "<6BH",
            when.year - 2000,
            when.month,
            when.day,
            when.hour,
            when.minute,
            when.second,
            when.microsecond // 1000,
        ),
    )


def counts(values: np.ndarray, full_scale: float) -> np.ndarray:
    return np.clip(np.rint(values / full_scale * 32768.0), -32768, 32767).astype(int)


def encode(block: SampleBlock, with_time: bool = True, temp_c: float = 25.0) -> list[bytes]:
    """The frames of each sample (time, acceleration, rate), one bytes object per sample."""
    acc = counts(block.accel, 16.0)
    gyr = counts(block.gyro, 2000.0)
    temp = int(round(temp_c * 100))
    out = []
    for i in range(len(block)):
        a = frame(0x51, struct.pack("<4h", *acc[i], temp))
        g = frame(0x52, struct.pack("<4h", *gyr[i], 3300))
        out.append((time_frame(float(block.t[i])) if with_time else b"") + a + g)
    return out


def still(n: int, t0: float = 0.0, rate: float = 200.0) -> SampleBlock:
    """n samples at rest, level: gravity on +z, small distinct rates."""
    t = t0 + np.arange(n) / rate
    acc = np.tile([0.01, -0.02, 1.0], (n, 1))
    gyr = np.tile([0.5, -0.25, 0.125], (n, 1))
    return SampleBlock(t=t, gyro=gyr, accel=acc)


def test_session_reaches_ok_and_names_the_bias_within_the_native_time():
    path = datasheet_path("witmotion-wt901")
    block = session_samples(load(path))
    frames = encode(block)
    with PtyPair() as pair, DaemonThread(f"witmotion://{pair.slave_path}", str(path)) as d:
        d.wait_connected()
        writer = BoardWriter(pair, (b"".join(c) for c in chunked_list(frames, 50)))
        writer.start()
        t_end = float(block.t[-1])
        d.wait(lambda s: s["t"] is not None and s["t"] >= t_end - 1e-6, timeout_s=120)
        writer.stop()
        last = d.sink.lines[-1]
    assert last["counters"]["crc_errors"] == 0 and last["counters"]["lost"] == 0
    assert last["counters"]["frames"] == len(block)
    judge_session(d.sink.lines)


def chunked_list(items: list[bytes], size: int) -> list[list[bytes]]:
    return [items[i : i + size] for i in range(0, len(items), size)]


def test_values_units_time_and_identity():
    block = still(40)
    block.accel[5] = [0.0, 0.0, 16.0]  # beyond full scale: clipped to 32767, flagged
    with PtyPair() as pair:
        with open_source(f"witmotion://{pair.slave_path}?rate=200") as src:
            pair.write(b"".join(encode(block)))
            got = read_samples(src, 40)
            info = src.device_info
    assert len(got) == 40
    assert np.allclose(got.t, np.arange(40) / 200.0, atol=1e-9)  # from the time frames
    q_a, q_g = 16.0 / 32768, 2000.0 / 32768
    assert np.allclose(got.accel[0], [0.01, -0.02, 1.0], atol=q_a / 2)
    assert np.allclose(got.gyro[0], [0.5, -0.25, 0.125], atol=q_g / 2)
    assert np.allclose(got.temp, 25.0)
    assert got.flags is not None and got.flags[5] & FLAG_ACCEL_SATURATED
    assert not np.any(np.delete(got.flags, 5) & FLAG_ACCEL_SATURATED)
    assert got.meta["units"] == {"gyro": "deg/s", "accel": "g"}
    assert info["vendor"] == "WitMotion" and info["product"] == "WT901"
    assert info["datasheet"] == "witmotion-wt901" and datasheet_path(info["datasheet"])
    assert {"serial", "firmware"} <= set(info)


def test_without_time_frames_the_rate_is_the_clock():
    with PtyPair() as pair:
        with open_source(f"witmotion://{pair.slave_path}?rate=100") as src:
            pair.write(b"".join(encode(still(30, rate=100), with_time=False)))
            got = read_samples(src, 30)
    assert len(got) == 30 and np.allclose(got.t, np.arange(30) / 100.0)


def test_garbage_and_checksum_errors_are_counted_and_skipped():
    rng = np.random.default_rng(7)
    block = still(60)
    frames = encode(block)
    garbage = rng.integers(0, 255, size=500).astype(np.uint8)
    garbage[garbage >= 0x55] += 1  # no header byte: exactly 500 skipped bytes
    broken = []
    for i in (20, 21, 40):  # the acceleration frame of three samples gets a bad checksum
        f = bytearray(frames[i])
        f[11 + 10] ^= 0x01  # after the 11-byte time frame: the accel frame's checksum
        broken.append(i)
        frames[i] = bytes(f)
    stream = b"".join(frames[:10]) + garbage.tobytes() + b"".join(frames[10:])
    with PtyPair() as pair:
        with open_source(f"witmotion://{pair.slave_path}?rate=200") as src:
            pair.write(stream)
            got = read_samples(src, 60 - len(broken), timeout_s=5)
            c = src.counters
            dec = src.decoder
    assert len(got) == 60 - len(broken)
    assert c.crc_errors == len(broken)
    assert c.skipped_bytes == 500 + 11 * len(broken)
    assert c.lost == len(broken)  # the time frames show the gaps
    assert c.bytes == dec.frame_bytes + c.skipped_bytes + dec.pending_bytes
    expected_t = np.delete(block.t, broken)
    assert np.allclose(got.t, expected_t, atol=1e-9)


def test_unplug_and_replug_recover(tmp_path):
    link = tmp_path / "imu0"
    first = PtyPair(link=link)
    src = ReconnectingSource(f"witmotion://{link}?rate=200", min_backoff_s=0.02, max_backoff_s=0.1)
    try:
        src.open()
        assert src.state == "connected"
        first.write(b"".join(encode(still(50))))
        got1 = read_samples(src, 50)
        first.close_master()
        assert read_until_state(src, "reconnecting", 50) == "reconnecting"
        first.close()
        with PtyPair(link=link) as second:
            assert read_until_state(src, "connected", 200) == "connected" and src.reconnects == 1
            second.write(b"".join(encode(still(50, t0=0.25))))
            got2 = read_samples(src, 50)
    finally:
        src.close()
        first.close()
    assert len(got1) == 50 and len(got2) == 50
    assert got2.t[0] > got1.t[-1]  # the device clock carries across the replug
    assert np.allclose(np.diff(np.concatenate([got1.t, got2.t])), 0.005)
    assert src.counters.frames == 100


@pytest.mark.parametrize("url", ["witmotion://", "witmotion:///dev/x?sped=1"])
def test_bad_urls_are_refused(url):
    from imudiag.errors import SourceError

    with pytest.raises(SourceError):
        open_source(url).open()


def test_chunked_is_used_for_frames():
    # the bench's chunked() splits a byte stream: the decoder takes any split
    block = still(20)
    data = b"".join(encode(block))
    from imudiag.drivers.witmotion import WitmotionDecoder

    dec = WitmotionDecoder(rate_hz=200)
    out = SampleBlock.concat([dec.feed(c) for c in chunked(data, 7)])
    assert len(out) == 20 and np.allclose(out.t, np.arange(20) / 200)


def test_daemon_says_no_data_while_unplugged_and_recovers(tmp_path):
    link = tmp_path / "wt901"
    first = PtyPair(link=link)
    path = datasheet_path("witmotion-wt901")
    try:
        with DaemonThread(f"witmotion://{link}?rate=200", str(path)) as d:
            d.wait_connected()
            first.write(b"".join(encode(still(200))))
            d.wait(lambda s: s["state"] == "ok")  # the line of the change to ok (any frames)
            first.close_master()
            gone = d.wait(lambda s: s["link"] == "reconnecting")
            assert gone["state"] == "no_data" and "reconnecting" in gone["notes"][-1]
            first.close()
            with PtyPair(link=link) as second:
                d.wait_connected()
                second.write(b"".join(encode(still(200, t0=1.0))))
                # (ok, or degraded if the reopened port dropped bytes in flight)
                back = d.wait(
                    lambda s: s["counters"]["frames"] > 200 and s["state"] in ("ok", "degraded")
                )
    finally:
        first.close()
    assert back["link"] == "connected" and back["counters"]["crc_errors"] == 0
    assert back["t"] >= 1.0  # the device clock carried on after the replug


def test_a_bench_scenario_served_by_the_fake_device(tmp_path):
    """`python -m imudiag.bench.fake_device witmotion`: the bench's sensor-faults scenario
    (az bias of 800 counts = 38 limits of the native board at t = 2 s) arrives as a
    38-limit az bias of the WT901 (0.38 g)."""
    from imudiag.bench.fake_device import serve
    from imudiag.bench.scenario import load_bundled

    scenario = load_bundled("sensor-faults").with_options(speed=10.0)
    link = tmp_path / "wt901"
    pair, writer = serve("witmotion", scenario, "", 200.0, link=link)
    try:
        with open_source(f"witmotion://{link}?rate=200") as src:
            got = read_samples(src, 700, timeout_s=20)  # 3.5 s of sample time
    finally:
        writer.stop()
        pair.close()
    assert len(got) >= 600 and got.meta["units"] == {"gyro": "deg/s", "accel": "g"}
    # (opening the port flushed what the fake sent before: time 0 is the first sample read,
    # within the first second of the scenario at this pace)
    before, after = got.accel[:50, 2].mean(), got.accel[-50:, 2].mean()  # t < 2 s, t > 3 s
    assert after - before == pytest.approx(800 / 21.0 * 0.01, abs=0.01)

"""CRC-16/CCITT-FALSE and the wire codec of spec/wire-protocol.md: round trips and accounting."""

from __future__ import annotations

import numpy as np
import pytest

from imudiag.drivers.crc import crc16_ccitt_false, crc16_ccitt_false_python, crc16_rows
from imudiag.drivers.wire import (
    FRAME_DTYPE,
    SAMPLE_FRAME_SIZE,
    TYPE_INFO,
    Decoder,
    encode_frame,
    encode_info,
    encode_samples,
)
from imudiag.samples import SampleBlock

RATE_US = 5000  # 200 Hz


def make_stream(n: int, seed: int = 0, seq_start: int = 0, t0_us: int = 1_000_000):
    """n sample frames of board-like data; returns (bytes, raw, time_us, temp_c, flags)."""
    rng = np.random.default_rng(seed)
    raw = np.column_stack(
        [rng.integers(20000, 45000, (n, 3)), rng.integers(28000, 37000, (n, 3))]
    ).astype(np.int64)
    time_us = t0_us + RATE_US * np.arange(n, dtype=np.int64)
    temp_c = np.round(rng.normal(31.0, 2.0, n), 2)
    flags = rng.integers(0, 16, n)
    return encode_samples(seq_start, time_us, raw, temp_c, flags), raw, time_us, temp_c, flags


def feed_chunks(dec: Decoder, data: bytes, rng: np.random.Generator, max_chunk: int) -> SampleBlock:
    """Feed ``data`` in random chunk sizes 1..max_chunk and finish."""
    blocks = []
    pos = 0
    while pos < len(data):
        k = int(rng.integers(1, max_chunk + 1))
        blocks.append(dec.feed(data[pos : pos + k]))
        pos += k
    blocks.append(dec.finish())
    return SampleBlock.concat(blocks)


def assert_accounting(dec: Decoder) -> None:
    c = dec.counters
    assert c.bytes == dec.frame_bytes + c.skipped_bytes + dec.pending_bytes


# -- CRC ----------------------------------------------------------------------


def test_crc_check_value():
    assert crc16_ccitt_false(b"123456789") == 0x29B1
    rows = np.frombuffer(b"123456789", dtype=np.uint8)[None, :]
    assert crc16_rows(rows)[0] == 0x29B1
    assert crc16_ccitt_false(b"") == 0xFFFF
    assert crc16_ccitt_false_python(b"123456789") == 0x29B1


@pytest.mark.parametrize("count", [0, 1, 5, 32, 33, 300])  # binascii below 33 rows, tables above
@pytest.mark.parametrize("length", [1, 2, 7, 36, 37])
def test_crc_rows_matches_scalar(length, count):
    rng = np.random.default_rng(length)
    rows = rng.integers(0, 256, (count, length + 5), dtype=np.uint8)[
        :, 2 : 2 + length
    ]  # strided view
    got = crc16_rows(rows)
    want = [crc16_ccitt_false_python(r.tobytes()) for r in rows]
    assert got.dtype == np.uint16
    assert got.tolist() == want
    assert [crc16_ccitt_false(r.tobytes()) for r in rows] == want


def test_crc_rows_rejects_bad_input():
    with pytest.raises(ValueError, match="2-D uint8"):
        crc16_rows(np.zeros(10, dtype=np.uint8))


# -- encoding ---------------------------------------------------------------------


def test_frame_layout_matches_spec():
    data = encode_samples(
        0x1234,
        np.array([0x89ABCDEF]),
        np.array([[1, -2, 3, -4, 5, 70000]]),
        np.array([-12.34]),
        np.array([0x0005]),
    )
    assert len(data) == SAMPLE_FRAME_SIZE
    assert data[:4] == b"\xaa\x55\x01\x22"
    assert data[4:6] == b"\x34\x12"
    assert data[6:10] == bytes.fromhex("efcdab89")
    assert np.frombuffer(data[10:34], "<i4").tolist() == [1, -2, 3, -4, 5, 70000]
    assert int.from_bytes(data[34:36], "little", signed=True) == -1234
    assert data[36:38] == b"\x05\x00"
    assert int.from_bytes(data[38:40], "little") == crc16_ccitt_false(data[2:38])


def test_encode_rejects_out_of_range():
    with pytest.raises(ValueError, match="int32"):
        encode_samples(0, np.array([0]), np.array([[2**31, 0, 0, 0, 0, 0]]))
    with pytest.raises(ValueError, match=r"\(N, 6\)"):
        encode_samples(0, np.array([0]), np.zeros((1, 5)))
    with pytest.raises(ValueError, match="temp_c"):
        encode_samples(0, np.array([0]), np.zeros((1, 6)), temp_c=np.array([400.0]))
    with pytest.raises(ValueError, match="exceeds"):
        encode_info(0, 0, {"x": "y" * 300})


# -- decoding -------------------------------------------------------------------


def test_round_trip_random_chunking():
    data, raw, time_us, temp_c, flags = make_stream(3000, seed=1, seq_start=100)
    rng = np.random.default_rng(7)
    for max_chunk in (1, 3, 39, 41, 257, 5000):
        dec = Decoder()
        out = feed_chunks(dec, data if max_chunk > 1 else data[: 200 * 40], rng, max_chunk)
        n = len(out)
        assert n == (3000 if max_chunk > 1 else 200)
        np.testing.assert_array_equal(out.gyro, raw[:n, :3])
        np.testing.assert_array_equal(out.accel, raw[:n, 3:])
        np.testing.assert_allclose(out.temp, temp_c[:n], atol=1e-9)
        np.testing.assert_array_equal(out.flags, flags[:n])
        np.testing.assert_array_equal(out.seq, 100 + np.arange(n))
        np.testing.assert_allclose(out.t, time_us[:n] * 1e-6, rtol=0, atol=1e-12)
        c = dec.counters
        assert (c.frames, c.crc_errors, c.skipped_bytes, c.lost, c.duplicates) == (n, 0, 0, 0, 0)
        assert c.bytes == n * SAMPLE_FRAME_SIZE
        assert_accounting(dec)


def test_clean_aligned_stream_takes_vectorised_path():
    data, raw, *_ = make_stream(20000, seed=2)
    dec = Decoder()
    out = dec.feed(data)
    assert len(out) == 20000
    assert dec.resync_steps == 0
    # whole frames per chunk stay on the vectorised path too
    dec = Decoder()
    for i in range(0, len(data), 40 * 1000):
        dec.feed(data[i : i + 40 * 1000])
    assert dec.counters.frames == 20000 and dec.resync_steps == 0


def test_garbage_is_skipped_and_counted_exactly():
    data, raw, *_ = make_stream(500, seed=3)
    rng = np.random.default_rng(3)
    frames = [data[i : i + 40] for i in range(0, len(data), 40)]
    stream = bytearray()
    garbage_total = 0
    for i, f in enumerate(frames):
        if i % 7 == 0:
            g = rng.integers(0, 0xAA, int(rng.integers(1, 90)), dtype=np.uint8).tobytes()  # no 0xAA
            stream += g
            garbage_total += len(g)
        stream += f
    stream += b"\x00\x13\xaa"  # trailing garbage, ending in half a sync
    garbage_total += 3
    dec = Decoder()
    out = feed_chunks(dec, bytes(stream), rng, 333)
    np.testing.assert_array_equal(out.gyro, raw[:, :3])
    c = dec.counters
    assert c.skipped_bytes == garbage_total
    assert (c.frames, c.crc_errors, c.lost, c.duplicates) == (500, 0, 0, 0)
    assert_accounting(dec)


def test_crc_error_dropped_counted_and_seq_gap_is_lost():
    data, raw, *_ = make_stream(100, seed=4)
    bad = bytearray(data)
    bad[40 * 10 + 20] ^= 0x01  # a bit flip in frame 10's gx
    bad[40 * 50 + 38] ^= 0xFF  # frame 50's CRC itself
    dec = Decoder()
    out = dec.feed(bytes(bad))
    c = dec.counters
    assert c.crc_errors == 2
    assert c.frames == 98
    assert c.lost == 2  # their seq numbers never arrive
    assert c.skipped_bytes == 80  # the bad frames' bytes, rescanned
    assert 10 not in out.seq and 50 not in out.seq
    np.testing.assert_array_equal(out.gyro, np.delete(raw, [10, 50], axis=0)[:, :3])
    assert_accounting(dec)


def test_lost_and_duplicate_frames():
    data, raw, *_ = make_stream(200, seed=5)
    frames = [data[i : i + 40] for i in range(0, len(data), 40)]
    drop = {5, 6, 7, 100}
    dup = {20, 21, 150}
    stream = b"".join(f + (f if i in dup else b"") for i, f in enumerate(frames) if i not in drop)
    dec = Decoder()
    out = feed_chunks(dec, stream, np.random.default_rng(5), 97)
    c = dec.counters
    assert c.lost == 4
    assert c.duplicates == 3
    assert c.frames == 196
    assert np.all(np.diff(out.seq) >= 1) and len(np.unique(out.seq)) == 196
    assert not set(drop) & set(out.seq.tolist())
    assert_accounting(dec)


def test_unknown_type_is_skipped_by_length():
    data, raw, time_us, *_ = make_stream(10, seed=6)
    # seq 5 is taken by an unknown frame type 0x07 with a 30-byte payload
    part1 = encode_samples(0, time_us[:5], raw[:5])
    unknown = encode_frame(0x07, 5, int(time_us[5]), bytes(range(30)))
    part2 = encode_samples(6, time_us[6:], raw[6:])
    dec = Decoder()
    out = dec.feed(part1 + unknown + part2)
    assert dec.unknown_frames == 1
    assert len(out) == 9
    c = dec.counters
    assert (c.lost, c.skipped_bytes, c.crc_errors) == (0, 0, 0)
    assert_accounting(dec)


def test_info_frames_parsed_and_take_a_seq():
    info = {"model": "ADXRS300/ADXL202", "serial": "0001", "fw": "1.4", "rate_hz": 200}
    data, raw, time_us, *_ = make_stream(2500, seed=7)
    # the board: info after power-up, then every 1000 frames; seq counts all frames
    parts = [encode_info(0, 0, info)]
    seq = 1
    for start in range(0, 2500, 1000):
        n = min(1000, 2500 - start)
        parts.append(encode_samples(seq, time_us[start : start + n], raw[start : start + n]))
        seq += n
        if start + n < 2500:
            parts.append(encode_info(seq, int(time_us[start + n - 1]) + 1, {**info, "fw": "1.5"}))
            seq += 1
    dec = Decoder()
    out = feed_chunks(dec, b"".join(parts), np.random.default_rng(7), 1500)
    assert dec.info_frames == 3
    assert dec.device_info == {**info, "fw": "1.5"}
    assert len(out) == 2500
    assert dec.counters.lost == 0 and dec.counters.skipped_bytes == 0
    assert_accounting(dec)


def test_info_frame_with_bad_json_is_counted_not_fatal():
    frame = encode_frame(TYPE_INFO, 0, 0, b"{not json")
    dec = Decoder()
    dec.feed(frame + encode_samples(1, np.array([5000]), np.zeros((1, 6))))
    assert dec.info_errors == 1 and dec.device_info == {} and dec.counters.frames == 1


def test_seq_and_time_wraps_unwrapped():
    n = 3000
    t0 = 2**32 - 7 * RATE_US  # time_us wraps after 7 frames
    data, raw, time_us, *_ = make_stream(n, seed=8, seq_start=65530, t0_us=t0)
    dec = Decoder()
    out = feed_chunks(dec, data, np.random.default_rng(8), 4096)
    np.testing.assert_array_equal(out.seq, 65530 + np.arange(n))
    np.testing.assert_allclose(out.t, (t0 + RATE_US * np.arange(n)) * 1e-6, rtol=0, atol=1e-9)
    assert np.all(np.diff(out.t) > 0)
    assert dec.counters.lost == 0 and dec.restarts == 0
    # the encoder wrapped them on the wire
    fr = np.frombuffer(data, FRAME_DTYPE)
    assert fr["seq"][6] == 0 and fr["time_us"][7] < 1000


def test_many_seq_wraps_across_feeds():
    dec = Decoder()
    n_total = 0
    seq = 60000
    t = 0
    for _ in range(5):  # 5 x 30000 frames: crosses 65536 twice
        n = 30000
        raw = np.zeros((n, 6), dtype=np.int64)
        dec.feed(encode_samples(seq, t + RATE_US * np.arange(n), raw))
        seq += n
        t += RATE_US * n
        n_total += n
    assert dec.counters.frames == n_total and dec.counters.lost == 0
    assert dec._seq_abs == 60000 + n_total - 1


def test_board_restart_reanchors_timeline():
    data1, *_ = make_stream(50, seed=9, seq_start=40000, t0_us=900_000_000)
    data2, *_ = make_stream(50, seed=10, seq_start=0, t0_us=20_000)  # power cycled
    dec = Decoder()
    out = SampleBlock.concat([dec.feed(data1), dec.feed(data2)])
    assert dec.restarts == 1
    assert dec.counters.lost == 0
    assert np.all(np.diff(out.t) > 0)
    assert np.all(np.diff(out.seq) == 1)
    np.testing.assert_allclose(np.diff(out.t), RATE_US * 1e-6)


def test_finish_counts_partial_frame_as_skipped():
    data, *_ = make_stream(3, seed=11)
    dec = Decoder()
    dec.feed(data[:100])
    assert dec.pending_bytes == 20
    dec.finish()
    assert dec.counters.skipped_bytes == 20 and dec.pending_bytes == 0
    assert dec.counters.frames == 2
    assert_accounting(dec)


def test_false_sync_in_garbage_does_not_hide_a_frame():
    data, raw, time_us, *_ = make_stream(3, seed=12)
    # garbage with a plausible sample header right before a real frame:
    # the false candidate's CRC fails, the decoder rescans and finds the real frame
    false = b"\xaa\x55\x01\x22" + bytes(10)
    dec = Decoder()
    out = dec.feed(data[:40] + false + data[40:])
    assert len(out) == 3
    assert dec.counters.crc_errors == 1
    assert dec.counters.skipped_bytes == len(false)
    assert_accounting(dec)

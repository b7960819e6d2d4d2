"""The iSensor and WitMotion decoders take plain-Python paths for a daemon's small reads and
numpy paths for large ones: the same stream (garbage, bad checksums, repeated and dropped
samples) gives the same samples and counters whether it arrives in one read or in small,
randomly split ones."""

from __future__ import annotations

import numpy as np
import pytest

from imudiag.bench.fake_isensor import entry_lines
from imudiag.bench.fake_witmotion import encode_frames
from imudiag.drivers.isensor import MODELS, ISensorDecoder
from imudiag.drivers.witmotion import WitmotionDecoder
from imudiag.samples import SampleBlock

COUNTERS = ("frames", "crc_errors", "skipped_bytes", "lost", "duplicates", "bytes")


def _session(n: int, rate: float, seed: int) -> SampleBlock:
    rng = np.random.default_rng(seed)
    t = np.arange(n) / rate
    gyro = rng.normal(0.0, 20.0, (n, 3))  # deg/s
    accel = np.array([0.0, 0.0, 1.0]) + rng.normal(0.0, 0.01, (n, 3))  # g
    gyro[n // 3, 0] = 5000.0  # a saturated sample
    return SampleBlock(t=t, gyro=gyro, accel=accel, temp=np.full(n, 25.0))


def _decode(decoder, data: bytes, sizes: list[int] | None):
    parts = [data] if sizes is None else []
    if sizes is not None:
        pos = 0
        for s in sizes:
            parts.append(data[pos : pos + s])
            pos += s
        parts.append(data[pos:])
    blocks = [decoder.feed(p) for p in parts]
    blocks = [b for b in blocks if len(b)]
    out = {k: np.concatenate([getattr(b, k) for b in blocks]) for k in ("t", "gyro", "accel")}
    out["flags"] = np.concatenate([b.flags for b in blocks])
    counters = {k: getattr(decoder.counters, k) for k in COUNTERS}
    return out, counters


def _same(a, b):
    (sa, ca), (sb, cb) = a, b
    assert ca == cb
    for k in sa:
        np.testing.assert_array_equal(sa[k], sb[k], err_msg=k)


def _split_sizes(rng, total: int, small: int) -> list[int]:
    sizes, pos = [], 0
    while pos < total:
        s = int(rng.integers(1, small))
        sizes.append(s)
        pos += s
    return sizes


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_isensor_small_reads_equal_one_read(seed):
    rng = np.random.default_rng(seed)
    model = MODELS["adis16475-2"]
    lines = entry_lines(_session(600, 1000.0, seed), model.gyro_lsb, model.accel_lsb)
    stream: list[bytes] = []
    for line in lines:
        r = rng.random()
        if r < 0.03:
            continue  # dropped: the data counter counts it lost
        if r < 0.06:
            k = 7 * 5 + int(rng.integers(0, 4))  # a hex digit of X_GYRO_OUT changed
            digit = b"1" if line[k : k + 1] == b"0" else b"0"
            line = line[:k] + digit + line[k + 1 :]
        elif r < 0.08:
            stream.append(line)  # repeated
        elif r < 0.10:
            stream.append(b"garbage " + bytes(rng.integers(65, 90, 20).tolist()) + b"\r\n")
        stream.append(line)
    data = b"".join(stream)
    one = _decode(ISensorDecoder(model=model), data, None)
    assert one[1]["crc_errors"] > 0 and one[1]["duplicates"] > 0 and one[1]["lost"] > 0
    assert one[0]["flags"].any()
    for small in (90, 400, 2000):
        sizes = _split_sizes(rng, len(data), small)
        _same(one, _decode(ISensorDecoder(model=model), data, sizes))


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_witmotion_small_reads_equal_one_read(seed):
    rng = np.random.default_rng(seed)
    frames = encode_frames(_session(600, 200.0, seed))
    stream: list[bytes] = []
    for i in range(0, len(frames), 33):
        sample = frames[i : i + 33]
        r = rng.random()
        if r < 0.03:
            continue  # dropped: the time frames show the gap
        if r < 0.06:
            k = 22 + int(rng.integers(2, 10))  # a payload byte of the rate frame
            sample = sample[:k] + bytes([sample[k] ^ 0x5A]) + sample[k + 1 :]
        elif r < 0.08:
            stream.append(sample)  # repeated
        elif r < 0.10:
            stream.append(bytes(rng.integers(0, 256, int(rng.integers(1, 40))).tolist()))
        stream.append(sample)
    data = b"".join(stream)
    one = _decode(WitmotionDecoder(rate_hz=200.0), data, None)
    assert one[1]["crc_errors"] > 0 and one[1]["skipped_bytes"] > 0 and one[1]["lost"] > 0
    for small in (12, 40, 400):
        sizes = _split_sizes(rng, len(data), small)
        _same(one, _decode(WitmotionDecoder(rate_hz=200.0), data, sizes))

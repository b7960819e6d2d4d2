"""The NPZ reader parses each array's header once per file version (issue 28: a fleet task
opens a log twice): a log rewritten in place with the same size and modification time but
other contents (the same columns as integers instead of floats) is read as it now is, the
arrays' CRC-32 in the key; and the second opening reads what the first did."""

from __future__ import annotations

import os

import numpy as np

from imudiag.logs import open_log


def write(path, t, dtype):
    n = t.size
    cols = {
        name: np.arange(n, dtype=dtype) + k for k, name in enumerate("gx gy gz ax ay az".split())
    }
    np.savez(path, t=t, **cols)


def read(path):
    with open_log(path, block_size=7) as reader:
        blocks = list(reader)
    return np.concatenate([b.t for b in blocks]), np.concatenate([b.gyro for b in blocks])


def test_a_log_rewritten_in_place_is_read_as_it_now_is(tmp_path):
    path = tmp_path / "log.npz"
    t = np.arange(50) * 0.01
    write(path, t, np.float64)
    st = os.stat(path)
    first = read(path)
    again = read(path)  # the headers from the first opening
    assert all(np.array_equal(a, b) for a, b in zip(first, again, strict=True))
    write(path, t, np.int64)  # the same size: '<i8' for '<f8' in each header
    assert os.stat(path).st_size == st.st_size
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns))  # and the same time
    t2, gyro2 = read(path)
    assert np.array_equal(t2, t)
    assert np.array_equal(gyro2[:, 0], np.arange(50, dtype=float))
    assert np.array_equal(gyro2[:, 2], np.arange(50, dtype=float) + 2)

"""A fleet task's gzip CSV logs inflated by ISA-L (``isal``, the fleet extra; issue 28): with
the compiled kernels on, :class:`~imudiag.logs.csv_format.CsvReader` reads the same blocks
from the same bytes as zlib does with them off, on the real recordings of tests/data/real
and on seeded simulated logs, and a damaged stream (truncated, flipped bytes, garbage after
the end) is refused as "corrupt gzip data" at the same place either way."""

from __future__ import annotations

import gzip
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("isal", reason="isal (the fleet extra) is not installed")

from imudiag import kernels  # noqa: E402
from imudiag.logs import LogError, open_log, write_log  # noqa: E402
from imudiag.sim import multi_position, simulate  # noqa: E402

REAL = Path(__file__).parent / "data" / "real"
REAL_GZ = sorted(p for p in REAL.glob("*/*.csv.gz") if "gnss" not in p.name)


def read(path: Path, on: bool) -> tuple[list[np.ndarray], str | None]:
    """Every block's columns stacked, and the error's text (None: read whole)."""
    was = kernels.enabled()
    assert kernels.enable(on) == on, kernels.status()
    out: list[np.ndarray] = []
    try:
        with open_log(path, block_size=5000) as reader:
            for b in reader:
                out.append(np.column_stack([b.t, b.gyro, b.accel]))
    except LogError as exc:
        return out, str(exc)
    finally:
        kernels.enable(was)
    return out, None


def same(path: Path) -> str | None:
    plain, err_plain = read(path, False)
    fast, err_fast = read(path, True)
    assert len(plain) == len(fast)
    for a, b in zip(plain, fast, strict=True):
        assert a.tobytes() == b.tobytes()
    assert (err_plain is None) == (err_fast is None), (err_plain, err_fast)
    if err_plain is not None:
        assert err_fast is not None
        # the same file, the same kind of refusal (the inflaters word their detail apart)
        assert err_plain.split("corrupt gzip data")[0] == err_fast.split("corrupt gzip data")[0]
        assert ("corrupt gzip data" in err_plain) == ("corrupt gzip data" in err_fast)
    return err_plain


@pytest.mark.parametrize("path", REAL_GZ, ids=lambda p: f"{p.parent.name}/{p.name}")
def test_real_gzip_recordings_read_the_same(path):
    assert same(path) is None


@pytest.mark.parametrize("seed", range(3))
def test_damaged_gzip_logs_are_refused_alike(seed, tmp_path):
    cert_free = multi_position(n_attitudes=4, dwell_s=4.0, turn_s=1.0, rate_hz=200, seed=seed)
    from imudiag.certificate import load_default

    block = simulate(load_default(), cert_free, seed=seed).samples
    good = tmp_path / "good.csv.gz"
    write_log(good, block)
    assert same(good) is None
    data = good.read_bytes()
    rng = np.random.default_rng(seed)
    damaged = {
        "truncated": data[: int(len(data) * rng.uniform(0.3, 0.9))],
        "flipped": bytearray(data),
        "trailing garbage": data + b"\x1f\x8b\x08junk",
    }
    flip = damaged["flipped"]
    assert isinstance(flip, bytearray)
    for i in rng.integers(64, len(flip) - 16, size=4):
        flip[i] ^= 0xFF
    refused = 0
    for name, content in damaged.items():
        bad = tmp_path / f"{name.replace(' ', '-')}.csv.gz"
        bad.write_bytes(bytes(content))
        err = same(bad)
        refused += err is not None
    assert refused >= 2  # truncated and flipped at least; the trailing bytes may be read as data
    assert gzip.decompress(data)  # (the good file is a real gzip stream)

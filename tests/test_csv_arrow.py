"""The CSV reader's compiled path (pyarrow's parser, :mod:`imudiag.logs.arrow_csv`) against
its numpy path: the same numbers bit for bit where pyarrow reads a field, nothing read
where numpy refuses one, and whole logs (every real CSV recording shipped, mutated fuzz
seeds) read to the same blocks or refused with the same line and reason."""

from __future__ import annotations

import gzip
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fuzz.targets import BAD_TOKENS, mutate_csv, seed_csv
from imudiag import kernels
from imudiag.logs import LogError, arrow_csv, open_log
from imudiag.logs.arrow_csv import floats
from imudiag.logs.csv_format import CsvReader

pytest.importorskip("pyarrow", reason="pyarrow (fleet extra) is the compiled CSV path")
if not kernels.available():  # the path is used only while the compiled kernels are on
    pytest.skip("numba (fleet extra) switches the compiled paths on", allow_module_level=True)

REAL = Path(__file__).parent / "data" / "real"

#: how a number may be written: Python's shortest repr and printf's forms
FORMATS = ("{!r}", "{:.17g}", "{:.6g}", "{:.3e}", "{:+.10f}", "{:E}", "{:.0f}", "{:.1f}")


def numpy_floats(text: bytes, ncols: int, used: list[int]) -> np.ndarray:
    """The numpy path's values (csv_format's own expression for all-used columns)."""
    flat = text.replace(b"\n", b",")
    return np.fromstring(flat, dtype=float, sep=",").reshape(-1, ncols)[:, used]


def bits(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a).view(np.int64)


@settings(max_examples=200, deadline=None)
@given(
    st.lists(
        st.lists(
            st.tuples(
                st.floats(allow_nan=False, allow_infinity=False, width=64),
                st.sampled_from(FORMATS),
            ),
            min_size=3,
            max_size=3,
        ),
        min_size=1,
        max_size=40,
    )
)
def test_every_spelling_of_a_number_is_read_as_numpy_reads_it(rows: list[list[Any]]) -> None:
    lines = [",".join(fmt.format(x) for x, fmt in row) for row in rows]
    text = ("\n".join(lines) + "\n").encode()
    want = numpy_floats(text, 3, [0, 1, 2])
    got = floats(text, len(rows), 3, [0, 1, 2])
    if got is None:  # not sure: only for a value that is not finite (1e308 written as %.0f)
        assert not np.isfinite(want).all()
        return
    assert got.shape == want.shape and got.strides == want.strides
    assert np.array_equal(bits(got), bits(want))


def test_a_field_numpy_refuses_is_never_read() -> None:
    """Every fuzz bad token and more, in each column of a row among good ones: where numpy
    refuses the text, pyarrow's path reads nothing (None: the numpy path names the line);
    where numpy reads a value that is not finite, the path leaves it to numpy too."""
    extra = ("1.#INF", "NA", "null", "0x1p3", "1d5", "'1'", '"1"', ".", "-", "+-1", "1e+")
    spellings = ("NAN", "+nan", "-nan", "Infinity", "-INF", "nan(1)")
    for token in BAD_TOKENS + extra + spellings:
        for col in range(3):
            fields = ["1.5", "-2", "3e-3"]
            fields[col] = token
            text = ("0.25,1,2\n" + ",".join(fields) + "\n4,5,6\n").encode()
            try:
                want = numpy_floats(text, 3, [0, 1, 2])
                refused = want.shape != (3, 3)
            except ValueError:
                refused = True
            got = floats(text, 3, 3, [0, 1, 2])
            if refused or not np.isfinite(want).all():
                assert got is None, (token, col)
            else:
                assert got is not None and np.array_equal(bits(got), bits(want)), (token, col)


def test_unused_columns_are_split_not_read() -> None:
    """Columns the reader ignores hold anything; the used ones are read as numpy reads them."""
    text = b"1,note one,2.5\n2,1_000,3.5\n"
    got = floats(text, 2, 3, [0, 2])
    assert got is not None and got.tolist() == [[1.0, 2.5], [2.0, 3.5]]
    assert floats(text, 3, 3, [0, 2]) is None  # a row count that differs: not sure


def read(path: Path, on: bool, block_size: int = 4096) -> tuple[str, Any]:
    """A whole log with the compiled paths on or off: ("ok", (meta, columns)) or
    ("error", (line, reason))."""
    with kernels.switched(on) as active:
        assert active is on
        try:
            with open_log(path, block_size) as reader:
                blocks = list(reader)
                meta = dict(reader.meta)
        except LogError as exc:
            return "error", (exc.line, exc.reason)
    cols = {
        name: [getattr(b, name) for b in blocks]
        for name in ("t", "gyro", "accel", "temp", "flags", "seq")
    }
    return "ok", (meta, cols)


def assert_same(a: tuple[str, Any], b: tuple[str, Any]) -> None:
    assert a[0] == b[0]
    if a[0] == "error":
        assert a[1] == b[1]
        return
    (ma, ca), (mb, cb) = a[1], b[1]
    assert ma == mb
    for name in ca:
        assert len(ca[name]) == len(cb[name])
        for u, v in zip(ca[name], cb[name], strict=True):
            assert (u is None) == (v is None)
            if u is not None:
                assert u.dtype == v.dtype and u.strides == v.strides
                assert np.array_equal(u.view(np.uint8), v.view(np.uint8)), name


def csv_logs() -> list[Path]:
    """The real recordings read by the CSV reader (not the units' own exports, which other
    readers take)."""
    found = []
    for p in sorted(REAL.rglob("*")):
        if p.name.endswith((".csv", ".csv.gz")):
            with open_log(p) as reader:
                if isinstance(reader, CsvReader):
                    found.append(p)
    return found


@pytest.mark.parametrize("path", csv_logs(), ids=lambda p: str(p.relative_to(REAL)))
def test_every_real_csv_recording_reads_the_same(
    path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    plain = read(path, False)
    assert plain[0] == "ok"
    read_by_arrow = []

    def counted(*args: Any) -> np.ndarray | None:
        values = floats(*args)
        read_by_arrow.append(values is not None)
        return values

    monkeypatch.setattr(arrow_csv, "floats", counted)
    assert_same(read(path, True), plain)
    assert any(read_by_arrow)  # pyarrow read these numbers (not only numpy after it)


def test_mutated_logs_are_read_or_refused_the_same(tmp_path: Path) -> None:
    """Fuzz seeds (shuffled columns, metadata) with two text mutations each (bad tokens,
    lost or extra fields, moved, empty and comment lines), plain and gzip, block sizes 1-3."""
    rng = np.random.default_rng(20261129)
    outcomes = set()
    for i in range(120):
        text = seed_csv(rng, int(rng.integers(1, 12)))
        ops = [
            (int(rng.integers(0, 10)), rng.random(), rng.random(), int(rng.integers(0, 100)))
            for _ in range(int(rng.integers(0, 3)))
        ]
        data = mutate_csv(text, ops).encode("utf-8")
        path = tmp_path / f"m{i}.csv"
        if i % 2:
            path = path.with_suffix(".csv.gz")
            data = gzip.compress(data, mtime=0)
        path.write_bytes(data)
        block = int(rng.integers(1, 4))
        plain = read(path, False, block)
        assert_same(read(path, True, block), plain)
        outcomes.add(plain[0])
    assert outcomes == {"ok", "error"}  # both kinds were compared

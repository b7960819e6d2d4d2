"""Sample logs (spec/sample-log.md): round trips, metadata, every rejection rule, streaming,
the convert command, and the copied real recordings."""

from __future__ import annotations

import gzip
import tracemalloc
import zipfile
from pathlib import Path

import numpy as np
import pytest
from conftest import run_imudiag_in_process

from imudiag.logs import LogError, open_log, open_writer, read_log, write_log
from imudiag.samples import SampleBlock

HEADER = "t,gx,gy,gz,ax,ay,az"


def random_block(n: int, seed: int = 0, optional: bool = True, t0: float = 0.0) -> SampleBlock:
    """n samples of full-precision random floats (outputs), optionally with temp, seq, flags."""
    rng = np.random.default_rng(seed)
    t = t0 + np.cumsum(rng.uniform(0.001, 0.01, n))
    return SampleBlock(
        t=t,
        gyro=rng.normal(32768.0, 300.0, (n, 3)),
        accel=rng.normal(0.0, 9.8, (n, 3)) * 10.0 ** rng.integers(-8, 8, (n, 3)),
        temp=rng.normal(25.0, 5.0, n) if optional else None,
        seq=np.arange(n) + 7 if optional else None,
        flags=rng.integers(0, 16, n) if optional else None,
    )


def count_block(n: int, seed: int = 0) -> SampleBlock:
    """n samples as a wire capture holds them: integer counts, whole microseconds, 0.01 degC."""
    rng = np.random.default_rng(seed)
    t_us = 1_000_000 + np.cumsum(rng.integers(4000, 6000, n))
    return SampleBlock(
        t=t_us * 1e-6,
        gyro=rng.integers(-(2**31), 2**31 - 1, (n, 3)).astype(float),
        accel=rng.integers(0, 65536, (n, 3)).astype(float),
        temp=rng.integers(-2000, 8000, n) * 0.01,
        seq=np.arange(n) + 100,
        flags=rng.integers(0, 16, n),
    )


def assert_same(a: SampleBlock, b: SampleBlock, optional: bool = True) -> None:
    np.testing.assert_array_equal(a.t, b.t)
    np.testing.assert_array_equal(a.gyro, b.gyro)
    np.testing.assert_array_equal(a.accel, b.accel)
    for name in ("temp", "seq", "flags"):
        if optional:
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
        else:
            assert getattr(b, name) is None


def write_csv(path: Path, text: str) -> Path:
    data = text.encode()
    path.write_bytes(gzip.compress(data) if path.name.endswith(".gz") else data)
    return path


def rejection(path: Path, block_size: int = 65536) -> LogError:
    """The LogError raised while opening and fully iterating ``path``."""
    with pytest.raises(LogError) as info:
        with open_log(path, block_size=block_size) as reader:
            for _ in reader:
                pass
    assert info.value.path == str(path)
    return info.value


# ---------------------------------------------------------------------------
# round trips


@pytest.mark.parametrize("ext", [".csv", ".csv.gz", ".npz"])
@pytest.mark.parametrize("optional", [True, False])
def test_round_trip_exact(tmp_path: Path, ext: str, optional: bool) -> None:
    block = random_block(3000, seed=1, optional=optional)
    meta = {"sample_rate": "200", "device": "test rig", "sections": {"a": {"start": 1}}}
    path = tmp_path / f"log{ext}"
    with open_writer(path, meta=meta) as w:
        w.write(block.slice(0, 1000))
        w.write(block.slice(1000, 3000))
    back = read_log(path)
    assert_same(block, back, optional)
    assert back.meta == meta
    if optional:
        assert back.flags.dtype == np.uint16 and back.seq.dtype == np.int64


def test_round_trip_bin(tmp_path: Path) -> None:
    block = count_block(5000, seed=2)
    path = tmp_path / "capture.bin"
    meta = {"model": "ADXRS300/ADXL202", "serial": "0001", "rate_hz": 200}
    write_log(path, block, meta=meta)
    with open_log(path, block_size=1000) as reader:
        assert reader.meta == meta  # the device-info frame, available before iterating
        blocks = list(reader)
        assert reader.counters.crc_errors == 0 and reader.counters.lost == 0
    back = SampleBlock.concat(blocks)
    assert max(len(b) for b in blocks) <= 1000 and len(back) == 5000
    np.testing.assert_array_equal(back.t, np.rint(block.t * 1e6) * 1e-6)
    np.testing.assert_array_equal(back.gyro, block.gyro)
    np.testing.assert_array_equal(back.accel, block.accel)
    np.testing.assert_allclose(back.temp, block.temp, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(back.seq, block.seq)
    np.testing.assert_array_equal(back.flags, block.flags)


def test_bin_writer_rounds_to_counts_and_keeps_seq_gaps(tmp_path: Path) -> None:
    block = count_block(100, seed=3)
    block.gyro = block.gyro + 0.3
    block.seq = np.r_[np.arange(50), np.arange(60, 110)]
    write_log(tmp_path / "c.bin", block, meta={})
    with open_log(tmp_path / "c.bin") as reader:
        back = SampleBlock.concat(list(reader))
        assert reader.counters.lost == 10
    np.testing.assert_array_equal(back.gyro, np.rint(block.gyro))
    np.testing.assert_array_equal(back.seq, block.seq)


def test_bin_metadata_must_fit_an_info_frame(tmp_path: Path) -> None:
    with pytest.raises(LogError, match="device-info frame holds 249"):
        open_writer(tmp_path / "c.bin", meta={"sections": "x" * 300})


def test_csv_columns_any_order_unknown_columns_comments_crlf(tmp_path: Path) -> None:
    text = (
        "# sample_rate: 100\r\n"
        "# note without key\r\n"
        '# sections: {"x_p": {"start": 0, "end": 2}}\r\n'
        "# broken: {not json\r\n"
        "\r\n"
        "label,az,ay,ax,gz,gy,gx,t,temp,extra\r\n"
        "a b,6,5,4,3,2,1,0.5,20.5,x\r\n"
        "# a comment between rows\r\n"
        "\r\n"
        "c,6.5,5.5,4.5,3.5,2.5,1.5,1.0e0,21,\r\n"
        "d,-6,-5,-4,-3,-2,-1,2.5,22,1_0"
    )
    path = write_csv(tmp_path / "odd.csv", text)
    with open_log(path) as reader:
        assert reader.meta == {
            "sample_rate": "100",
            "sections": {"x_p": {"start": 0, "end": 2}},
            "broken": "{not json",
        }
        block = SampleBlock.concat(list(reader))
    np.testing.assert_array_equal(block.t, [0.5, 1.0, 2.5])
    np.testing.assert_array_equal(block.gyro, [[1, 2, 3], [1.5, 2.5, 3.5], [-1, -2, -3]])
    np.testing.assert_array_equal(block.accel, [[4, 5, 6], [4.5, 5.5, 6.5], [-4, -5, -6]])
    np.testing.assert_array_equal(block.temp, [20.5, 21, 22])
    assert block.seq is None and block.flags is None


def test_csv_with_byte_order_mark(tmp_path: Path) -> None:
    path = tmp_path / "bom.csv"
    path.write_bytes(b"\xef\xbb\xbf" + HEADER.encode() + b"\n0,1,2,3,4,5,6\n")
    assert len(read_log(path)) == 1


def test_writer_refuses_what_readers_reject(tmp_path: Path) -> None:
    block = random_block(10, optional=False)
    path = tmp_path / "w.csv"
    with pytest.raises(LogError, match="t not increasing"):
        with open_writer(path) as w:
            w.write(block)
            w.write(block)  # t restarts: not increasing across blocks
    assert not path.exists() and not Path(str(path) + ".part").exists()
    bad = random_block(10, optional=False)
    bad.accel[4, 1] = np.inf
    with pytest.raises(LogError, match="sample 4: column 'ay': non-finite"):
        write_log(tmp_path / "w.npz", bad)
    assert not (tmp_path / "w.npz").exists()
    with pytest.raises(LogError, match="columns"):
        with open_writer(tmp_path / "w2.csv") as w:
            w.write(random_block(5, optional=True))
            w.write(random_block(5, optional=False, t0=100.0))


def test_writer_without_samples_gives_a_log_readers_reject(tmp_path: Path) -> None:
    for ext in (".csv", ".npz"):
        path = tmp_path / f"empty{ext}"
        with open_writer(path, meta={"a": "b"}):
            pass
        assert "no samples" in rejection(path).reason


# ---------------------------------------------------------------------------
# rejection rules, CSV: file name, exact line, reason

GOOD_ROWS = ["0.00,1,2,3,4,5,6", "0.01,1,2,3,4,5,6", "0.02,1,2,3,4,5,6", "0.03,1,2,3,4,5,6"]


def csv_with(tmp_path: Path, rows: list[str], header: str = HEADER, ext: str = ".csv") -> Path:
    """Two metadata lines, the header on line 3, rows from line 4."""
    text = "# sample_rate: 100\n# device: test\n" + header + "\n" + "\n".join(rows) + "\n"
    return write_csv(tmp_path / f"bad{ext}", text)


def with_row(i: int, row: str) -> list[str]:
    rows = list(GOOD_ROWS)
    rows[i] = row
    return rows


@pytest.mark.parametrize("ext", [".csv", ".csv.gz"])
@pytest.mark.parametrize(
    ("rows", "header", "line", "reason"),
    [
        (GOOD_ROWS, "t,gx,gy,gz,ax,ay", 3, "missing column 'az'"),
        (GOOD_ROWS, "t,gx,gy,gz,ax,ay,temp,az", 4, "ragged row: 7 fields, header has 8"),
        (GOOD_ROWS, "t,gx,gy,gz,ax,ay,az,gx", 3, "duplicate column 'gx'"),
        (GOOD_ROWS, "t,gx,gy,gz,,ax,ay,az", 3, "empty column name"),
        (with_row(2, "0.02,1,2,abc,4,5,6"), HEADER, 6, "column 'gz': not a number: 'abc'"),
        (with_row(1, "0.01,1,2,3,4,,6"), HEADER, 5, "column 'ay': not a number: ''"),
        (with_row(1, "0.01,1,2,3,4,1_000,6"), HEADER, 5, "column 'ay': not a number"),
        (with_row(3, "0.03,1,2,3,4,5,6x"), HEADER, 7, "column 'az': not a number"),
        (with_row(2, "0.02,1,2,3,nan,5,6"), HEADER, 6, "column 'ax': non-finite value nan"),
        (with_row(1, "0.01,1,2,3,4,5,-inf"), HEADER, 5, "column 'az': non-finite value -inf"),
        (with_row(0, "inf,1,2,3,4,5,6"), HEADER, 4, "column 't': non-finite value inf"),
        (with_row(2, "0.01,1,2,3,4,5,6"), HEADER, 6, "t not increasing: 0.01 s after 0.01 s"),
        (with_row(3, "0.015,1,2,3,4,5,6"), HEADER, 7, "t not increasing: 0.015 s after 0.02 s"),
        (with_row(1, "0.01,1,2,3,4,5"), HEADER, 5, "ragged row: 6 fields, header has 7"),
        (with_row(3, "0.03,1,2,3,4,5,6,7"), HEADER, 7, "ragged row: 8 fields, header has 7"),
        (with_row(2, "0.02,1,2,3,4,5,6,"), HEADER, 6, "ragged row: 8 fields, header has 7"),
        (with_row(0, "   "), HEADER, 4, "ragged row: 1 fields, header has 7"),
        # the first bad line wins whatever the kinds of fault after it
        (
            ["0.00,1,2,3,4,5,6", "0.01,1,2,x,4,5,6", "0.00,1,2", "0.03,nan,2,3,4,5,6"],
            HEADER,
            5,
            "not a number",
        ),
        (["0.00,1,2,3,4,5,6", "0.01,1,2,3,4,5,6,9", "0.00,x,2,3,4,5,6"], HEADER, 5, "ragged row"),
        (["0.00,1,2,3,4,5,6", "0.00,1,2,3,4,5,nan"], HEADER, 5, "column 'az': non-finite"),
        ([], HEADER, None, "empty log: no samples"),
    ],
)
def test_csv_rejections(
    tmp_path: Path, ext: str, rows: list[str], header: str, line: int | None, reason: str
) -> None:
    err = rejection(csv_with(tmp_path, rows, header, ext))
    assert err.line == line
    assert reason in err.reason
    where = f"bad{ext}:{line}: " if line is not None else f"bad{ext}: "
    assert where in str(err)


@pytest.mark.parametrize(
    ("column", "value", "reason"),
    [
        ("seq", "1.5", "column 'seq': expected an integer"),
        ("seq", "-1", "column 'seq': expected an integer"),
        ("flags", "65536", "column 'flags': expected an integer 0..65535"),
    ],
)
def test_csv_integer_columns(tmp_path: Path, column: str, value: str, reason: str) -> None:
    rows = [f"{r},0" for r in GOOD_ROWS]
    rows[2] = f"{GOOD_ROWS[2]},{value}"
    err = rejection(csv_with(tmp_path, rows, HEADER + f",{column}"))
    assert (err.line, reason in err.reason) == (6, True)


def test_csv_line_numbers_count_comments_and_blank_lines(tmp_path: Path) -> None:
    text = "# a: 1\n\n" + HEADER + "\n0,1,2,3,4,5,6\n# note\n\n1,1,2,3,4,5,6\n# x\n1,1,2,3,4,5,6\n"
    err = rejection(write_csv(tmp_path / "c.csv", text))
    assert (err.line, err.reason) == (9, "t not increasing: 1.0 s after 1.0 s")


def test_csv_header_problems(tmp_path: Path) -> None:
    err = rejection(write_csv(tmp_path / "h.csv", "# only: comments\n\n"))
    assert err.line is None and "no header" in err.reason
    err = rejection(write_csv(tmp_path / "u.csv", "# a: 1\nt,gx,gy,gz,ax,ay,\xe9z\n"))
    assert "missing column 'az'" in err.reason and err.line == 2
    (tmp_path / "latin.csv").write_bytes(b"# a: \xff\xfe\n" + HEADER.encode() + b"\n")
    err = rejection(tmp_path / "latin.csv")
    assert (err.line, err.reason) == (1, "not UTF-8 text")


def test_unreadable_files(tmp_path: Path) -> None:
    err = rejection(tmp_path / "missing.csv")
    assert "cannot read" in err.reason
    err = rejection(tmp_path / "log.xlsx")
    assert "unknown log format" in err.reason
    err = rejection(tmp_path / "log.txt")  # a text table (issue 11), here missing
    assert "cannot read" in err.reason
    (tmp_path / "trunc.csv.gz").write_bytes(
        gzip.compress((HEADER + "\n" + "\n".join(GOOD_ROWS * 1) + "\n").encode())[:-12]
    )
    assert "corrupt gzip" in rejection(tmp_path / "trunc.csv.gz").reason
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    assert "not an NPZ" in rejection(tmp_path / "junk.npz").reason


# ---------------------------------------------------------------------------
# rejection rules, NPZ and raw capture


def npz_with(tmp_path: Path, **changes: object) -> Path:
    block = random_block(20, optional=False)
    arrays: dict[str, object] = {
        "t": block.t,
        "gx": block.gyro[:, 0],
        "gy": block.gyro[:, 1],
        "gz": block.gyro[:, 2],
        "ax": block.accel[:, 0],
        "ay": block.accel[:, 1],
        "az": block.accel[:, 2],
    }
    arrays.update(changes)
    arrays = {k: v for k, v in arrays.items() if v is not None}
    path = tmp_path / "bad.npz"
    np.savez_compressed(path, **arrays)
    return path


def test_npz_reads_numpy_savez_files(tmp_path: Path) -> None:
    block = random_block(50, optional=False)
    path = tmp_path / "numpy.npz"
    np.savez(
        path,
        t=block.t,
        gx=np.arange(50, dtype=np.int16),
        gy=block.gyro[:, 1],
        gz=block.gyro[:, 2],
        ax=block.accel[:, 0],
        ay=block.accel[:, 1].astype(">f8"),
        az=block.accel[:, 2].astype(np.float32),
        label=np.zeros(3),
        meta=np.array('{"sample_rate": "100"}'),
    )
    back = read_log(path)
    np.testing.assert_array_equal(back.t, block.t)
    np.testing.assert_array_equal(back.gyro[:, 0], np.arange(50))
    np.testing.assert_array_equal(back.accel[:, 1], block.accel[:, 1])
    np.testing.assert_array_equal(back.accel[:, 2], block.accel[:, 2].astype(np.float32))
    assert len(back) == 50 and back.meta == {"sample_rate": "100"}


def test_npz_rejections(tmp_path: Path) -> None:
    t = np.arange(20) * 0.01
    cases = [
        ({"az": None}, "missing array 'az'"),
        ({"gy": np.zeros(19)}, "array 'gy' has 19 values, 't' has 20"),
        ({"ax": np.r_[np.zeros(12), np.nan, np.zeros(7)]}, "sample 12: column 'ax': non-finite"),
        ({"t": np.r_[t[:15], t[14], t[16:]]}, "sample 15: t not increasing"),
        ({"gz": np.zeros((20, 2))}, "array 'gz' must be 1-D"),
        ({"gz": np.array(["x"] * 20)}, "array 'gz' is not numeric"),
        ({"meta": np.array("[1, 2]")}, "array 'meta' is not a JSON object"),
        (
            {"t": np.zeros(0), **{k: np.zeros(0) for k in ("gx", "gy", "gz", "ax", "ay", "az")}},
            "empty log: no samples",
        ),
    ]
    for changes, reason in cases:
        err = rejection(npz_with(tmp_path, **changes), block_size=8)
        assert reason in err.reason, (changes, err)
        assert err.line is None


def test_bin_rejects_repeated_device_time(tmp_path: Path) -> None:
    block = count_block(30, seed=4)
    block.t[17] = block.t[16]
    path = tmp_path / "c.bin"
    from imudiag.drivers.wire import encode_samples

    raw = np.column_stack([block.gyro, block.accel])
    path.write_bytes(encode_samples(0, np.rint(block.t * 1e6).astype(np.int64), raw))
    err = rejection(path, block_size=8)
    assert "sample 17 (frame seq 17): t not increasing" in err.reason
    (tmp_path / "garbage.bin").write_bytes(b"\x00" * 100)
    assert "no samples" in rejection(tmp_path / "garbage.bin").reason


# ---------------------------------------------------------------------------
# streaming


@pytest.mark.parametrize("ext", [".csv", ".csv.gz", ".npz", ".bin"])
def test_streams_in_blocks_without_holding_the_log(tmp_path: Path, ext: str) -> None:
    n = 60_000
    block = count_block(n, seed=5)
    path = tmp_path / f"big{ext}"
    write_log(path, block, meta={"k": "v"})
    whole = n * 12 * 8  # bytes of the samples as float64 arrays
    tracemalloc.start()
    try:
        sizes = []
        last = -np.inf
        with open_log(path, block_size=1000) as reader:
            for b in reader:
                sizes.append(len(b))
                assert b.t[0] > last
                last = b.t[-1]
                del b
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert sum(sizes) == n and len(sizes) >= 60 and max(sizes) <= 1000
    assert peak < whole / 4, f"peak {peak} bytes while streaming a {whole}-byte log"


@pytest.mark.parametrize("block_size", [1, 2, 3, 5, 8])
def test_t_checked_across_block_boundaries(tmp_path: Path, block_size: int) -> None:
    rows = [f"{t},1,2,3,4,5,6" for t in (0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8)]
    rows[8] = "0.7,1,2,3,4,5,6"  # line 10: equal to the previous t
    path = write_csv(tmp_path / "b.csv", HEADER + "\n\n" + "\n".join(rows) + "\n")
    yielded = []
    with pytest.raises(LogError) as info:
        with open_log(path, block_size=block_size) as reader:
            for b in reader:
                yielded.append(len(b))
    assert (info.value.line, info.value.reason) == (11, "t not increasing: 0.7 s after 0.7 s")
    assert sum(yielded) <= 8 and len(yielded) >= 8 // block_size - 1  # earlier blocks came out


def test_t_checked_across_npz_block_boundary(tmp_path: Path) -> None:
    t = np.arange(20) * 0.01
    t[10] = t[9]
    err = rejection(npz_with(tmp_path, t=t), block_size=5)  # row 10 opens the third block
    assert "sample 10: t not increasing" in err.reason


def test_reader_iterates_again_from_the_start(tmp_path: Path) -> None:
    path = tmp_path / "r.csv.gz"
    write_log(path, random_block(100, optional=False), meta={})
    with open_log(path, block_size=30) as reader:
        first = SampleBlock.concat(list(reader))
        second = SampleBlock.concat(list(reader))
        assert reader.samples_read == 100
    assert_same(first, second, optional=False)


# ---------------------------------------------------------------------------
# the convert command (real subprocess)


def test_convert_chain_round_trips(tmp_path: Path, real_data_dir: Path, imudiag_cli) -> None:
    src = real_data_dir / "imucal-ferraris" / "session.csv.gz"
    original = read_log(src)
    steps = [src, tmp_path / "a.npz", tmp_path / "b.csv", tmp_path / "c.csv.gz"]
    for i, (a, b) in enumerate(zip(steps, steps[1:], strict=False)):
        # the first as a real subprocess, the others through cli.main in this process
        run = imudiag_cli if i == 0 else run_imudiag_in_process
        proc = run("convert", str(a), str(b), "--block-size", "4096")
        assert proc.returncode == 0, proc.stderr
        assert f"{len(original)} samples" in proc.stdout
    back = read_log(steps[-1])
    assert_same(original, back, optional=False)
    assert back.meta == original.meta and "x_rot" in back.meta["sections"]


def test_convert_to_bin_and_back(tmp_path: Path, real_data_dir: Path, imudiag_cli) -> None:
    """Real subprocesses: the first refusal and the .bin written from the MPU-6050 log; the
    other cases through cli.main in this process."""
    sections = real_data_dir / "imucal-ferraris" / "session.csv.gz"
    proc = imudiag_cli("convert", str(sections), str(tmp_path / "r.bin"))
    assert proc.returncode == 2 and "device-info frame holds 249" in proc.stderr
    assert not (tmp_path / "r.bin").exists()
    proc = run_imudiag_in_process("convert", "--no-meta", str(sections), str(tmp_path / "r.bin"))
    assert proc.returncode == 2 and "not in counts (gyro in deg/s, accel in m/s^2)" in proc.stderr
    assert not (tmp_path / "r.bin").exists()
    quantum = ["--quantum", "gyro=0.001,accel=0.0001"]
    proc = run_imudiag_in_process(
        "convert", "--no-meta", *quantum, str(sections), str(tmp_path / "r.bin")
    )
    assert proc.returncode == 0, proc.stderr
    assert open_log(tmp_path / "r.bin").meta == {}
    src = real_data_dir / "mpu6050" / "rot90x.csv.gz"
    proc = imudiag_cli("convert", str(src), str(tmp_path / "r.bin"))
    assert proc.returncode == 0, proc.stderr
    proc = run_imudiag_in_process("convert", str(tmp_path / "r.bin"), str(tmp_path / "r.csv"))
    assert proc.returncode == 0, proc.stderr
    original, back = read_log(src), read_log(tmp_path / "r.csv")
    assert back.meta == original.meta  # carried by the device-info frame
    np.testing.assert_array_equal(back.gyro, original.gyro)  # integer counts survive
    np.testing.assert_array_equal(back.accel, original.accel)
    np.testing.assert_allclose(back.t, original.t, rtol=0, atol=0.5e-6)


def test_convert_bad_input_exit_2_names_file_and_line(tmp_path: Path, imudiag_cli) -> None:
    rows = [f"{i * 0.01:.2f},1,2,3,4,5,6" for i in range(5000)]
    rows[4321] = "43.21,1,2,3,4,5"
    bad = write_csv(tmp_path / "bad.csv", HEADER + "\n" + "\n".join(rows) + "\n")
    out = tmp_path / "out.npz"
    proc = imudiag_cli("convert", "--block-size", "1000", str(bad), str(out))
    assert proc.returncode == 2
    assert f"{bad}:4323: ragged row: 6 fields, header has 7" in proc.stderr
    assert not out.exists() and not Path(str(out) + ".part").exists()
    # the ragged row above is the real subprocess; the other refusals in process
    proc = run_imudiag_in_process("convert", str(tmp_path / "nope.csv"), str(out))
    assert proc.returncode == 2 and "nope.csv: cannot read" in proc.stderr
    proc = run_imudiag_in_process("convert", str(bad), str(tmp_path / "out.xlsx"))
    assert proc.returncode == 2 and "unknown log format" in proc.stderr


# ---------------------------------------------------------------------------
# the copied real recordings

REAL = [
    ("xsens-mti-multiposition/session.csv.gz", 51175, "gyro=count accel=count"),
    ("imucal-ferraris/session.csv.gz", 10376, "gyro=deg/s accel=m/s^2"),
    ("mpu6050/static.csv.gz", 44930, "gyro=count accel=count"),
    ("mpu6050/calibration.csv.gz", 10245, "gyro=count accel=count"),
    ("mpu6050/rot90x.csv.gz", 9987, "gyro=count accel=count"),
    ("firm-rocket-launch/flight.csv.gz", 6616, "gyro=deg/s accel=g"),
]


@pytest.mark.parametrize(("name", "rows", "units"), REAL)
def test_real_recordings_parse(real_data_dir: Path, name: str, rows: int, units: str) -> None:
    path = real_data_dir / name
    source = (path.parent / "SOURCE.md").read_text()
    assert "Licence" in source and "copies from the project's shared data set" in source
    with open_log(path, block_size=8192) as reader:
        assert reader.meta["units"] == units
        assert "sample_rate" in reader.meta and "device" in reader.meta
        blocks = list(reader)
    block = SampleBlock.concat(blocks)
    assert len(block) == rows and len(blocks) == -(-rows // 8192)
    assert np.all(np.diff(block.t) > 0) and np.all(np.isfinite(block.gyro))
    if name.startswith("firm"):
        assert block.temp is not None and 26.0 < block.temp.min() < block.temp.max() < 33.0
    if name.startswith("imucal"):
        assert block.meta["sections"]["z_rot"] == {"start": 9205, "end": 9512}


def test_real_recording_files_are_zip_safe(tmp_path: Path, real_data_dir: Path) -> None:
    """A real log survives a round trip through NPZ unchanged (numbers and metadata)."""
    src = real_data_dir / "firm-rocket-launch" / "flight.csv.gz"
    original = read_log(src)
    write_log(tmp_path / "f.npz", original)
    with zipfile.ZipFile(tmp_path / "f.npz") as zf:
        assert "temp.npy" in zf.namelist()
    back = read_log(tmp_path / "f.npz")
    np.testing.assert_array_equal(back.temp, original.temp)
    assert back.meta == original.meta

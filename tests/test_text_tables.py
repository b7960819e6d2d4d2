"""Text tables users already have: separators, headers or none, --columns, time units, --rate."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import run_imudiag_in_process

from imudiag.errors import BadInput
from imudiag.logs import LogError, LogOptions, open_log, read_log
from imudiag.logs.options import parse_columns, parse_units
from imudiag.samples import SampleBlock

RNG = np.random.default_rng(11)
N = 50
T = 100.0 + np.arange(N) * 0.01
G = RNG.normal(0, 0.01, (N, 3))
A = RNG.normal(0, 0.01, (N, 3)) + [0, 0, 9.81]


def _rows(sep: str, t_scale: float = 1.0, with_t: bool = True) -> list[str]:
    rows = []
    for i in range(N):
        vals = ([repr(float(T[i] / t_scale))] if with_t else []) + [
            repr(float(v)) for v in (*G[i], *A[i])
        ]
        rows.append(sep.join(vals))
    return rows


def _check(block, t=T) -> None:
    np.testing.assert_allclose(block.t, t, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(block.gyro, G)
    np.testing.assert_array_equal(block.accel, A)


@pytest.mark.parametrize("sep", [",", ";", "\t", " ", "   "])
def test_separators_with_a_header(tmp_path: Path, sep: str) -> None:
    head = sep.join(["time", "gyro_x", "gyro_y", "gyro_z", "acc_x", "acc_y", "acc_z"])
    path = tmp_path / "imu.txt"
    path.write_text("% recorded on a bench\n" + head + "\n" + "\n".join(_rows(sep)) + "\n")
    _check(read_log(path))


def test_semicolon_table_with_decimal_commas(tmp_path: Path) -> None:
    rows = [r.replace(".", ",") for r in _rows(";")]
    path = tmp_path / "imu.dat"
    path.write_text("\n".join(rows) + "\n")
    opts = LogOptions(columns=parse_columns("t,gx,gy,gz,ax,ay,az"))
    _check(read_log_opts(path, opts))


def read_log_opts(path: Path, opts: LogOptions):
    with open_log(path, options=opts) as reader:
        blocks = list(reader)
    from imudiag.samples import SampleBlock

    return SampleBlock.concat(blocks)


def test_headerless_without_time_needs_columns_and_rate(tmp_path: Path) -> None:
    path = tmp_path / "imu.txt"
    path.write_text("\n".join(_rows(" ", with_t=False)) + "\n")
    with pytest.raises(LogError, match="--columns") as exc:
        open_log(path)
    assert exc.value.line == 1
    with pytest.raises(LogError, match="--rate"):
        open_log(path, options=LogOptions(columns=parse_columns("gx,gy,gz,ax,ay,az")))
    opts = LogOptions(columns=parse_columns("gx,gy,gz,ax,ay,az"), rate=100.0)
    block = read_log_opts(path, opts)
    _check(block, t=np.arange(N) * 0.01)


def test_microsecond_time_and_skipped_columns(tmp_path: Path) -> None:
    rows = [f"{i},{r},junk" for i, r in enumerate(_rows(",", t_scale=1e-6))]
    path = tmp_path / "imu.csv"
    path.write_text("\n".join(rows) + "\n")
    with pytest.raises(LogError, match="--columns"):
        open_log(path)  # no header: the spec CSV reader and the table reader both need names
    opts = LogOptions(columns=parse_columns("_,t,gx,gy,gz,ax,ay,az,_"), time_unit="us")
    _check(read_log_opts(path, opts))


def test_slash_comment_lines_as_xsens_mt_manager_writes_them(tmp_path: Path) -> None:
    """Xsens MT Manager's ASCII export opens with ``// key: value`` lines, then a
    tab-separated header (the real one is in the corpus: tests/data/real/skinematics);
    they are comments, ``// units:`` is metadata like ``# units:``, and a ``//`` line
    among the rows is skipped like a ``#`` one."""
    head = ["// Start Time: 0", "// Sample rate: 100.0Hz", "// units: gyro=rad/s accel=m/s^2"]
    names = "\t".join(["Counter", "Gyr_X", "Gyr_Y", "Gyr_Z", "Acc_X", "Acc_Y", "Acc_Z"])
    rows = [f" {i}\t{r}\t" for i, r in enumerate(_rows("\t", with_t=False))]
    path = tmp_path / "MT_0001.txt"
    path.write_text("\n".join([*head, names, *rows[:10], "// a note", *rows[10:]]) + "\n")
    opts = LogOptions(columns=parse_columns("_,gx,gy,gz,ax,ay,az"), rate=100.0)
    block = read_log_opts(path, opts)
    _check(block, t=np.arange(N) * 0.01)
    assert block.meta["units"] == {"gyro": "rad/s", "accel": "m/s^2"}


def test_bad_rows_name_file_and_line(tmp_path: Path) -> None:
    rows = _rows("\t")
    rows[7] = rows[7].replace(repr(float(G[7, 1])), "abc")
    path = tmp_path / "imu.tsv"
    path.write_text("t\tgx\tgy\tgz\tax\tay\taz\n" + "\n".join(rows) + "\n")
    with pytest.raises(LogError) as exc:
        read_log(path)
    assert exc.value.line == 9 and "not a number: 'abc'" in exc.value.reason
    rows = _rows("\t")
    rows[3] = rows[2]
    path.write_text("t\tgx\tgy\tgz\tax\tay\taz\n" + "\n".join(rows) + "\n")
    with pytest.raises(LogError, match="t not increasing") as exc:
        read_log(path)
    assert exc.value.line == 5


def test_option_values_are_checked() -> None:
    with pytest.raises(BadInput, match="unknown column 'wx'"):
        parse_columns("t,wx,gy,gz,ax,ay,az")
    with pytest.raises(BadInput, match="missing gx"):
        parse_columns("t,gy,gz,ax,ay,az")
    with pytest.raises(BadInput, match="furlong"):
        parse_units("gyro=furlong/s")
    assert parse_units("gyro=deg/s,accel=g") == {"gyro": "deg/s", "accel": "g"}


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """One simulated multi-position session (counts), as the spec CSV of imudiag."""
    from imudiag.certificate import load_default
    from imudiag.logs import open_writer
    from imudiag.sim import Fault, multi_position, simulate

    cert = load_default()
    traj = multi_position(n_attitudes=14, dwell_s=3.0, turn_s=1.5, rate_hz=200, seed=21)
    lim = cert.accel.limits.scale_factor_error[2]
    sim = simulate(cert, traj, seed=22, faults=[Fault("scale_factor", "az", 0.0, 4 * lim)])
    d = tmp_path_factory.mktemp("table")
    with open_writer(d / "session.csv", {}) as w:
        w.write(sim.samples)
    return d, sim.samples


def _report(imudiag_cli, *args: str) -> dict:
    import json

    r = imudiag_cli("diagnose", *args, "--json", "-", "--no-windows")
    assert r.returncode == 0, r.stderr
    report = json.loads(r.stdout)
    report.pop("log", None)
    return report


def test_diagnose_reads_a_users_table_like_the_spec_csv(session, imudiag_cli) -> None:
    """Same session, whitespace table in ms with other column names: the same report."""
    d, samples = session
    table = d / "session.txt"
    lines = ["# exported by a bench logger", "stamp_ms wx wy wz acc_x acc_y acc_z"]
    for i in range(len(samples)):
        vals = [samples.t[i] * 1e3, *samples.gyro[i], *samples.accel[i]]
        lines.append(" ".join(repr(float(v)) for v in vals))
    table.write_text("\n".join(lines) + "\n")
    ref = _report(imudiag_cli, str(d / "session.csv"))
    assert ref["verdict"]["accel"] == "fault"
    # the reference above is the real subprocess; the user's table in process
    got = _report(
        run_imudiag_in_process, str(table), "--columns", "t,gx,gy,gz,ax,ay,az", "--time-unit", "ms"
    )
    _same(got, ref)


def _same(a, b, where: str = "") -> None:
    """Equal reports up to float precision (t in ms -> s rounds in the last bit)."""
    if isinstance(a, dict):
        assert set(a) == set(b), where
        for k in a:
            _same(a[k], b[k], f"{where}.{k}")
    elif isinstance(a, list):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            _same(x, y, f"{where}[{i}]")
    elif isinstance(a, float) and isinstance(b, float):
        assert a == pytest.approx(b, rel=1e-9, abs=1e-12), where
    else:
        assert a == b, where


def test_log_options_refuse_bad_values_with_exit_2(session, imudiag_cli) -> None:
    d, _ = session
    for i, (args, text) in enumerate(
        (
            (["--columns", "t,gx,gy,gz,ax,ay,bogus"], "unknown column 'bogus'"),
            (["--units", "gyro=furlong/s"], "furlong"),
            (["--time-unit", "fortnight"], "--time-unit"),
        )
    ):
        # the first as a real subprocess, the others through cli.main in this process
        run = imudiag_cli if i == 0 else run_imudiag_in_process
        r = run("diagnose", str(d / "session.csv"), *args)
        assert r.returncode == 2 and text in r.stderr, (args, r.stderr)
        assert "Traceback" not in r.stderr


def test_replay_url_reads_a_text_table_with_query_keys(tmp_path: Path) -> None:
    from imudiag.drivers import EndOfStream, SourceError, open_source
    from imudiag.samples import SampleBlock

    path = tmp_path / "imu.txt"
    path.write_text("\n".join(_rows(" ", with_t=False)) + "\n")
    src = open_source(f"replay://{path}?speed=0&columns=gx,gy,gz,ax,ay,az&rate=100")
    blocks = []
    with src:
        with pytest.raises(EndOfStream):
            for _ in range(1000):
                blocks.append(src.read())
    _check(SampleBlock.concat(blocks), t=np.arange(N) * 0.01)
    with pytest.raises(SourceError, match="time_unit"):
        open_source(f"replay://{path}?time_unit=fortnight")
    with pytest.raises(SourceError, match="rate"):
        open_source(f"replay://{path}?columns=gx,gy,gz,ax,ay,az&rate=0")


@pytest.mark.parametrize("name", ["spec.csv", "table.txt"])
def test_absurd_finite_values_are_refused_with_file_and_line(tmp_path: Path, name: str) -> None:
    rows = _rows(",")
    rows[4] = rows[4].replace(repr(float(A[4, 2])), "1e300")
    path = tmp_path / name
    path.write_text("t,gx,gy,gz,ax,ay,az\n" + "\n".join(rows) + "\n")
    with pytest.raises(LogError, match="absurd value 1e\\+300") as exc:
        read_log(path)
    assert exc.value.line == 6 and exc.value.path == str(path)


def test_convert_to_bin_refuses_a_log_not_in_counts(tmp_path: Path, imudiag_cli) -> None:
    """Issue 11 item 5 / 12 item 7: FIRM (deg/s, g) to .bin was rc 0 with every gyro 0.0."""
    firm = Path(__file__).parent / "data" / "real" / "firm-rocket-launch" / "flight.csv.gz"
    out = tmp_path / "firm.bin"
    r = imudiag_cli("convert", str(firm), str(out))
    assert r.returncode == 2 and "not in counts (gyro in deg/s, accel in g)" in r.stderr
    assert "--quantum" in r.stderr and not out.exists()
    assert not Path(str(out) + ".part").exists()
    # the refusal above is the real subprocess; with --quantum in process
    r = run_imudiag_in_process(
        "convert", str(firm), str(out), "--quantum", "gyro=0.001,accel=0.0001"
    )
    assert r.returncode == 0, r.stderr
    back = read_log(out)
    src = read_log(firm)
    np.testing.assert_allclose(back.gyro * 0.001, src.gyro, atol=0.0005 + 1e-12)
    np.testing.assert_allclose(back.accel * 0.0001, src.accel, atol=0.00005 + 1e-12)
    assert np.any(back.gyro != 0)
    assert back.meta["units"] == "gyro=count accel=count"


def test_convert_to_bin_refuses_fractional_counts_and_keeps_no_temperature(
    tmp_path: Path, imudiag_in_process
) -> None:
    """In process: convert's refusal to write a .bin runs as a real subprocess in
    test_convert_to_bin_refuses_a_log_not_in_counts, its .bin written in test_logs.py."""
    imudiag_cli = imudiag_in_process
    path = tmp_path / "frac.csv"
    path.write_text("t,gx,gy,gz,ax,ay,az\n" + "\n".join(_rows(",")) + "\n")
    r = imudiag_cli("convert", str(path), str(tmp_path / "frac.bin"))
    assert r.returncode == 2 and "sample 0 (t = 100.0 s): gyro output" in r.stderr
    assert not (tmp_path / "frac.bin").exists()
    counts = tmp_path / "counts.csv"
    rows = [f"{i * 0.01!r},1,2,3,4,5,{1000 + i}" for i in range(20)]
    counts.write_text("t,gx,gy,gz,ax,ay,az\n" + "\n".join(rows) + "\n")
    r = imudiag_cli("convert", str(counts), str(tmp_path / "counts.bin"))
    assert r.returncode == 0, r.stderr
    back = read_log(tmp_path / "counts.bin")
    assert back.temp is None and back.meta == {}  # not temp 0.0
    r = imudiag_cli("convert", str(tmp_path / "counts.bin"), str(tmp_path / "again.csv"))
    assert r.returncode == 0, r.stderr
    assert "temp" not in (tmp_path / "again.csv").read_text().splitlines()[0]


@pytest.mark.parametrize("command", ["diagnose", "calibrate"])
def test_si_log_with_a_counts_certificate_is_exit_2_naming_both(
    session, tmp_path: Path, imudiag_cli, command: str
) -> None:
    """Issue 11 item 2: no silent misreading of units, stated in the log or by --units."""
    d, _ = session
    firm = Path(__file__).parent / "data" / "real" / "firm-rocket-launch" / "flight.csv.gz"
    extra = ["--like", "config/default-certificate.yaml", "--out", str(tmp_path / "c.yaml")]
    args = extra if command == "calibrate" else []
    # diagnose's first refusal is the real subprocess, the others in process
    run = imudiag_cli if command == "diagnose" else run_imudiag_in_process
    r = run(command, str(firm), *args)
    assert r.returncode == 2, r.stderr
    assert "'deg/s'" in r.stderr and "output_unit is 'count'" in r.stderr
    assert "--units" in r.stderr and "use a certificate" in r.stderr
    r = run_imudiag_in_process(
        command, str(d / "session.csv"), "--units", "gyro=rad/s,accel=m/s^2", *args
    )
    assert r.returncode == 2 and "'rad/s'" in r.stderr and "'count'" in r.stderr, r.stderr
    assert not (tmp_path / "c.yaml").exists()


XIO = Path(__file__).parent / "data" / "real" / "skinematics"


def _read(path: Path, options: LogOptions | None = None) -> SampleBlock:
    with open_log(path, options=options) as reader:
        return SampleBlock.concat(list(reader))


@pytest.mark.parametrize(
    ("name", "opts"),
    [
        ("ngimu-sensors.csv", LogOptions(units={"gyro": "deg/s", "accel": "g"})),
        ("ximu3-inertial.csv", LogOptions(units={"gyro": "deg/s", "accel": "g"}, time_unit="us")),
    ],
)
def test_x_io_exports_read_their_units_from_the_header(name: str, opts: LogOptions) -> None:
    """x-io's GUI writes ``Gyroscope X (deg/s)``, ``Accelerometer X (g)``, ``Timestamp
    (us)``: the real exports read with no option as they read with the options stated."""
    path = XIO / name
    with open_log(path) as r:
        assert r.meta["units"] == {"gyro": "deg/s", "accel": "g"}
        assert r.meta["units_from"] == "the header's brackets"
    bare, stated = _read(path), _read(path, opts)
    assert len(bare) == len(stated) > 400
    np.testing.assert_array_equal(bare.t, stated.t)
    np.testing.assert_array_equal(bare.gyro, stated.gyro)
    np.testing.assert_array_equal(bare.accel, stated.accel)
    assert 0.015 < float(np.median(np.diff(bare.t))) < 0.025  # about 50 Hz, in seconds


def test_stated_options_win_over_the_header_and_mixed_brackets_state_nothing(
    tmp_path: Path,
) -> None:
    rows = "\n".join(f"{i * 10},0.1,0.2,0.3,0,0,1" for i in range(50))
    mixed = tmp_path / "mixed.csv"
    mixed.write_text(
        "Time (ms),Gyro X (deg/s),Gyro Y (rad/s),Gyro Z (deg/s),Acc X (g),Acc Y (g),Acc Z (g)\n"
        + rows
    )
    with open_log(mixed) as r:
        assert "units" not in r.meta  # the gyro columns disagree: no unit is guessed
    assert float(_read(mixed).t[1]) == pytest.approx(0.010)  # the (ms) of the time column
    opts = LogOptions(units={"gyro": "rad/s", "accel": "m/s^2"}, time_unit="s")
    with open_log(mixed, options=opts) as r:
        assert r.meta["units"] == {"gyro": "rad/s", "accel": "m/s^2"}
        assert "units_from" not in r.meta
    # --time-unit s is taken as said: 10 s per sample, which the rate check refuses
    with pytest.raises(LogError, match="likely in ms"):
        _read(mixed, opts)

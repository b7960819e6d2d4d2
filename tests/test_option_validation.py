"""Every option value of every command is checked up front (issue 11 item 5).

Each bad value runs through the real command line (imudiag.cli.main, and a real
subprocess per command): exit 2, one line on stderr naming the option and the
reason, no traceback, nothing written.
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import run_imudiag_in_process

from imudiag.argtypes import (
    finite_float,
    nonnegative_float,
    positive_float,
    positive_int,
    seed,
    writable_directory,
    writable_output_path,
)
from imudiag.certificate import default_certificate_path
from imudiag.cli import build_parser, main

DATA = Path(__file__).parent / "data" / "rdata"

RATES = ["0", "-5", "nan", "inf", "-inf", "fast", "1e999"]
POSITIVE_S = ["0", "-1", "nan", "inf", "x"]
COUNTS = ["0", "-3", "2.5", "many"]
SEEDS = ["1.5", "abc", "-1", "1e3", str(2**64)]
#: output paths that cannot be written: {tmp} is the test's directory
BAD_OUTPUTS = ["{tmp}/no-such-dir/out.{ext}", "{tmp}/a-file/out.{ext}", "{tmp}"]

NONE = "{tmp}/none.yaml"  #: an input file that does not exist
FLEET = ["fleet", "{log}", "--out", "{tmp}/fo"]
LOG_COMMANDS = {
    "diagnose": ["diagnose", "{log}"],
    "calibrate": ["calibrate", "{log}", "--like", "{cert}", "--out", "{tmp}/c.yaml"],
    "model-check": ["model-check", "{log}", "--certificate", "{cert}"],
    "allan": ["allan", "{log}"],
    "convert": ["convert", "{log}", "{tmp}/o.csv"],
}
#: the log options every log command shares: bad values, and choosers that do not apply to CSV
LOG_OPTIONS: list[tuple[str, list[str]]] = [
    ("--rate", RATES),
    ("--instance", ["-1", "first", "0"]),
    ("--variable", ["imu"]),
    ("--topic", ["/imu/data"]),
    ("--ros-distro", ["melodic", "humble"]),  # unknown; a CSV is no ROS bag
    ("--units", ["gyro=furlong", "speed=1"]),
    ("--time-unit", ["fortnight"]),
    ("--columns", ["t,gx,gy", "t,gx,gy,gz,ax,ay,qq"]),
]

# command line before the option, the option, its bad values[, text the message must hold
# instead of the option: an input file's message names the file]
CASES: list[tuple] = [
    # run: the daemon (a bad value must stop it before it starts)
    (["run"], "--status-rate", RATES),
    (["run"], "--nmea-rate", RATES),
    (["run"], "--no-data-timeout", POSITIVE_S),
    (["run"], "--log-level", ["loud"]),
    (["run"], "--source", ["bogus://x"]),
    (["run"], "--source", ["sim://nowhere", "serial://"], "://"),
    (["run"], "--aiding", ["bogus://x"]),
    (["run"], "--certificate", [NONE]),
    (["run"], "--config", [NONE], "none.yaml"),
    (["run"], "--status", ["/dev/no-such-port"], "/dev/no-such-port"),
    # diagnose
    (["diagnose", "{log}"], "--block-size", COUNTS),
    (["diagnose", "{log}"], "--min-interval", POSITIVE_S),
    (["diagnose", "{log}"], "--window-intervals", COUNTS),
    (["diagnose", "{log}"], "--persist", COUNTS),
    (["diagnose", "{log}"], "--k-sigma", ["0", "-4", "nan", "inf"]),
    (["diagnose", "{log}"], "--min-dof", ["-1", "nan", "inf"]),
    (["diagnose", "{log}"], "--gnss-latency", ["nan", "inf", "soon"]),
    (["diagnose", "{log}"], "--gnss-interval", POSITIVE_S),
    (["diagnose", "{log}"], "--gnss-window", POSITIVE_S),
    (["diagnose", "{log}"], "--lever-arm", ["1,2", "1,2,nan"]),
    (["diagnose", "{log}"], "--known-rate", ["0rpm", "-3deg/s", "fast", "nanrpm"]),
    (["diagnose", "{log}"], "--method", ["best"]),
    (["diagnose", "{log}"], "--gyro-mode", ["psychic"]),
    (["diagnose", "{log}"], "--magnitude", [NONE]),
    (["diagnose", "{log}"], "--gnss", [NONE], "none.yaml"),
    (["diagnose", "{log}"], "--certificate", [NONE], "none.yaml"),
    (["diagnose", "{log}"], "--json", BAD_OUTPUTS),
    (["diagnose", "{log}"], "--plots", ["{tmp}/a-file/plots", "{tmp}/a-file"]),
    # calibrate
    (LOG_COMMANDS["calibrate"], "--min-interval", ["0", "-1", "nan"]),
    (LOG_COMMANDS["calibrate"], "--block-size", COUNTS),
    (LOG_COMMANDS["calibrate"], "--json", BAD_OUTPUTS),
    (LOG_COMMANDS["calibrate"], "--known-rate", ["0rpm"]),
    (LOG_COMMANDS["calibrate"], "--short-holds", ["sometimes", ""]),
    (LOG_COMMANDS["calibrate"], "--method", ["best"]),
    (LOG_COMMANDS["calibrate"], "--gyro-mode", ["psychic"]),
    (LOG_COMMANDS["calibrate"], "--magnitude", [NONE], "none.yaml"),
    (["calibrate", "{log}", "--out", "{tmp}/c.yaml"], "--like", [NONE], "none.yaml"),
    (["calibrate", "{log}", "--like", "{cert}"], "--out", BAD_OUTPUTS),
    (LOG_COMMANDS["calibrate"], "--plots", ["{tmp}/a-file/plots", "{tmp}/a-file"]),
    # model-check
    (LOG_COMMANDS["model-check"], "--seed", SEEDS),
    (LOG_COMMANDS["model-check"], "--chunk", ["0", "0.01", "nan"]),
    (LOG_COMMANDS["model-check"], "--z-min", ["0", "-1", "inf"]),
    (LOG_COMMANDS["model-check"], "--block-size", ["10", "0", "x"]),
    (LOG_COMMANDS["model-check"], "--json", BAD_OUTPUTS),
    (LOG_COMMANDS["model-check"], "--extended-certificate", BAD_OUTPUTS),
    (LOG_COMMANDS["model-check"], "--plots", ["{tmp}/a-file/plots", "{tmp}/a-file"]),
    (["model-check", "{log}"], "--certificate", [NONE], "none.yaml"),
    # fleet
    (FLEET, "--workers", COUNTS),
    (FLEET, "--timeout", POSITIVE_S),
    (FLEET, "--retries", ["-1", "2.5", "x"]),
    (FLEET, "--memory-limit", ["lots", "-5MB", "0", "60MB"]),
    (FLEET, "--scheduler", ["not-a-url", "tcp://", "tcp://host:port"]),
    (FLEET, "--certificate", [NONE], "none.yaml"),
    (FLEET, "--certificates", [NONE], "none.yaml"),
    (["fleet", "{log}"], "--out", ["{tmp}/a-file/out", "{tmp}/a-file"]),
    (["fleet", "--out", "{tmp}/fo"], "PATH", [NONE], "none.yaml"),
    (["fleet", "--out", "{tmp}/fo"], "PATH", ["{tmp}/*.nothing"], "*.nothing"),
    # simulate
    (["simulate", "static", "--out", "{tmp}/s.csv"], "--duration", POSITIVE_S + ["-0.5"]),
    (["simulate", "static", "--out", "{tmp}/s.csv", "--duration", "2"], "--seed", SEEDS),
    (["simulate", "static", "--out", "{tmp}/s.csv", "--duration", "2"], "--rate", RATES),
    (["simulate", "static", "--duration", "2"], "--out", BAD_OUTPUTS),
    # simulate fleet
    (["simulate", "fleet", "--out", "{tmp}/sf", "--flights", "3"], "--vehicles", COUNTS),
    (["simulate", "fleet", "--out", "{tmp}/sf", "--vehicles", "2"], "--flights", COUNTS),
    (
        ["simulate", "fleet", "--out", "{tmp}/sf", "--vehicles", "2", "--flights", "3"],
        "--drifting",
        ["-1", "x", "5"],
    ),
    (
        ["simulate", "fleet", "--out", "{tmp}/sf", "--vehicles", "2", "--flights", "3"],
        "--corrupt",
        ["-1", "x"],
    ),
    (
        ["simulate", "fleet", "--out", "{tmp}/sf", "--vehicles", "2", "--flights", "3"],
        "--flight-seconds",
        ["x", "0:5", "5:1", "nan:3"],
    ),
    (["simulate", "fleet", "--vehicles", "2", "--flights", "3"], "--out", ["{tmp}/a-file"]),
    (["simulate", "urban", "--out", "{tmp}/s.csv", "--duration", "2"], "--gnss", BAD_OUTPUTS),
    (
        ["simulate", "static", "--out", "{tmp}/s.csv", "--duration", "2"],
        "--true-certificate",
        BAD_OUTPUTS,
    ),
    (
        ["simulate", "static", "--out", "{tmp}/s.csv", "--duration", "2"],
        "--effect",
        ["bogus", "noise:-1", "drop:2"],
    ),
    (
        ["simulate", "static", "--out", "{tmp}/s.csv", "--duration", "2"],
        "--fault",
        ["bogus", "bias:qx:1:2", "bias:ax:nan:2", "bias:ax:2:100", "stuck:gz:5"],
    ),
    (
        ["simulate", "multiposition", "--out", "{tmp}/s.csv", "--duration", "2"],
        "--param",
        ["n", "n=x", "n=-3"],
    ),
    (
        ["simulate", "static", "--out", "{tmp}/s.csv", "--duration", "2"],
        "--certificate",
        [NONE],
        "none.yaml",
    ),
    (["simulate", "--out", "{tmp}/s.csv", "--duration", "2"], "SCENARIO", ["nowhere"]),
    # allan
    (["allan", "{log}"], "--start", ["nan", "inf", "early"]),
    (["allan", "{log}"], "--stop", ["nan", "-inf"]),
    (["allan", "{log}"], "--points-per-decade", COUNTS),
    (["allan", "{log}"], "--psd-segment", ["8", "0", "-1", "x"]),
    (["allan", "{log}"], "--sensors", ["gq"]),
    (["allan", "{log}"], "--json", BAD_OUTPUTS),
    # bench (refused before the daemon starts)
    (["bench"], "--seed", SEEDS),
    (["bench"], "--speed", ["-1", "0", "nan", "inf", "quick"]),
    (["bench"], "--json", BAD_OUTPUTS),
    (["bench"], "--scenario", [NONE], "none.yaml"),
    (["bench"], "--device", ["nosuch"]),
    (["bench"], "SCENARIO", ["no-such-scenario"], "no-such-scenario"),
    # convert
    (["convert", "{log}"], "OUT", BAD_OUTPUTS),
    (LOG_COMMANDS["convert"], "--block-size", COUNTS),
    (["convert", "{log}", "{tmp}/o.bin"], "--quantum", ["gyro=0", "gyro=x"]),
    # certificate import / export
    (
        ["certificate", "import", "--format", "imu_tk", "--out", "{tmp}/c.yaml"],
        "FILE",
        [NONE],
        "none.yaml",
    ),
    (["certificate", "import", NONE, "--out", "{tmp}/c.yaml"], "--format", ["matlab"]),
    (
        ["certificate", "import", NONE, "--format", "imu_tk", "--out", "{tmp}/c.yaml"],
        "--units",
        ["gyro=furlong", "speed=1", "accel"],
    ),
    (
        ["certificate", "import", "--format", "imu_tk", "--gyro", NONE, "--out", "{tmp}/c.yaml"],
        "--accel",
        [NONE],
        "none.yaml",
    ),
    (
        ["certificate", "import", "--format", "imu_tk", "--accel", NONE, "--out", "{tmp}/c.yaml"],
        "--gyro",
        [NONE],
        "none.yaml",
    ),
    (
        ["certificate", "import", "{cert}", "--format", "kalibr", "--out", "{tmp}/c.yaml"],
        "--like",
        [NONE],
        "none.yaml",
    ),
    (
        ["certificate", "import", "{cert}", "--format", "kalibr", "--out", "{tmp}/c.yaml"],
        "--gauge",
        ["crooked"],
    ),
    (["certificate", "import", "{cert}", "--format", "kalibr"], "--out", BAD_OUTPUTS),
    (
        ["certificate", "export", "--format", "kalibr", "--out", "{tmp}/k.yaml"],
        "CERT",
        [NONE],
        "none.yaml",
    ),
    (["certificate", "export", "{cert}", "--out", "{tmp}/k.yaml"], "--format", ["matlab"]),
    (["certificate", "export", "{cert}", "--format", "kalibr"], "--out", BAD_OUTPUTS),
] + [(prefix, option, values) for prefix in LOG_COMMANDS.values() for option, values in LOG_OPTIONS]


def _command(prefix: list[str]) -> str:
    """The command words of a command line: the command, and the action of ``certificate``."""
    return " ".join(prefix[:2]) if prefix[0] == "certificate" else prefix[0]


def _params():
    for prefix, option, values, *names in CASES:
        for value in values:
            named = names[0] if names else option
            yield pytest.param(
                prefix, option, value, named, id=f"{_command(prefix)} {option} {value}"
            )


@pytest.fixture
def workdir(tmp_path: Path):
    """A directory with a real log, a regular file (not a directory) and the certificate;
    the signal handlers main() installs are restored afterwards."""
    log = tmp_path / "log.csv.gz"
    shutil.copy(DATA / "session.csv.gz", log)
    (tmp_path / "a-file").write_text("a file, not a directory\n")
    saved = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    yield {"tmp": str(tmp_path), "log": str(log), "cert": str(default_certificate_path())}
    for s, handler in saved.items():
        signal.signal(s, handler)


def _argv(prefix: list[str], option: str, value: str, where: dict[str, str]) -> list[str]:
    ext = "csv" if prefix[0] in ("convert", "simulate") else "json"
    value = value.format(ext=ext, **where)
    args = [a.format(**where) for a in prefix]
    if option.startswith("--"):
        return [*args, f"{option}={value}"]  # '=' so a value like -5 is never an option
    return [*args, value]


def _listing(tmp: Path) -> set[str]:
    return {str(p.relative_to(tmp)) for p in tmp.rglob("*")}


@pytest.mark.parametrize(("prefix", "option", "value", "named"), list(_params()))
def test_bad_value_is_exit_2_one_line_naming_the_option(
    workdir, capsys, prefix: list[str], option: str, value: str, named: str
) -> None:
    before = _listing(Path(workdir["tmp"]))
    try:
        code = main(_argv(prefix, option, value, workdir))
    except SystemExit as exc:
        code = exc.code
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert code == 2, captured.err
    assert len(lines) == 1, captured.err
    assert named in lines[0], lines[0]
    assert lines[0].startswith(f"imudiag {_command(prefix)}: error: "), lines[0]
    assert "Traceback" not in captured.err
    assert _listing(Path(workdir["tmp"])) == before  # nothing written


def test_every_numeric_or_output_option_has_a_checking_type() -> None:
    """No option of any command is parsed by bare float or int (nan, inf, 0 or a negative
    would get through), and every option that takes a value has bad values in CASES."""
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    bare = []
    for name, cmd in sub.choices.items():
        for action in cmd._actions:
            if action.type in (float, int):
                bare.append(f"{name} {'/'.join(action.option_strings) or action.dest}")
    assert bare == []
    covered = {(_command(case[0]), case[1]) for case in CASES}
    commands = dict(sub.choices)
    for name, cmd in list(commands.items()):  # a command with actions: each action's options
        for action in cmd._actions:
            if isinstance(action, argparse._SubParsersAction):
                del commands[name]
                commands.update({f"{name} {a}": p for a, p in action.choices.items()})
    for name, cmd in commands.items():
        for action in cmd._actions:
            if action.nargs == 0 or action.dest == "help":
                continue  # a flag: no value to check
            option = action.option_strings[0] if action.option_strings else action.metavar
            if option in ("LOG", "IN"):
                continue  # the log a command reads: its errors are the readers' (test_logs.py)
            assert (name, option) in covered, (name, option)


@pytest.mark.parametrize(
    "argv",
    [
        ["run", "--status-rate", "0"],
        ["diagnose", "{log}", "--min-interval", "0"],
        ["calibrate", "{log}", "--like", "{cert}", "--out", "{tmp}/no/c.yaml"],
        ["model-check", "{log}", "--certificate", "{cert}", "--seed", "1.5"],
        ["simulate", "static", "--duration", "nan", "--out", "{tmp}/s.csv"],
        ["allan", "{log}", "--rate=-5"],
        ["bench", "--speed=-1"],
        ["convert", "{log}", "{tmp}/no/o.csv"],
    ],
    ids=lambda argv: argv[0],
)
def test_real_subprocess_per_command(workdir, argv: list[str]) -> None:
    args = [a.format(**workdir) for a in argv]
    r = subprocess.run(
        [sys.executable, "-m", "imudiag", *args], capture_output=True, text=True, timeout=120
    )
    assert r.returncode == 2, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert "Traceback" not in r.stderr and r.stdout == ""


def test_types_convert_good_values(tmp_path: Path) -> None:
    assert positive_float("Hz")("200") == 200.0
    assert positive_float("s", above=0.05)("0.06") == 0.06
    assert nonnegative_float("s")("0") == 0.0
    assert finite_float("s")("-3.5") == -3.5
    assert positive_int("samples")("64") == 64
    assert seed("0") == 0 and seed(str(2**64 - 1)) == 2**64 - 1
    assert writable_output_path(stdout=True)("-") == "-"
    out = str(tmp_path / "new.json")
    assert writable_output_path()(out) == out
    nested = str(tmp_path / "a" / "b")
    assert writable_directory(nested) == nested  # made with its parents when written
    with pytest.raises(argparse.ArgumentTypeError, match="a directory, not a file"):
        writable_output_path()(str(tmp_path))
    with pytest.raises(argparse.ArgumentTypeError, match="does not exist"):
        writable_output_path(stdout=True)(str(tmp_path / "no" / "out.json"))
    with pytest.raises(argparse.ArgumentTypeError, match="must be > 0.05 s, got '0.05'"):
        positive_float("s", above=0.05)("0.05")


def _unwritable_directory(tmp_path: Path) -> Path | None:
    """A real directory this process cannot write: a read-only one (non-root), else a
    kernel directory root cannot create files in; None when there is none."""
    if os.geteuid() != 0:
        locked = tmp_path / "locked"
        locked.mkdir(mode=0o500)
        return locked
    proc_sys = Path("/proc/sys")
    if proc_sys.is_dir() and not os.access(proc_sys, os.W_OK):
        return proc_sys
    return None


def test_unwritable_directory_is_refused(tmp_path: Path) -> None:
    directory = _unwritable_directory(tmp_path)
    if directory is None:
        pytest.skip("no directory this process cannot write")
    try:
        with pytest.raises(argparse.ArgumentTypeError, match="is not writable"):
            writable_output_path()(str(directory / "out.csv"))
        # in process: test_real_subprocess_per_command refuses an --out in a real subprocess
        r = run_imudiag_in_process(
            "simulate", "static", "--duration", "1", "--out", str(directory / "out.csv")
        )
        assert r.returncode == 2, r.stderr
        assert "argument --out: cannot write" in r.stderr and "is not writable" in r.stderr
        assert len(r.stderr.strip().splitlines()) == 1
    finally:
        if directory.is_relative_to(tmp_path):
            directory.chmod(0o700)

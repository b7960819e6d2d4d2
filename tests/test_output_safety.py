"""Issue 11 item 5: never lose a file, never look done when not done. Real commands as
subprocesses, real signals."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import PROJECT_DIR, run_imudiag, run_imudiag_in_process

from imudiag import atomic
from imudiag.errors import BadInput

REAL = Path(__file__).parent / "data" / "real"
LOG = REAL / "imucal-ferraris" / "session.csv.gz"


@pytest.mark.parametrize(
    "args",
    [
        ("diagnose", "{log}", "--json", "{log}"),
        ("allan", "{log}", "--json", "{log}"),
        ("model-check", "{log}", "--certificate", "{like}", "--json", "{log}"),
        ("calibrate", "{log}", "--like", "{like}", "--out", "{like}"),
        ("calibrate", "{log}", "--like", "{like}", "--out", "{alias}"),
        ("convert", "{log}", "{alias_log}"),
    ],
)
def test_an_output_never_overwrites_an_input(tmp_path, args):
    log = tmp_path / "session.csv.gz"
    log.write_bytes(LOG.read_bytes())
    like = tmp_path / "like.yaml"
    like.write_text((Path(__file__).parent / "data" / "diagnosis" / "like-imucal.yaml").read_text())
    alias = tmp_path / "sub" / ".." / "like.yaml"
    (tmp_path / "sub").mkdir()
    alias_log = tmp_path / "link.csv.gz"
    alias_log.symlink_to(log)
    before = {p: p.read_bytes() for p in (log, like)}
    fmt = {"log": log, "like": like, "alias": alias, "alias_log": alias_log}
    # one case as a real subprocess (the CLI is the contract), the others through the
    # command's entry point in this process: the refusal is cli.main's, the same output
    run = run_imudiag if args[0] == "diagnose" else run_imudiag_in_process
    r = run(*(a.format(**fmt) for a in args))
    assert r.returncode == 2, r.stderr
    assert "refusing to overwrite an input" in r.stderr or "is the input" in r.stderr
    assert r.stderr.count("\n") == 1 and "Traceback" not in r.stderr
    assert {p: p.read_bytes() for p in (log, like)} == before


def _start(*args: str) -> subprocess.Popen[str]:
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    return subprocess.Popen(
        [sys.executable, "-m", "imudiag", *args],
        cwd=PROJECT_DIR,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _wait_for_part(d: Path, proc: subprocess.Popen[str]) -> None:
    """Wait (on the event, bounded) until the command has begun writing its output."""
    deadline = time.monotonic() + 60.0
    while not any(p.name.endswith(".part") for p in d.iterdir()):
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "no partial output appeared"
        time.sleep(0.01)


@pytest.mark.realtime
@pytest.mark.parametrize("sig, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_a_signal_ends_a_command_with_its_code_and_no_partial_file(tmp_path, sig, code):
    out = tmp_path / "long.csv"
    proc = _start("simulate", "static", "--duration", "100000", "--out", str(out))
    _wait_for_part(tmp_path, proc)
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == code, err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert list(tmp_path.iterdir()) == []


# ---------------------------------------------------------------------------
# more cases: aliases, two outputs, atomic writes, signals mid-stream

CERT = PROJECT_DIR / "config" / "default-certificate.yaml"


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A short simulated multi-position session (CSV)."""
    d = tmp_path_factory.mktemp("session")
    log = d / "session.csv"
    r = run_imudiag("simulate", "multiposition", "--seed", "3", "--out", str(log))
    assert r.returncode == 0, r.stderr
    return log


def _copy(src: Path, dst: Path) -> Path:
    shutil.copyfile(src, dst)
    return dst


def _one_line(stderr: str) -> str:
    lines = [ln for ln in stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, stderr
    return lines[0]


# ---------------------------------------------------------------------------
# an output is never an input


def _refusals(d: Path, log: Path, cert: Path) -> list[tuple[list[str], Path]]:
    link = d / "link.csv"
    link.symlink_to(log)
    dotted = d / ".." / d.name / log.name
    return [
        (["diagnose", str(log), "--json", str(log)], log),
        (["diagnose", str(log), "--json", str(link)], log),
        (["diagnose", str(log), "--certificate", str(cert), "--json", str(cert)], cert),
        (["calibrate", str(log), "--like", str(cert), "--out", str(dotted)], log),
        (["calibrate", str(log), "--like", str(cert), "--out", str(cert)], cert),
        (
            [
                "calibrate",
                str(log),
                "--like",
                str(cert),
                "--out",
                str(d / "new.yaml"),
                "--json",
                str(log),
            ],
            log,
        ),
        (["allan", str(log), "--json", str(log)], log),
        (["model-check", str(log), "--certificate", str(cert), "--json", str(link)], log),
        (
            [
                "model-check",
                str(log),
                "--certificate",
                str(cert),
                "--json",
                str(d / "r.json"),
                "--extended-certificate",
                str(cert),
            ],
            cert,
        ),
        (["convert", str(log), str(link)], log),
        (["convert", str(link), str(log)], log),
        (["certificate", "export", str(cert), "--format", "imucal", "--out", str(cert)], cert),
        (
            [
                "certificate",
                "import",
                str(log),
                "--format",
                "kalibr",
                "--like",
                str(cert),
                "--out",
                str(cert),
            ],
            cert,
        ),
        (
            [
                "simulate",
                "static",
                "--duration",
                "1",
                "--certificate",
                str(cert),
                "--out",
                str(cert),
            ],
            cert,
        ),
    ]


def test_every_command_refuses_an_output_that_is_an_input(session: Path, tmp_path: Path):
    log = _copy(session, tmp_path / "session.csv")
    cert = _copy(CERT, tmp_path / "cert.yaml")
    before = {p: p.read_bytes() for p in (log, cert)}
    for i, (argv, victim) in enumerate(_refusals(tmp_path, log, cert)):
        # the first as a real subprocess, the others in this process (the refusal is
        # cli.main's, before any command runs: the same exit status and line)
        r = (run_imudiag if i == 0 else run_imudiag_in_process)(*argv)
        assert r.returncode == 2, (argv, r.stderr)
        line = _one_line(r.stderr)
        assert "input" in line and "refusing" in line, line
        assert victim.read_bytes() == before[victim], argv
    assert atomic.leftovers(tmp_path) == []
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cert.yaml", "link.csv", "session.csv"]


def test_two_outputs_naming_one_file_are_refused(session: Path, tmp_path: Path):
    out = tmp_path / "x.yaml"
    # in process: test_every_command_refuses_an_output_that_is_an_input refuses in a subprocess
    r = run_imudiag_in_process(
        "calibrate", str(session), "--like", str(CERT), "--out", str(out), "--json", str(out)
    )
    assert r.returncode == 2
    assert "name the same file" in _one_line(r.stderr)
    assert not out.exists()


# ---------------------------------------------------------------------------
# atomic writes


def test_atomic_write_replaces_whole_or_not_at_all(tmp_path: Path):
    dest = tmp_path / "report.json"
    dest.write_text("old\n")
    with pytest.raises(RuntimeError), atomic.atomic_open(dest) as fh:
        fh.write("half a rep")
        assert len(atomic.leftovers(tmp_path)) == 1
        raise RuntimeError("cut short")
    assert dest.read_text() == "old\n"
    assert atomic.leftovers(tmp_path) == []
    atomic.write_text_atomic(dest, "new\n")
    assert dest.read_text() == "new\n"
    assert atomic.leftovers(tmp_path) == []
    # the file gets the mode a plain open() would give it, not mkstemp's 0600
    umask = os.umask(0)
    os.umask(umask)
    assert dest.stat().st_mode & 0o777 == 0o666 & ~umask


def test_temporary_names_are_unique(tmp_path: Path):
    dest = tmp_path / "log.csv"
    a, b = atomic.temp_path(dest), atomic.temp_path(dest)
    try:
        assert a != b and Path(a).parent == Path(b).parent == tmp_path
    finally:
        atomic.discard(a)
        atomic.discard(b)
    assert atomic.leftovers(tmp_path) == []


def test_unwritable_output_is_bad_input(tmp_path: Path):
    with (
        pytest.raises(BadInput, match="no-such-dir"),
        atomic.atomic_open(tmp_path / "no-such-dir" / "r.json"),
    ):
        pass


def test_report_into_a_missing_directory_exits_2(session: Path, tmp_path: Path):
    # in process, as test_two_outputs_naming_one_file_are_refused
    r = run_imudiag_in_process("allan", str(session), "--json", str(tmp_path / "nodir" / "a.json"))
    assert r.returncode == 2
    assert "cannot write" in _one_line(r.stderr)


# ---------------------------------------------------------------------------
# signals


def _wait_for(proc: subprocess.Popen[str], cond, what: str, timeout_s: float = 60.0) -> None:
    """Poll ``cond`` (a file-system event) until true; fail if the process ended first."""
    end = time.monotonic() + timeout_s
    while not cond():
        if proc.poll() is not None:
            out, err = proc.communicate()
            pytest.fail(f"command ended (rc {proc.returncode}) before {what}: {err}")
        if time.monotonic() > end:
            proc.kill()
            pytest.fail(f"no {what} within {timeout_s} s")
        time.sleep(0.01)


SIGNALS = [(signal.SIGINT, 130, "interrupted"), (signal.SIGTERM, 143, "terminated")]


@pytest.mark.realtime
@pytest.mark.parametrize(("sig", "code", "word"), SIGNALS)
def test_simulate_stopped_leaves_old_output_and_no_temporary(tmp_path: Path, sig, code, word):
    out = tmp_path / "long.csv"
    out.write_text("previous\n")
    proc = _start("simulate", "static", "--duration", "1e6", "--out", str(out))
    _wait_for(proc, lambda: atomic.leftovers(tmp_path), "temporary output file")
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == code, err
    assert word in _one_line(err)
    assert atomic.leftovers(tmp_path) == []
    assert out.read_text() == "previous\n"


@pytest.fixture(scope="module")
def long_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """1000 s at 200 Hz as a wire capture: seconds of work for convert and diagnose."""
    log = tmp_path_factory.mktemp("long") / "long.bin"
    r = run_imudiag("simulate", "static", "--duration", "1000", "--out", str(log))
    assert r.returncode == 0, r.stderr
    return log


def _has_open(proc: subprocess.Popen[str], path: Path) -> bool:
    """Whether the process has ``path`` open (Linux /proc): it is reading the log."""
    fd_dir = Path(f"/proc/{proc.pid}/fd")
    try:
        links = [os.readlink(fd_dir / fd) for fd in os.listdir(fd_dir)]
    except OSError:  # an fd closed while listing
        return False
    return str(path.resolve()) in links


@pytest.mark.realtime
@pytest.mark.parametrize(("sig", "code", "word"), SIGNALS)
def test_convert_stopped_mid_stream(long_log: Path, tmp_path: Path, sig, code, word):
    out = tmp_path / "out.csv"
    proc = _start("convert", str(long_log), str(out))
    _wait_for(proc, lambda: atomic.leftovers(tmp_path), "temporary output file")
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == code, err
    assert word in _one_line(err)
    assert atomic.leftovers(tmp_path) == []
    assert not out.exists()


@pytest.mark.realtime
@pytest.mark.skipif(not Path("/proc/self/fd").is_dir(), reason="needs Linux /proc")
@pytest.mark.parametrize(("sig", "code", "word"), SIGNALS)
def test_diagnose_stopped_writes_no_report(long_log: Path, tmp_path: Path, sig, code, word):
    report = tmp_path / "report.json"
    report.write_text("previous\n")
    proc = _start("diagnose", str(long_log), "--json", str(report))
    _wait_for(proc, lambda: _has_open(proc, long_log), "log opened")
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == code, err
    assert word in _one_line(err)
    assert report.read_text() == "previous\n"
    assert atomic.leftovers(tmp_path) == []


def test_a_signal_while_the_temporary_is_made_leaves_nothing(tmp_path: Path, monkeypatch):
    """Ctrl-C arriving right after the temporary file is created (the moment a test that
    waits for the first .part file sends its signal; in a process with threads the Python
    handler may run there whatever the main thread's signal mask) leaves nothing once the
    exit clean-up has run: the name is registered before the file exists."""
    real_open = os.open

    def open_then_ctrl_c(*args, **kwargs):
        fd = real_open(*args, **kwargs)
        os.close(fd)
        raise KeyboardInterrupt  # what the SIGINT handler raises at the next bytecode

    monkeypatch.setattr(atomic.os, "open", open_then_ctrl_c)
    with pytest.raises(KeyboardInterrupt):
        atomic.temp_path(tmp_path / "out.csv")
    monkeypatch.undo()
    atomic._remove_leftovers()  # what the interpreter runs at exit
    assert list(tmp_path.iterdir()) == []


def test_a_temporary_gets_the_mode_of_a_new_file(tmp_path: Path):
    """Not mkstemp's 0600: the mode open(path, "w") would give under the umask."""
    mask = os.umask(0o022)
    try:
        tmp = atomic.temp_path(tmp_path / "out.csv")
        assert os.stat(tmp).st_mode & 0o777 == 0o644
    finally:
        os.umask(mask)
    atomic.discard(tmp)

"""The progress bar of the long commands (diagnose, calibrate, model-check, simulate,
convert): drawn on standard error when it is a terminal (a real pseudo-terminal here),
never into a pipe, never with --quiet; and the fraction the log readers report."""

from __future__ import annotations

import io
import os
import subprocess
import sys
import threading
from pathlib import Path

import pytest
from conftest import PROJECT_DIR, run_imudiag

from imudiag.logs import open_log
from imudiag.progress import Progress

CERT = "config/default-certificate.yaml"


def run_on_pty(*args: str) -> tuple[int, bytes, str]:
    """Run ``imudiag ARGS`` with a pseudo-terminal as its standard error (standard output a
    pipe); returns the exit code, what the terminal received and standard output."""
    master, slave = os.openpty()
    proc = subprocess.Popen(
        [sys.executable, "-m", "imudiag", *args],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=slave,
        cwd=PROJECT_DIR,
    )
    os.close(slave)
    got = bytearray()

    def drain() -> None:  # the terminal's buffer is small: read while the command runs
        while True:
            try:
                data = os.read(master, 4096)
            except OSError:  # EIO: the command closed its end
                return
            if not data:
                return
            got.extend(data)

    reader = threading.Thread(target=drain)
    reader.start()
    out, _ = proc.communicate(timeout=300)
    reader.join(timeout=60)
    os.close(master)
    return proc.returncode, bytes(got), out.decode()


@pytest.fixture(scope="module")
def session(tmp_path_factory) -> Path:
    """A short simulated multi-position session (seed 4), written by the real command."""
    d = tmp_path_factory.mktemp("progress")
    log = d / "multiposition.csv"
    res = run_imudiag(
        "simulate", "multiposition", "--duration", "45", "--seed", "4", "--param", "n=10",
        "--out", str(log), "--quiet",
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    return log


def assert_bar(term: bytes, command: str) -> None:
    text = term.decode()
    assert f"\rimudiag {command}: " in text, text[:300]
    assert "%" in text and "[" in text and "#" in text
    # cleared at the end: after the last bar, blanks over it and the cursor back home, so
    # whatever follows (a warning) starts on a clean line (the terminal shows \n as \r\n)
    last = text.rfind(f"\rimudiag {command}: ")
    parts = text[last + 1 :].split("\r")
    assert len(parts) >= 3 and parts[1].strip() == "" and len(parts[1]) >= len(parts[0])
    assert "%" not in "\r".join(parts[2:]), repr(text[-200:])


@pytest.mark.realtime
@pytest.mark.parametrize(
    "command",
    ["simulate", "convert", "diagnose", "calibrate", "model-check"],
)
def test_bar_on_a_terminal(command, session, tmp_path):
    args = {
        "simulate": (
            "simulate",
            "multiposition",
            "--duration",
            "20",
            "--seed",
            "5",
            "--out",
            str(tmp_path / "s.npz"),
        ),  # fmt: skip
        "convert": ("convert", str(session), str(tmp_path / "c.csv.gz"), "--block-size", "2000"),
        "diagnose": ("diagnose", str(session), "-c", CERT, "--block-size", "2000"),
        "calibrate": (
            "calibrate",
            str(session),
            "--like",
            CERT,
            "--out",
            str(tmp_path / "x.yaml"),
            "--force",
            "--block-size",
            "2000",
        ),  # fmt: skip
        "model-check": (
            "model-check",
            str(session),
            "--certificate",
            CERT,
            "--json",
            str(tmp_path / "mc.json"),
        ),  # fmt: skip
    }[command]
    code, term, out = run_on_pty(*args)
    assert code == 0, term.decode()
    assert_bar(term, command)
    assert "\r" not in out and "[#" not in out  # standard output carries none of it


@pytest.mark.realtime
def test_phases_of_the_diagnosis_are_named(session, tmp_path):
    """``diagnose`` reads its log once (the noise measured along the pass): one phase;
    ``calibrate`` measures the noise first, then collects the intervals: two, in order."""
    code, term, _ = run_on_pty("diagnose", str(session), "-c", CERT, "--block-size", "1000")
    assert code == 0
    text = term.decode()
    assert "diagnosing [" in text and "measuring noise [" not in text
    out = str(tmp_path / "x.yaml")
    code, term, _ = run_on_pty(
        "calibrate", str(session), "--like", CERT, "--out", out, "--force", "--block-size", "1000"
    )  # fmt: skip
    assert code == 0, term.decode()
    text = term.decode()
    assert "measuring noise [" in text and "collecting intervals [" in text
    assert text.index("measuring noise [") < text.index("collecting intervals [")


@pytest.mark.realtime
@pytest.mark.parametrize("command", ["diagnose", "simulate", "convert"])
def test_quiet_on_a_terminal_draws_nothing(command, session, tmp_path):
    args = {
        "diagnose": ("diagnose", str(session), "-c", CERT, "--json", str(tmp_path / "r.json")),
        "simulate": (
            "simulate",
            "multiposition",
            "--duration",
            "10",
            "--out",
            str(tmp_path / "s.csv"),
        ),  # fmt: skip
        "convert": ("convert", str(session), str(tmp_path / "c.npz")),
    }[command]
    code, term, _ = run_on_pty(*args, "--quiet")
    assert code == 0
    assert term == b""


def test_nothing_into_a_pipe(session, tmp_path):
    for args in (
        ("diagnose", str(session), "-c", CERT, "--block-size", "1000"),
        ("convert", str(session), str(tmp_path / "c.bin"), "--block-size", "1000"),
    ):
        res = run_imudiag(*args)
        assert res.returncode == 0, res.stderr
        assert "\r" not in res.stderr and "%" not in res.stderr and "[#" not in res.stderr


@pytest.mark.realtime
def test_error_clears_the_bar_then_one_line(session, tmp_path):
    """A bad sample half-way: the bar is cleared and the error starts its own line."""
    lines = session.read_text().splitlines()
    bad = list(lines)
    k = next(i for i in range(len(bad) // 2, len(bad)) if not bad[i].startswith("#"))
    bad[k] = bad[k].split(",", 1)[0] + ",oops" + "," + bad[k].split(",", 2)[2]
    path = tmp_path / "bad.csv"
    path.write_text("\n".join(bad) + "\n")
    code, term, _ = run_on_pty("convert", str(path), str(tmp_path / "o.npz"), "--block-size", "500")
    assert code == 2
    text = term.decode()
    assert "imudiag convert: error:" in text
    before, _, after = text.partition("imudiag convert: error:")
    assert before.endswith("\r") and before.rsplit("\r", 2)[-2].strip() == ""
    assert after.count("\n") == 1


# -- the module itself, on an in-memory stream told it is a terminal ----------------------


def test_rate_limited_and_cleared():
    s = io.StringIO()
    bar = Progress("diagnose", stream=s, enabled=True, min_redraw_s=3600.0)
    for i in range(1, 1001):
        bar.update("diagnosing", i / 1000, i * 100)
    assert bar.redraws == 1  # the first at once, then none within the hour
    bar.close()
    text = s.getvalue()
    assert text.startswith("\rimudiag diagnose: diagnosing [")
    assert text.endswith("\r") and text.rsplit("\r", 2)[-2].strip() == ""


def test_each_phase_is_drawn_at_once_however_fast():
    """A new phase is drawn at its first update even within the redraw interval, so a phase
    shorter than the interval is still named (a fast machine ran diagnose's 'diagnosing'
    within 0.1 s of 'measuring noise' and the line never named it)."""
    s = io.StringIO()
    bar = Progress("diagnose", stream=s, enabled=True, min_redraw_s=3600.0)
    for i in range(1, 101):
        bar.update("measuring noise", i / 100, i)
    for i in range(1, 101):
        bar.update("diagnosing", i / 100, i)
    bar.update("measuring noise", 1.0, 100)  # back to a phase: a change again
    assert bar.redraws == 3
    lines = [x for x in s.getvalue().split("\r") if x.strip()]
    assert [x.split("[")[0].strip() for x in lines] == [
        "imudiag diagnose: measuring noise",
        "imudiag diagnose: diagnosing",
        "imudiag diagnose: measuring noise",
    ]


def test_bar_fraction_and_unknown_fraction():
    s = io.StringIO()
    bar = Progress("convert", stream=s, enabled=True, min_redraw_s=0.0)
    bar.update("converting", 0.5, 1_234_567)
    assert "50%" in s.getvalue() and "1.23M samples" in s.getvalue()
    bar.update("converting", None, 2500)
    last = s.getvalue().rsplit("\r", 1)[1]
    assert last.rstrip() == "imudiag convert: converting ... 2.5k samples"
    assert len(last) == len(s.getvalue().split("\r")[1])  # blanks over the longer line


def test_disabled_and_not_a_terminal_write_nothing():
    s = io.StringIO()  # isatty() is False
    bar = Progress("simulate", stream=s)
    bar.update("simulating", 0.3, 10)
    bar.close()
    quiet = Progress("simulate", stream=s, enabled=False)
    quiet.update("simulating", 0.3, 10)
    quiet.close()
    assert s.getvalue() == "" and not bar.enabled


@pytest.mark.parametrize("suffix", [".csv", ".csv.gz", ".npz", ".bin"])
def test_readers_report_the_fraction_read(suffix, session, tmp_path):
    log = tmp_path / f"log{suffix}"
    res = run_imudiag("convert", str(session), str(log), "--quiet")
    assert res.returncode == 0, res.stderr
    seen = []
    with open_log(log, block_size=700) as reader:
        assert reader.fraction_read() in (None, 0.0) or reader.fraction_read() < 0.1
        for _block in reader:
            seen.append(reader.fraction_read())
    assert all(f is not None for f in seen), seen
    assert seen == sorted(seen) and seen[-1] == pytest.approx(1.0, abs=0.02)
    assert len(set(seen)) >= 3  # it moves as the blocks come, not all at once
    if suffix != ".csv.gz":  # (a .gz's position leads by the decompressor's read-ahead)
        assert seen[0] < 0.2

"""Issue 11 item 5: never lose a file, never look done when not done. Real commands as
subprocesses, real signals."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import PROJECT_DIR, run_imudiag

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
    r = run_imudiag(*(a.format(**fmt) for a in args))
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

"""Issue 12 items 5-6: every scheme refuses a misspelt query key; a replay at full speed
writes a status line per second of sample time and one at once on each change."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from imudiag.drivers.base import SourceError, open_source

REAL = Path(__file__).parent / "data" / "real"


@pytest.mark.parametrize(
    "url, key",
    [
        ("replay://log.csv?sped=0", "sped"),
        ("serial:///dev/ttyACM0?baudrate=9600", "baudrate"),
        ("loop://?bud=9600", "bud"),
        ("socket://localhost:7777?timeout=1", "timeout"),
        ("usb://1234:5678?iface=1", "iface"),
        ("hid://1234:5678?serail=A1", "serail"),
        ("sim://static?sed=3", "sed"),
    ],
)
def test_every_scheme_refuses_an_unknown_query_key(url, key):
    with pytest.raises(SourceError, match=repr(key)):
        open_source(url)


def test_known_keys_are_accepted():
    for url in (
        "replay://log.csv?speed=0&step=0.1",
        "serial:///dev/x?baud=9600&exclusive=1",
        "usb://1234:5678?interface=0&serial=A",
        "hid://1234:5678?serial=A",
    ):
        open_source(url)  # made, not opened


def test_run_refuses_a_misspelt_key_with_exit_2(imudiag_cli):
    log = REAL / "imucal-ferraris" / "session.csv.gz"
    r = imudiag_cli("run", "--source", f"replay://{log}?sped=0")
    assert r.returncode == 2
    assert "'sped'" in r.stderr and "Traceback" not in r.stderr


@pytest.mark.realtime
def test_full_speed_replay_writes_a_line_per_second_of_sample_time(imudiag_cli):
    log = REAL / "imucal-ferraris" / "session.csv.gz"
    # its certificate (deg/s and m/s^2): the bundled one is in counts, which the daemon
    # refuses for this log as diagnose does (issue 25)
    like = REAL.parent / "diagnosis" / "like-imucal.yaml"
    r = imudiag_cli(
        "run", "--source", f"replay://{log}?speed=0", "--certificate", str(like), "--no-diagnosis"
    )
    assert r.returncode == 0, r.stderr
    lines = [json.loads(x) for x in r.stdout.splitlines() if x.startswith("{")]
    ts = [s["t"] for s in lines if s["t"] is not None]
    duration = ts[-1] - ts[0]
    assert duration > 100
    # one per second of data (plus one per change), never a handful for the whole log
    assert (
        duration - 2
        <= len(ts)
        <= duration
        + 2
        + 2 * sum(a["state"] != b["state"] for a, b in zip(lines, lines[1:], strict=False))
    )
    gaps = [b - a for a, b in zip(ts, ts[1:], strict=False)]
    assert max(gaps) <= 1.1

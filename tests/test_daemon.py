"""The daemon as a real subprocess fed by the simulated board over a real pty.

F0 flags a gross accelerometer fault, status lines parse, SIGHUP reloads the
certificate (a bad one is refused and the old one kept), SIGTERM and SIGINT
stop with exit 0, a stalled stream turns into no_data.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from imudiag.bench.daemon_process import DaemonProcess
from imudiag.bench.pty import BoardWriter, PtyPair
from imudiag.certificate import load_default
from imudiag.sim.board import SimulatedBoard
from imudiag.sim.faults import Fault
from imudiag.sim.scenarios import scenario_motion

pytestmark = pytest.mark.realtime  # tests/conftest.py: the two tiers

FAULT_T_S = 4.0  #: sample time of the injected accelerometer fault, s
FAULT_COUNTS = 800.0  #: az bias step, counts (about 1.9 m/s^2: a gross fault)
SPEED = 4.0  #: board pace relative to real time


@pytest.fixture
def board_pty():
    """A pty whose master side is fed by the simulated board with a gross az bias fault."""
    cert = load_default()
    board = SimulatedBoard(
        cert,
        scenario_motion("static", seed=3),
        seed=3,
        faults=[Fault("bias", "az", FAULT_T_S, FAULT_COUNTS)],
        duration_s=120.0,
    )
    chunk_s = 0.05
    with PtyPair() as pair:
        writer = BoardWriter(pair, board.iter_bytes(chunk_s), rate_hz=SPEED / chunk_s)
        writer.start()
        yield pair, writer
        writer.stop()


def _has_accel_f0(status: dict) -> bool:
    return any(f["triad"] == "accel" and f["cause"] == "f0" for f in status["faults"])


def test_daemon_flags_gross_accel_fault_and_obeys_signals(board_pty, tmp_path: Path):
    pair, _writer = board_pty
    cert_path = tmp_path / "cert.yaml"
    cert = load_default()
    cert.save(cert_path)
    d = DaemonProcess(
        [
            "--source",
            f"serial://{pair.slave_path}",
            "--certificate",
            str(cert_path),
            "--no-diagnosis",
        ]
    )
    try:
        first = d.wait_for(lambda s: s["t"] is not None and s["static"])
        assert set(first) >= {"t", "state", "faults", "counters"}
        assert set(first["counters"]) == {
            "bytes",
            "frames",
            "crc_errors",
            "skipped_bytes",
            "lost",
            "duplicates",
        }
        healthy = d.wait_for(lambda s: s["t"] is not None and s["t"] >= 2.0)
        assert healthy["state"] == "ok" and healthy["faults"] == []
        assert healthy["f0"]["accel"]["checked"] > 0

        faulty = d.wait_for(_has_accel_f0)
        assert faulty["state"] == "fault"
        assert FAULT_T_S <= faulty["t"] < FAULT_T_S + 2.0  # detected within 2 s of sample time
        # nothing fired before the fault time
        assert all(not s["faults"] for s in d.all if s["t"] is not None and s["t"] < FAULT_T_S)

        # a bad certificate on SIGHUP is refused; the old one stays in force
        cert_path.write_text(
            cert_path.read_text().replace("scale_factor: [416.8", "scale_factor: [-416.8")
        )
        d.proc.send_signal(signal.SIGHUP)
        refused = d.wait_for(lambda s: "notes" in s)
        assert "keeping the previous one" in refused["notes"][0]
        assert "accel.scale_factor[0]" in refused["notes"][0]
        assert refused["certificate"]["reloads"] == 0
        assert _has_accel_f0(refused)

        # a certificate that knows the new az bias explains the data: the fault clears
        fixed = load_default()
        fixed.accel.bias[2] += FAULT_COUNTS
        fixed.save(cert_path)
        d.proc.send_signal(signal.SIGHUP)
        cleared = d.wait_for(lambda s: s["certificate"]["reloads"] == 1 and not s["faults"])
        assert cleared["state"] == "ok" and "notes" not in cleared

        assert d.stop(signal.SIGTERM) == 0
    finally:
        if d.proc.poll() is None:
            d.proc.kill()


def test_daemon_reports_no_data_when_stream_stalls_and_exits_on_sigint(board_pty):
    pair, writer = board_pty
    d = DaemonProcess(
        ["--source", f"serial://{pair.slave_path}", "--no-diagnosis", "--no-data-timeout", "0.5"]
    )
    try:
        d.wait_for(lambda s: s["state"] == "ok" and s["t"] is not None)
        writer.stop()  # the board goes silent but stays plugged in
        stalled = d.wait_for(lambda s: s["state"] == "no_data", timeout_s=10)
        # a loaded machine may still deliver a backlog after a first no_data: wait until
        # the frame count stands still, then the steady lines must keep saying no_data
        for _ in range(10):
            again = d.wait_for(lambda s: True, timeout_s=5)
            if again["counters"]["frames"] == stalled["counters"]["frames"]:
                break
            stalled = again
        assert stalled["counters"]["frames"] > 0
        assert again["state"] == "no_data"
        assert again["counters"]["frames"] == stalled["counters"]["frames"]
        assert d.stop(signal.SIGINT) == 0
    finally:
        if d.proc.poll() is None:
            d.proc.kill()


def test_daemon_bad_source_is_bad_input():
    proc = subprocess.run(
        [sys.executable, "-m", "imudiag", "run", "--source", "nosuch://x"],
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert proc.returncode == 2
    assert "nosuch" in proc.stderr


def test_daemon_speaks_sd_notify_and_pings_watchdog_only_while_frames_flow(board_pty, tmp_path):
    import os
    import socket

    pair, writer = board_pty
    sock_path = tmp_path / "notify.sock"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(sock_path))
    sock.settimeout(0.2)
    env = dict(os.environ, NOTIFY_SOCKET=str(sock_path), WATCHDOG_USEC="400000")
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "imudiag",
            "run",
            "--source",
            f"serial://{pair.slave_path}",
            "--no-diagnosis",
            "--no-data-timeout",
            "0.5",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        env=env,
    )
    got: list[tuple[float, str]] = []

    def collect(seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            try:
                got.append((time.monotonic(), sock.recv(4096).decode()))
            except TimeoutError:
                pass

    def fields() -> list[str]:
        return [f for _, msg in got for f in msg.split("\n")]

    try:
        # wait on the events (READY, then pings while frames arrive), not on a wall-clock
        # budget that interpreter start-up on a loaded machine can eat
        deadline = time.monotonic() + 60.0
        while sum(f == "WATCHDOG=1" for f in fields()) < 5:
            assert proc.poll() is None, proc.stderr.read().decode() if proc.stderr else ""
            assert time.monotonic() < deadline, f"fewer than 5 watchdog pings: {fields()}"
            collect(0.2)
        assert "READY=1" in fields()
        assert fields().index("READY=1") < fields().index("WATCHDOG=1")
        writer.stop()
        deadline = time.monotonic() + 10.0
        while not any("STATUS=no_data" in msg for _, msg in got):
            assert time.monotonic() < deadline, "daemon never reported no_data"
            collect(0.2)
        got.clear()
        collect(1.5)
        starved = [f for _, msg in got for f in msg.split("\n")]
        assert "WATCHDOG=1" not in starved  # systemd would restart a daemon that gets no frames
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(10) == 0
        collect(0.5)
        assert any("STOPPING=1" in msg for _, msg in got)
    finally:
        if proc.poll() is None:
            proc.kill()
        sock.close()


def test_daemon_writes_nmea_status_to_a_serial_link(board_pty):
    import os
    import select

    from imudiag.service.nmea import decode_sentence, split_sentences

    pair, _writer = board_pty
    with PtyPair() as link:  # the status link: the daemon writes the slave, we read the master
        d = DaemonProcess(
            [
                "--source",
                f"serial://{pair.slave_path}",
                "--no-diagnosis",
                "--status",
                "-",
                "--status",
                f"serial://{link.slave_path}?baud=115200",
            ]
        )
        try:
            buf, sentences = b"", []
            deadline = time.monotonic() + 20
            while len([s for s in sentences if s["type"] == "health"]) < 3:
                assert time.monotonic() < deadline, f"no NMEA health sentences: {sentences}"
                r, _, _ = select.select([link.master_fd], [], [], 0.2)
                if r:
                    buf += os.read(link.master_fd, 4096)
                    lines, buf = split_sentences(buf)
                    sentences += [decode_sentence(x) for x in lines]  # checksums verified
            assert {"health", "counters"} <= {s["type"] for s in sentences}
            health = [s for s in sentences if s["type"] == "health"]
            assert health[0]["state"] in ("ok", "no_data")
            # the board's az fault (t = 4 s) reaches the serial link too, as a fault sentence
            deadline = time.monotonic() + 20
            while not any(s["type"] == "fault" for s in sentences):
                assert time.monotonic() < deadline, "no NMEA fault sentence"
                r, _, _ = select.select([link.master_fd], [], [], 0.2)
                if r:
                    buf += os.read(link.master_fd, 4096)
                    lines, buf = split_sentences(buf)
                    sentences += [decode_sentence(x) for x in lines]
            fault = next(s for s in sentences if s["type"] == "fault")
            assert (fault["triad"], fault["cause"]) == ("accel", "f0")
            d.wait_for(lambda s: s["t"] is not None)  # stdout JSON goes on alongside
            assert d.stop() == 0
        finally:
            if d.proc.poll() is None:
                d.proc.kill()

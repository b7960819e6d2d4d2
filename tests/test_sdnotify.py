"""sd_notify against a real Unix datagram socket acting as systemd's notify socket."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import uuid
from collections.abc import Iterator

import pytest

from imudiag.service.sdnotify import Notifier, WatchdogGate

WATCHDOG_USEC = 10_000_000  # 10 s, as WatchdogSec=10s in systemd/imudiag.service


class NotifySocket:
    """A bound AF_UNIX datagram socket and the NOTIFY_SOCKET value naming it."""

    def __init__(self, sock: socket.socket, name: str) -> None:
        self.sock = sock
        self.name = name

    def recv(self, timeout_s: float = 2.0) -> str:
        self.sock.settimeout(timeout_s)
        return self.sock.recv(4096).decode()

    def drain(self) -> list[str]:
        """Every datagram queued right now."""
        self.sock.setblocking(False)
        out = []
        while True:
            try:
                out.append(self.sock.recv(4096).decode())
            except BlockingIOError:
                return out

    def env(self, **extra: str) -> dict[str, str]:
        return {"NOTIFY_SOCKET": self.name, **extra}


@pytest.fixture(params=["path", "abstract"])
def notify_socket(request: pytest.FixtureRequest, tmp_path) -> Iterator[NotifySocket]:
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    if request.param == "path":
        name = str(tmp_path / "notify.sock")
        sock.bind(name)
    else:
        name = f"@imudiag-test-{os.getpid()}-{uuid.uuid4().hex[:8]}"
        sock.bind("\0" + name[1:])
    try:
        yield NotifySocket(sock, name)
    finally:
        sock.close()


def test_ready_status_stopping(notify_socket: NotifySocket) -> None:
    n = Notifier.from_env(notify_socket.env())
    assert n.enabled and not n.watchdog_enabled
    assert n.ready()
    assert notify_socket.recv() == "READY=1"
    assert n.ready("running on sim://")
    assert notify_socket.recv() == "READY=1\nSTATUS=running on sim://"
    assert n.status("state fault\naccel ax bias")  # a newline would split the field
    assert notify_socket.recv() == "STATUS=state fault accel ax bias"
    assert n.reloading()
    assert notify_socket.recv() == "RELOADING=1"
    assert n.stopping()
    assert notify_socket.recv() == "STOPPING=1"
    assert n.sent == 5 and n.failures == 0
    n.close()


def test_no_socket_is_a_no_op() -> None:
    n = Notifier.from_env({"WATCHDOG_USEC": str(WATCHDOG_USEC)})
    assert not n.enabled and not n.watchdog_enabled
    assert n.watchdog_interval_s is None
    assert not n.ready() and not n.watchdog() and not n.stopping()
    gate = WatchdogGate(n)
    gate.frames_arrived(0.0)
    assert not gate.tick(100.0) and gate.pings == 0


def test_vanished_socket_never_raises(tmp_path) -> None:
    n = Notifier(str(tmp_path / "gone.sock"))
    assert not n.ready()
    assert not n.status("x")
    assert n.failures == 2 and n.sent == 0


def test_watchdog_interval_is_half_of_watchdog_usec(notify_socket: NotifySocket) -> None:
    n = Notifier.from_env(notify_socket.env(WATCHDOG_USEC=str(WATCHDOG_USEC)))
    assert n.watchdog_enabled
    assert n.watchdog_interval_s == pytest.approx(5.0)
    assert n.watchdog()
    assert notify_socket.recv() == "WATCHDOG=1"


def test_full_receive_queue_never_blocks(notify_socket: NotifySocket) -> None:
    """Nobody reads the notify socket: sends fail fast, a ping is retried on the next tick."""
    n = Notifier.from_env(notify_socket.env(WATCHDOG_USEC=str(WATCHDOG_USEC)))
    sent = [n.status(f"line {i}") for i in range(200)]  # far beyond any datagram queue
    assert sent[0] and not sent[-1]
    assert n.failures == sent.count(False) > 0
    gate = WatchdogGate(n)
    gate.frames_arrived(0.0)
    assert not gate.tick(0.0) and gate.pings == 0 and not gate.starved  # not sent, kept due
    queued = notify_socket.drain()
    assert len(queued) == n.sent and queued[0] == "STATUS=line 0"
    assert gate.tick(0.125) and gate.pings == 1  # retried as soon as there is room
    assert notify_socket.recv() == "WATCHDOG=1"


@pytest.mark.parametrize("usec", ["", "0", "ten", "-5"])
def test_bad_or_zero_watchdog_usec_disables_watchdog(usec: str, notify_socket: NotifySocket):
    n = Notifier.from_env(notify_socket.env(WATCHDOG_USEC=usec))
    assert n.enabled and not n.watchdog_enabled
    assert not n.watchdog()
    assert notify_socket.drain() == []


def _run_clock(
    gate: WatchdogGate, t_end_s: float, step_s: float, frames, sock: NotifySocket | None = None
) -> list[float]:
    """Tick the gate on a simulated clock; ``frames(t)`` says whether frames arrived.

    With ``sock``, every datagram is read as it arrives (as systemd does) and
    must be exactly one WATCHDOG=1 per reported ping.
    """
    pings = []
    n_steps = round(t_end_s / step_s)
    for i in range(n_steps + 1):
        t = i * step_s
        if frames(t):
            gate.frames_arrived(t)
        if gate.tick(t):
            pings.append(t)
        if sock is not None:
            got = sock.drain()
            assert got == (["WATCHDOG=1"] if pings and pings[-1] == t else []), (t, got)
    return pings


def test_watchdog_cadence_while_frames_flow(notify_socket: NotifySocket) -> None:
    n = Notifier.from_env(notify_socket.env(WATCHDOG_USEC=str(WATCHDOG_USEC)))
    gate = WatchdogGate(n)
    pings = _run_clock(gate, 60.0, 0.125, lambda t: True, notify_socket)  # binary-exact steps
    assert gate.pings == len(pings)
    assert pings == [5.0 * k for k in range(13)]  # t = 0, 5, ..., 60 s: half of 10 s


def test_watchdog_cadence_with_slow_frames(notify_socket: NotifySocket) -> None:
    """Frames every 7 s: each ping follows fresh frames, gaps stay under the 10 s timeout."""
    n = Notifier.from_env(notify_socket.env(WATCHDOG_USEC=str(WATCHDOG_USEC)))
    gate = WatchdogGate(n)
    pings = _run_clock(gate, 30.0, 0.0625, lambda t: t % 7.0 == 0.0, notify_socket)
    assert pings == [0.0, 7.0, 14.0, 21.0, 28.0]


def test_no_pings_while_starved(notify_socket: NotifySocket) -> None:
    """Frames flow for 20 s, stop for 30 s, resume: the watchdog starves in between."""
    n = Notifier.from_env(notify_socket.env(WATCHDOG_USEC=str(WATCHDOG_USEC)))
    gate = WatchdogGate(n)

    def frames(t: float) -> bool:
        return t < 20.0 or t >= 50.0

    pings = _run_clock(gate, 70.0, 0.125, frames, notify_socket)
    # the ping at 20 s vouches for the frames of 15..19.875 s; then nothing until they resume
    assert pings == [0.0, 5.0, 10.0, 15.0, 20.0, 50.0, 55.0, 60.0, 65.0, 70.0]
    assert gate.last_frames_s == 70.0


def test_starved_from_the_start(notify_socket: NotifySocket) -> None:
    n = Notifier.from_env(notify_socket.env(WATCHDOG_USEC=str(WATCHDOG_USEC)))
    gate = WatchdogGate(n)
    assert gate.enabled and gate.starved
    assert _run_clock(gate, 40.0, 0.125, lambda t: False, notify_socket) == []


def test_watchdog_pid_mismatch_means_no_pings(notify_socket: NotifySocket) -> None:
    other = os.getpid() + 1
    env = notify_socket.env(WATCHDOG_USEC=str(WATCHDOG_USEC), WATCHDOG_PID=str(other))
    n = Notifier.from_env(env)
    assert n.enabled and not n.watchdog_enabled
    gate = WatchdogGate(n)
    assert not gate.enabled
    assert _run_clock(gate, 30.0, 0.125, lambda t: True, notify_socket) == []
    assert n.ready()  # the other notifications still go out
    assert notify_socket.drain() == ["READY=1"]


def test_watchdog_pid_match_means_pings(notify_socket: NotifySocket) -> None:
    env = notify_socket.env(WATCHDOG_USEC=str(WATCHDOG_USEC), WATCHDOG_PID=str(os.getpid()))
    n = Notifier.from_env(env)
    assert n.watchdog_enabled
    assert n.watchdog()
    assert notify_socket.recv() == "WATCHDOG=1"


_CHILD = """
import os
from imudiag.service.sdnotify import Notifier, WatchdogGate
n = Notifier.from_env()
gate = WatchdogGate(n)
n.ready("child {}".format(os.getpid()))
print(os.getpid())
for t in (0.0, 1.0, 2.5, 3.0):   # simulated s; interval 2.5 s
    gate.frames_arrived(t)
    gate.tick(t)
n.stopping()
"""


@pytest.mark.realtime
@pytest.mark.parametrize("pid_mode", ["unset", "parent"])
def test_real_process_reads_its_environment(notify_socket: NotifySocket, pid_mode: str) -> None:
    """A child process gets NOTIFY_SOCKET etc. as systemd would pass them."""
    env = {k: v for k, v in os.environ.items() if k not in ("WATCHDOG_PID", "NOTIFY_SOCKET")}
    env.update(notify_socket.env(WATCHDOG_USEC="5000000"))
    if pid_mode == "parent":
        env["WATCHDOG_PID"] = str(os.getpid())  # the watchdog belongs to someone else
    proc = subprocess.run(
        [sys.executable, "-c", _CHILD], env=env, capture_output=True, timeout=30, check=False
    )
    assert proc.returncode == 0, proc.stderr.decode()
    got = notify_socket.drain()
    assert got[0] == f"READY=1\nSTATUS=child {int(proc.stdout)}"
    assert got[-1] == "STOPPING=1"
    pings = got[1:-1]
    if pid_mode == "unset":
        assert pings == ["WATCHDOG=1", "WATCHDOG=1"]  # at t = 0 and 2.5 s
    else:
        assert pings == []

"""Live daemon cost: CPU share and resident memory of ``imudiag run`` fed over a real pty.

The daemon runs unmodified as a subprocess (``python -m imudiag run --source
serial:///dev/pts/N``) on a certificate whose ``sample_rate`` is the board's
rate. The simulated board's bytes (static scenario, a device-info frame every
1000 frames) are generated before the run and written to the pty master by
:class:`imudiag.bench.pty.BoardWriter`, one sample frame per write at the
board's rate, as a CDC-ACM board delivers them. After a warm-up the daemon's
user + system CPU time (``/proc/PID/stat``) over the wall time gives its share
of one core; its resident set (``/proc/PID/statm``) is sampled every second.

The floor reader (:mod:`benchmarks.floor_reader`) runs beside it on a second pty
fed the same frames at the same read interval; the daemon's CPU over the floor's,
both from the same window, is the figure that holds on a shared machine.

Run: ``.venv/bin/python -m benchmarks.daemon_live [--rate 1000] [--duration 60]
[--read-interval 0.02]``.
"""

from __future__ import annotations

import argparse
import json
import queue
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from imudiag.bench.pty import BoardWriter, PtyPair
from imudiag.certificate import Certificate, load_default
from imudiag.drivers.wire import HEADER_SIZE, SAMPLE_FRAME_SIZE, TYPE_SAMPLE
from imudiag.sim.board import SimulatedBoard
from imudiag.sim.faults import Fault
from imudiag.sim.scenarios import scenario_motion
from soak.status_check import check_status_line

from .procstat import cpu_seconds, rss_bytes


@dataclass
class BoardStream:
    """A simulated board session cut into writes: one sample frame per chunk."""

    chunks: list[bytes]  #: bytes of each write (a device-info frame rides with the next sample)
    time_us: np.ndarray  #: (K,) device time of each chunk's sample frame, us
    rate_hz: float  #: sample rate, Hz

    @property
    def frames(self) -> int:
        """Sample frames in the session."""
        return len(self.chunks)


def split_frames(data: bytes) -> tuple[list[bytes], list[int]]:
    """Cut a well-formed board byte stream into one chunk per sample frame.

    Frames of other types (device-info) are prepended to the sample frame that
    follows them. Returns the chunks and each chunk's sample ``time_us``.
    Setup code, not a hot path: one Python step per frame.
    """
    chunks: list[bytes] = []
    times: list[int] = []
    pos = 0
    pending = b""
    while pos < len(data):
        total = HEADER_SIZE + data[pos + 3] + 2
        frame = data[pos : pos + total]
        if data[pos + 2] == TYPE_SAMPLE and total == SAMPLE_FRAME_SIZE:
            chunks.append(pending + frame)
            times.append(int.from_bytes(frame[6:10], "little"))
            pending = b""
        else:
            pending += frame
        pos += total
    return chunks, times


def board_stream(
    certificate: Certificate,
    rate_hz: float,
    duration_s: float,
    seed: int = 0,
    faults: Sequence[Fault] = (),
) -> BoardStream:
    """``duration_s`` seconds of the simulated board (static scenario) at ``rate_hz``."""
    board = SimulatedBoard(
        certificate,
        scenario_motion("static", seed),
        rate_hz,
        seed,
        faults=faults,
        duration_s=duration_s,
    )
    parts = []
    while not board.exhausted:
        data, _ = board.generate(int(rate_hz * 10))
        parts.append(data)
    chunks, times = split_frames(b"".join(parts))
    return BoardStream(chunks, np.asarray(times, dtype=np.int64), float(rate_hz))


def rate_certificate(rate_hz: float, directory: Path) -> Path:
    """The bundled certificate with ``sample_rate`` = ``rate_hz``, saved in ``directory``."""
    cert = load_default()
    cert.sample_rate = float(rate_hz)
    path = directory / f"certificate-{rate_hz:g}hz.yaml"
    cert.save(path)
    return path


class StatusReader(threading.Thread):
    """Reads a daemon's stdout: every line must be a well-formed status object."""

    def __init__(self, stream: Any) -> None:
        super().__init__(daemon=True, name="StatusReader")
        self.stream = stream
        self.lines: queue.Queue[tuple[float, dict[str, Any]]] = queue.Queue()
        self.count = 0
        self.last: dict[str, Any] | None = None
        self.errors: list[str] = []

    def run(self) -> None:
        for line in self.stream:
            now = time.monotonic()
            try:
                status = json.loads(line)
                check_status_line(status)
            except ValueError as exc:
                self.errors.append(f"{exc}: {line[:200]!r}")
                continue
            self.count += 1
            self.last = status
            self.lines.put((now, status))

    def wait_first(self, timeout_s: float) -> dict[str, Any]:
        """The first status line (the daemon is up and polling its source)."""
        _, status = self.lines.get(timeout=timeout_s)
        return status


def daemon_command(source: str, certificate: Path, diagnosis: bool) -> list[str]:
    """The ``imudiag run`` command line for a source URL and certificate file."""
    cmd = [
        sys.executable,
        "-m",
        "imudiag",
        "run",
        "--source",
        source,
        "--certificate",
        str(certificate),
        "--log-level",
        "warning",
    ]
    if not diagnosis:
        cmd.append("--no-diagnosis")
    return cmd


def measure_live(
    rate_hz: float,
    duration_s: float = 60.0,
    diagnosis: bool = True,
    warmup_s: float | None = None,
    seed: int = 0,
    read_interval_s: float | None = None,
) -> dict[str, Any]:
    """Run the daemon on a pty fed at ``rate_hz`` for ``duration_s`` seconds; its cost.

    Beside it, in the same run, the floor reader (:mod:`benchmarks.floor_reader`)
    reads the same frames from a second pty at the same read interval: both CPU
    shares are measured over the same wall-clock window, so their ratio holds on a
    loaded machine where the absolute shares do not. Returns CPU shares (% of one
    core, over the time after ``warmup_s``) and their ratio, resident memory (MB:
    after warm-up, at the end, the peak of the 1 s samples), frames written and
    received, status lines and the exit status. ``read_interval_s``: the daemon's
    (``read_interval_s`` of its configuration) and the floor's; default 5 ms, the daemon's.
    """
    warm = warmup_s if warmup_s is not None else min(5.0, duration_s / 4)
    interval = 0.005 if read_interval_s is None else float(read_interval_s)
    stream = board_stream(load_default(), rate_hz, duration_s + 2.0, seed)
    with tempfile.TemporaryDirectory() as tmp, PtyPair() as pair, PtyPair() as floor_pair:
        cert_path = rate_certificate(rate_hz, Path(tmp))
        cmd = daemon_command(f"serial://{pair.slave_path}", cert_path, diagnosis)
        if read_interval_s is not None:  # a configuration file that sets only the interval
            config = Path(tmp) / "imudiag.yaml"
            config.write_text(f"read_interval_s: {interval:g}\n", encoding="utf-8")
            cmd += ["--config", str(config)]
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        floor = subprocess.Popen(
            [sys.executable, "-m", "benchmarks.floor_reader", floor_pair.slave_path,
             str(cert_path), "--interval", f"{interval:g}"],
            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
        )  # fmt: skip
        floor_lines: list[str] = []
        threading.Thread(target=lambda: floor_lines.extend(floor.stdout), daemon=True).start()
        reader = StatusReader(proc.stdout)
        reader.start()
        stderr: list[str] = []
        threading.Thread(target=lambda: stderr.extend(proc.stderr), daemon=True).start()
        try:
            try:
                reader.wait_first(30.0)
            except queue.Empty:
                raise RuntimeError(f"daemon wrote no status: {''.join(stderr)[-2000:]}") from None
            writer = BoardWriter(pair, stream.chunks, rate_hz=rate_hz)
            floor_writer = BoardWriter(floor_pair, stream.chunks, rate_hz=rate_hz)
            writer.start()
            floor_writer.start()
            start = time.monotonic()
            rss: list[tuple[float, int]] = []
            cpu0 = wall0 = None
            while (now := time.monotonic()) - start < duration_s and proc.poll() is None:
                rss.append((now - start, rss_bytes(proc.pid)))
                if cpu0 is None and now - start >= warm:
                    cpu0, wall0 = cpu_seconds(proc.pid), now
                    floor0 = cpu_seconds(floor.pid)
                time.sleep(1.0)
            if proc.poll() is not None:
                raise RuntimeError(f"daemon exited early: {''.join(stderr)[-2000:]}")
            cpu1, wall1 = cpu_seconds(proc.pid), time.monotonic()
            floor1 = cpu_seconds(floor.pid)
            rss.append((wall1 - start, rss_bytes(proc.pid)))
            written = writer.chunks_written
            writer.stop()
            floor_writer.stop()
            time.sleep(0.3)  # let the daemon drain the pty before stopping it
        finally:
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
            exit_status = proc.wait(15.0)
            if floor.poll() is None:
                floor.send_signal(signal.SIGTERM)
            floor.wait(15.0)
        reader.join(5.0)
    assert cpu0 is not None and wall0 is not None
    last = reader.last or {}
    rss_after = [r for t, r in rss if t >= warm]
    mb = 1.0 / 2**20
    floor_last = json.loads(floor_lines[-1]) if floor_lines else {}
    cpu = 100.0 * (cpu1 - cpu0) / (wall1 - wall0)
    floor_cpu = 100.0 * (floor1 - floor0) / (wall1 - wall0)
    return {
        "rate_hz": rate_hz,
        "duration_s": duration_s,
        "diagnosis": diagnosis,
        "read_interval_s": interval,
        "cpu_percent_of_one_core": cpu,
        "floor_cpu_percent_of_one_core": floor_cpu,
        "cpu_ratio_to_floor": cpu / floor_cpu if floor_cpu > 0 else None,
        "floor_frames": int(floor_last.get("frames", 0)),
        "cpu_window_s": wall1 - wall0,
        "rss_mb_after_warmup": rss_after[0] * mb,
        "rss_mb_end": rss_after[-1] * mb,
        "rss_mb_max": max(rss_after) * mb,
        "frames_written": written,
        "frames_received": int(last.get("counters", {}).get("frames", 0)),
        "counters": last.get("counters"),
        "state": last.get("state"),
        "status_lines": reader.count,
        "malformed_status_lines": len(reader.errors),
        "exit_status": exit_status,
    }


def main(argv: Sequence[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rate", type=float, action="append", help="board rate, Hz (repeatable)")
    p.add_argument("--duration", type=float, default=60.0, help="seconds per run")
    p.add_argument("--no-diagnosis", action="store_true", help="per-sample checks only")
    p.add_argument("--read-interval", type=float, help="daemon's and floor's read interval, s")
    a = p.parse_args(argv)
    for rate in a.rate or [200.0, 1000.0]:
        r = measure_live(rate, a.duration, diagnosis=not a.no_diagnosis,
                         read_interval_s=a.read_interval)  # fmt: skip
        print(json.dumps(r, indent=1))


if __name__ == "__main__":
    main()

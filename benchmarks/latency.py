"""End-to-end latency: a frame's last byte written to the pty -> its F0 verdict in the daemon.

Method (both ends stamp ``time.monotonic()``, which is Linux CLOCK_MONOTONIC,
one clock for every process of the machine):

- the writer (this process) writes the simulated board's frames to a real pty
  master at the board's rate, one sample frame per ``os.write``, and stamps
  the moment each write returned, i.e. the frame's last byte is in the pty;
- the daemon runs in a child process (``python -m benchmarks.latency child``):
  the real :class:`imudiag.service.daemon.Daemon` with the real serial source
  on the pty slave, built from the same settings as ``imudiag run``, with one
  hook: :meth:`Monitor.update` is wrapped to stamp the moment it returns,
  with the device times of the first and last sample of the block. When
  ``update`` returns, every sample of the block has its F0 check done, its
  failure counted and the k-of-n persistence updated: that is the verdict.
- frames are matched to blocks by device time; latency = verdict stamp minus
  write stamp, for every frame after the warm-up.

Not included: the status line (written at 1 Hz and at once on a change, after
the diagnosis update of the same loop turn), which :func:`alarm_latency` could
add; the hook itself costs one Python call per block.

With ``--aiding process|thread|inline`` the board drives (an urban drive of
:mod:`imudiag.sim.drive`) and a real gpsd (:class:`imudiag.bench.gnss.GnssFeed`) is fed
the same drive's GNSS, paced by the board's sample time like the bench's
``drive-aided``; the daemon runs with ``--aiding`` and its aiding batches in their
worker process (``process``, as shipped), a thread (``thread``) or inline in the
sampling loop (``inline``,
as before). ``max_loop_gap_ms`` is then the longest wall time between two consecutive
monitor updates after the warm-up: a batch that stalls the loop shows there.

Run: ``.venv/bin/python -m benchmarks.latency [--rate 1000] [--duration 60]
[--aiding process --aiding thread --aiding inline]``.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from imudiag.bench.gnss import GnssFeed
from imudiag.bench.pty import PtyPair, write_all
from imudiag.certificate import load_default
from imudiag.sim.board import SimulatedBoard
from imudiag.sim.drive import DriveMotion, GnssSimConfig, drive_motion

from .daemon_live import BoardStream, board_stream, rate_certificate, split_frames
from .procstat import cpu_seconds

_TRACE_CAPACITY = 1 << 20  #: monitor updates recorded at most by the child


class TimedWriter(threading.Thread):
    """Writes chunk i to ``fd`` at ``start + i / rate_hz`` s; stamps each write's return."""

    def __init__(
        self,
        fd: int,
        chunks: Sequence[bytes],
        rate_hz: float,
        after_write: Callable[[float], None] | None = None,
    ) -> None:
        super().__init__(daemon=True, name="TimedWriter")
        self.fd = fd
        self.chunks = chunks
        self.period = 1.0 / rate_hz
        #: called with the sample time (s) of each chunk after its write (the GNSS feed)
        self.after_write = after_write
        self.done = np.full(len(chunks), np.nan)  #: monotonic s when the write returned
        self._stop_event = threading.Event()

    def run(self) -> None:
        start = time.monotonic()
        for i, chunk in enumerate(self.chunks):
            delay = start + i * self.period - time.monotonic()
            if delay > 0 and self._stop_event.wait(delay):
                break
            if self._stop_event.is_set():
                break
            write_all(self.fd, chunk, self._stop_event)
            self.done[i] = time.monotonic()
            if self.after_write is not None:
                self.after_write(i * self.period)

    def stop(self) -> None:
        """Stop writing and wait for the thread."""
        self._stop_event.set()
        self.join(5.0)


def _child(argv: Sequence[str]) -> int:
    """The instrumented daemon: runs until SIGTERM, then writes its trace (npz)."""
    p = argparse.ArgumentParser(prog="benchmarks.latency child")
    p.add_argument("--source", required=True)
    p.add_argument("--certificate", required=True)
    p.add_argument("--trace", required=True, help="output .npz")
    p.add_argument("--no-diagnosis", action="store_true")
    p.add_argument(
        "--read-interval",
        type=float,
        default=None,
        help="daemon read interval, s (default: the daemon's)",
    )
    p.add_argument("--aiding", default=None, help="gpsd://HOST:PORT")
    p.add_argument("--aiding-mode", default="process", help="where the aiding batches run")
    p.add_argument("--switch-interval", type=float, default=None, help="GIL switch interval, s")
    a = p.parse_args(argv)

    from imudiag.service.config import default_config, merge_cli
    from imudiag.service.daemon import Daemon, settings_from_config
    from imudiag.service.status import JsonLinesSink

    config = merge_cli(default_config(), {"source": a.source, "certificate": a.certificate})
    settings = settings_from_config(config)
    settings.diagnosis = not a.no_diagnosis
    if a.read_interval is not None:
        settings.read_interval_s = a.read_interval
    settings.aiding_url = a.aiding
    settings.aiding_batches = a.aiding_mode
    devnull = open(os.devnull, "w")  # noqa: SIM115 - lives as long as the process
    daemon = Daemon(settings, [JsonLinesSink(devnull)])
    if a.switch_interval is not None:
        sys.setswitchinterval(a.switch_interval)
    daemon.install_signal_handlers()

    t_first = np.zeros(_TRACE_CAPACITY)
    t_last = np.zeros(_TRACE_CAPACITY)
    stamp = np.zeros(_TRACE_CAPACITY)
    count = [0]
    update = daemon.monitor.update

    def hooked(block: Any) -> None:
        update(block)
        i = count[0]
        if len(block) and i < _TRACE_CAPACITY:
            stamp[i] = time.monotonic()
            t_first[i] = block.t[0]
            t_last[i] = block.t[-1]
            count[0] = i + 1

    daemon.monitor.update = hooked  # type: ignore[method-assign]
    print("ready", flush=True)
    daemon.run()
    n = count[0]
    np.savez(a.trace, t_first=t_first[:n], t_last=t_last[:n], stamp=stamp[:n])
    if daemon.aiding is not None:  # what the aiding did, for the figures
        Path(a.trace + ".aiding.json").write_text(json.dumps(daemon.aiding.status()))
    return 0


def drive_stream(
    rate_hz: float, duration_s: float, seed: int = 0, route: str = "urban"
) -> tuple[BoardStream, DriveMotion]:
    """``duration_s`` s of the simulated board on a drive at ``rate_hz``, and its motion
    (for the GNSS feed)."""
    motion = drive_motion(route, duration_s + 30.0, seed)
    board = SimulatedBoard(load_default(), motion, rate_hz, seed, duration_s=duration_s)
    parts = []
    while not board.exhausted:
        data, _ = board.generate(int(rate_hz * 10))
        parts.append(data)
    chunks, times = split_frames(b"".join(parts))
    return BoardStream(chunks, np.asarray(times, dtype=np.int64), float(rate_hz)), motion


def match_latency(
    stream: BoardStream, write_done: np.ndarray, trace: dict[str, np.ndarray]
) -> np.ndarray:
    """Per-frame latency (s): verdict stamp of the block holding the frame minus its write stamp.

    Frames not written (NaN stamp) or never verdicted are left out.
    """
    t_frame = stream.time_us * 1e-6
    t_last = trace["t_last"]
    order = np.argsort(t_last, kind="stable")
    t_last, stamp, t_first = t_last[order], trace["stamp"][order], trace["t_first"][order]
    k = np.searchsorted(t_last, t_frame - 1e-9)  # first block ending at or after the frame
    inside = k < len(t_last)
    k_in = np.minimum(k, len(t_last) - 1)
    inside &= t_first[k_in] <= t_frame + 1e-9
    ok = inside & np.isfinite(write_done)
    return stamp[k_in[ok]] - write_done[ok]


def measure_latency(
    rate_hz: float,
    duration_s: float = 60.0,
    diagnosis: bool = True,
    read_interval_s: float | None = None,
    warmup_s: float | None = None,
    seed: int = 0,
    aiding: str | None = None,
    switch_interval_s: float | None = None,
) -> dict[str, Any]:
    """Latency percentiles (ms) of the F0 verdict at ``rate_hz`` over ``duration_s`` s;
    ``aiding``: None, ``"process"``, ``"thread"`` or ``"inline"`` (module doc)."""
    warm = warmup_s if warmup_s is not None else min(5.0, duration_s / 4)
    with contextlib.ExitStack() as stack:
        tmp = stack.enter_context(tempfile.TemporaryDirectory())
        pair = stack.enter_context(PtyPair())
        feed = None
        if aiding is None:
            stream = board_stream(load_default(), rate_hz, duration_s, seed)
        else:
            stream, motion = drive_stream(rate_hz, duration_s, seed)
            feed = stack.enter_context(GnssFeed(motion, GnssSimConfig(), seed, tmp))
        cert_path = rate_certificate(rate_hz, Path(tmp))
        trace_path = Path(tmp) / "trace.npz"
        cmd = [
            sys.executable,
            "-m",
            "benchmarks.latency",
            "child",
            "--source",
            f"serial://{pair.slave_path}",
            "--certificate",
            str(cert_path),
            "--trace",
            str(trace_path),
        ]
        if not diagnosis:
            cmd.append("--no-diagnosis")
        if read_interval_s is not None:
            cmd += ["--read-interval", str(read_interval_s)]
        if switch_interval_s is not None:
            cmd += ["--switch-interval", str(switch_interval_s)]
        if feed is not None:
            cmd += ["--aiding", feed.url, "--aiding-mode", str(aiding)]
        proc = subprocess.Popen(
            cmd,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            cwd=Path(__file__).resolve().parent.parent,
        )
        try:
            assert proc.stdout is not None
            if proc.stdout.readline().strip() != "ready":
                raise RuntimeError(f"latency child failed: {proc.stderr.read()[-2000:]}")
            time.sleep(0.5)  # the daemon opens the port after printing "ready"
            writer = TimedWriter(
                pair.master_fd, stream.chunks, rate_hz, None if feed is None else feed.send_until
            )
            writer.start()
            writer.join(warm)
            cpu0, wall0 = cpu_seconds(proc.pid), time.monotonic()
            writer.join(duration_s + 30.0)
            cpu1, wall1 = cpu_seconds(proc.pid), time.monotonic()
            time.sleep(0.5)  # the last frames reach their verdict
        finally:
            proc.send_signal(signal.SIGTERM)
            _, err = proc.communicate(timeout=30.0)
        if proc.returncode != 0:
            raise RuntimeError(f"latency child exited {proc.returncode}: {err[-2000:]}")
        with np.load(trace_path) as z:
            trace = {k: z[k] for k in z.files}
        aid_path = Path(str(trace_path) + ".aiding.json")
        aid = json.loads(aid_path.read_text()) if aid_path.exists() else None
    keep = stream.time_us * 1e-6 >= warm
    lat = match_latency(
        BoardStream(
            [c for c, k in zip(stream.chunks, keep, strict=True) if k],
            stream.time_us[keep],
            rate_hz,
        ),
        writer.done[keep],
        trace,
    )
    ms = 1e3 * lat
    after = trace["t_first"] >= warm
    gaps = np.diff(trace["stamp"][after]) if np.sum(after) > 1 else np.zeros(0)
    return {
        "rate_hz": rate_hz,
        "duration_s": duration_s,
        "diagnosis": diagnosis,
        "aiding": aiding,
        "switch_interval_s": switch_interval_s,
        "max_loop_gap_ms": 1e3 * float(gaps.max()) if gaps.size else None,
        # the daemon's last aiding status: batches run, F0 epochs checked, windows
        "aiding_status": None
        if aid is None
        else {k: aid[k] for k in ("in_use", "reason", "batches", "f0", "windows", "latency_s")},
        "read_interval_s": read_interval_s,
        "frames": int(ms.size),
        "frames_written": int(np.count_nonzero(np.isfinite(writer.done))),
        "p50_ms": float(np.percentile(ms, 50)) if ms.size else None,
        "p99_ms": float(np.percentile(ms, 99)) if ms.size else None,
        "p999_ms": float(np.percentile(ms, 99.9)) if ms.size else None,
        "max_ms": float(ms.max()) if ms.size else None,
        "blocks": int(trace["stamp"].size),
        # CPU of the instrumented daemon after the warm-up, % of one core
        "cpu_percent_of_one_core": 100.0 * (cpu1 - cpu0) / (wall1 - wall0),
    }


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["child"]:
        return _child(argv[1:])
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rate", type=float, action="append", help="board rate, Hz (repeatable)")
    p.add_argument("--duration", type=float, default=60.0, help="seconds per run")
    p.add_argument("--no-diagnosis", action="store_true", help="per-sample checks only")
    p.add_argument(
        "--read-interval", type=float, action="append", help="daemon read interval(s) to compare, s"
    )
    p.add_argument(
        "--aiding",
        choices=("process", "thread", "inline"),
        action="append",
        help="drive with GNSS aiding through gpsd, batches in a process, a thread or inline "
        "(repeatable, to compare)",
    )
    p.add_argument(
        "--switch-interval",
        type=float,
        action="append",
        help="the daemon's GIL switch interval(s) to compare, s (default: the daemon's)",
    )
    a = p.parse_args(argv)
    for rate in a.rate or [1000.0]:
        for interval in a.read_interval or [None]:
            for aiding in a.aiding or [None]:
                for switch in a.switch_interval or [None]:
                    r = measure_latency(
                        rate, a.duration, not a.no_diagnosis, interval, aiding=aiding,
                        switch_interval_s=switch,
                    )  # fmt: skip
                    print(json.dumps(r), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())

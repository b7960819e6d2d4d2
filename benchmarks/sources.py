"""Device sources against the native protocol: the daemon's CPU share on each, same run.

For each rate, one simulated session (static scenario, the bundled certificate with
``sample_rate`` = the rate) is encoded before the run by each device's fake encoder
(:mod:`imudiag.bench.devices`) and cut into one write per sample, as a device sends it.
``imudiag run`` (unmodified, a subprocess, the window diagnosis on) reads each device on
its own pty; all of one rate run at once, so they share the machine alike. After a
warm-up each daemon's user + system CPU (``/proc/PID/stat``) over the same wall-clock
window gives its share of one core; a source's figure is its share over the native
protocol's (the target of issue 26: at most 1.3x).

A source is one line in :data:`SOURCES`: its URL for a pty path, the fake device
(:data:`imudiag.bench.devices.ENCODERS`) and the rate it is judged at.

A device with a set-up dialogue (the iSensor SPI Buffer board) is answered by its fake's
command line until its daemon reports the link connected, then streams like the others.
The IIO source reads a character device, not a port: it gets a fake sysfs tree and FIFO
(:class:`imudiag.bench.fake_iio.FakeIIODevice`) with one packed record per sample, encoded
by the bench's IIO fake (:class:`imudiag.bench.devices.IIOEncoder`: ADIS16475-2's 32-bit
LSB sizes, SI scales).

Run: ``.venv/bin/python -m benchmarks.sources [--duration 30] [--runs 3] [--only mavlink]``.
"""

from __future__ import annotations

import argparse
import json
import queue
import signal
import subprocess
import tempfile
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from imudiag.bench.devices import (
    DeviceEncoder,
    IIOEncoder,
    make_encoder,
)
from imudiag.bench.fake_iio import FakeIIODevice
from imudiag.bench.pty import BoardWriter, PtyPair, read_available, write_all
from imudiag.certificate import load_default
from imudiag.samples import SampleBlock
from imudiag.sim.board import SimulatedBoard
from imudiag.sim.scenarios import scenario_motion

from .daemon_live import StatusReader, daemon_command
from .procstat import cpu_seconds

NATIVE = "native"
#: name -> (source URL with {path}, fake device, rate in Hz): one line per source
SOURCES: dict[str, tuple[str, str, float]] = {
    NATIVE: ("serial://{path}", "native", 0.0),  # at every rate below: the reference
    "mavlink": ("mavlink://{path}?rate=1000", "mavlink", 1000.0),
    "isensor": ("isensor://{path}", "isensor", 1000.0),
    "witmotion": ("witmotion://{path}?rate=200", "witmotion", 200.0),
    "iio": ("iio://adis16475?root={path}/root&devdir={path}/dev&rate=1000", "iio", 1000.0),
}
IIO = "iio"  #: not a port: a fake sysfs tree and FIFO (:mod:`imudiag.bench.fake_iio`)
#: the host's last set-up lines: start the capture (the iSensor board's CLI; others ignore it)
START_CAPTURE = b"stream 1\r\nwrite 0 FF\r\n"


def answer_until_connected(
    pair: PtyPair, encoder: DeviceEncoder, reader: StatusReader, timeout_s: float = 30.0
) -> None:
    """Answer the host's set-up dialogue (:attr:`DeviceEncoder.dialogue`) until its daemon
    reports the link connected."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        data = read_available(pair.master_fd) if encoder.dialogue else b""
        reply = encoder.answer(data) if data else b""
        if reply:
            write_all(pair.master_fd, reply)
        if (reader.last or {}).get("link") == "connected":
            return
        time.sleep(0.01)
    raise RuntimeError(f"{encoder.name}: the daemon did not configure the device in {timeout_s} s")


def wait_connected(reader: StatusReader, timeout_s: float = 30.0) -> None:
    """Wait until a daemon reports its link connected (a source without a dialogue)."""
    end = time.monotonic() + timeout_s
    while (reader.last or {}).get("link") != "connected":
        if time.monotonic() > end:
            raise RuntimeError(f"the daemon did not open its source in {timeout_s} s")
        time.sleep(0.01)


def device_writes(device: str, rate_hz: float, duration_s: float, seed: int = 0) -> list[bytes]:
    """One write per sample of a static session, encoded by the fake ``device``."""
    cert = load_default()
    cert.sample_rate = rate_hz
    motion = scenario_motion("static", seed)
    board = SimulatedBoard(cert, motion, rate_hz, seed, duration_s=duration_s)
    writes: list[bytes] = []
    encoder = make_encoder(device, cert)
    encoder.answer(START_CAPTURE)  # a board with a set-up dialogue: as the host leaves it
    while not board.exhausted:
        _, block = board.generate(int(rate_hz * 5))
        for i in range(len(block)):
            one: SampleBlock = block.slice(i, i + 1)
            writes.append(encoder.encode(one))
    return writes


def measure(names: Sequence[str], rate_hz: float, duration_s: float, seed: int = 0) -> dict:
    """Run the daemon on each of ``names`` (the native protocol among them) at ``rate_hz``
    at once; each one's CPU share (% of one core) and ratio to the native one's."""
    warm = min(5.0, duration_s / 4)
    procs: dict[str, tuple[subprocess.Popen[str], StatusReader, list[str]]] = {}
    pairs = {name: PtyPair() for name in names if SOURCES[name][1] != IIO}
    writers: dict[str, BoardWriter] = {}
    fakes: list[FakeIIODevice] = []
    with tempfile.TemporaryDirectory() as tmp:
        try:
            for name in names:
                url, device, _ = SOURCES[name]
                cert = load_default()
                cert.sample_rate = rate_hz
                cert_path = Path(tmp) / f"{name}.yaml"
                if device == IIO:
                    path = str(Path(tmp) / name)
                    iio = IIOEncoder(cert)  # one packed record per sample (its encode)
                    root, devdir = f"{path}/root", f"{path}/dev"
                    fakes.append(FakeIIODevice(root, devdir, iio.model, iio.channels, 0, rate_hz))
                    iio.certificate.save(cert_path)
                else:
                    path = pairs[name].slave_path
                    make_encoder(device, cert).certificate.save(cert_path)
                cmd = daemon_command(url.format(path=path), cert_path, True)
                proc = subprocess.Popen(
                    cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
                )
                reader = StatusReader(proc.stdout)
                reader.start()
                err: list[str] = []
                drain = threading.Thread(target=lambda p=proc, e=err: e.extend(p.stderr))
                drain.daemon = True
                drain.start()
                procs[name] = (proc, reader, err)
            for name, (_, reader, err) in procs.items():
                try:
                    reader.wait_first(30.0)
                except queue.Empty:
                    raise RuntimeError(f"{name}: no status: {''.join(err)[-2000:]}") from None
                if SOURCES[name][1] == IIO:
                    wait_connected(reader)
                    continue
                device = make_encoder(SOURCES[name][1], load_default())
                answer_until_connected(pairs[name], device, reader)
            for name in names:
                writes = device_writes(SOURCES[name][1], rate_hz, duration_s + 2.0, seed)
                target: PtyPair | int = (
                    pairs[name] if name in pairs else fakes[0].fd  # one IIO source per run
                )
                writers[name] = BoardWriter(target, writes, rate_hz=rate_hz)
            for w in writers.values():
                w.start()
            start = time.monotonic()
            time.sleep(warm)
            cpu0 = {n: cpu_seconds(p.pid) for n, (p, _, _) in procs.items()}
            wall0 = time.monotonic()
            time.sleep(max(0.0, duration_s - (wall0 - start)))
            cpu1 = {n: cpu_seconds(p.pid) for n, (p, _, _) in procs.items()}
            wall1 = time.monotonic()
            for w in writers.values():
                w.stop()
            time.sleep(0.3)
        finally:
            for proc, _, _ in procs.values():
                if proc.poll() is None:
                    proc.send_signal(signal.SIGTERM)
            for proc, _, _ in procs.values():
                proc.wait(15.0)
            for pair in pairs.values():
                pair.close()
            for fake in fakes:
                fake.close()
    out: dict[str, Any] = {"rate_hz": rate_hz, "cpu_window_s": round(wall1 - wall0, 2)}
    share = {n: 100.0 * (cpu1[n] - cpu0[n]) / (wall1 - wall0) for n in names}
    for name in names:
        last = procs[name][1].last or {}
        out[name] = {
            "cpu_percent_of_one_core": round(share[name], 2),
            "ratio_to_native": round(share[name] / share[NATIVE], 3) if share[NATIVE] else None,
            "frames_written": writers[name].chunks_written,
            "frames_received": int(last.get("counters", {}).get("frames", 0)),
            "state": last.get("state"),
        }
    return out


def main(argv: Sequence[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--duration", type=float, default=30.0, help="seconds per run")
    p.add_argument("--runs", type=int, default=1, help="rounds (each source beside native)")
    p.add_argument("--only", action="append", help="a source of SOURCES (repeatable)")
    a = p.parse_args(argv)
    chosen = [n for n in SOURCES if n != NATIVE and (not a.only or n in a.only)]
    by_rate: dict[float, list[str]] = {}
    for name in chosen:
        by_rate.setdefault(SOURCES[name][2], []).append(name)
    for _ in range(a.runs):
        for rate, names in by_rate.items():
            r = measure([NATIVE, *names], rate, a.duration)
            print(json.dumps(r, indent=1), flush=True)


if __name__ == "__main__":
    main()

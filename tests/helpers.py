"""Helpers shared by the tests: transports and the daemon, block cuts of a stream, a log
through both faces."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from imudiag.drivers.base import Source
from imudiag.samples import SampleBlock


def read_samples(src: Source, n: int, timeout_s: float = 5.0) -> SampleBlock:
    """Read from ``src`` until ``n`` samples arrived or ``timeout_s`` seconds passed."""
    blocks, got = [], 0
    end = time.monotonic() + timeout_s
    while got < n and time.monotonic() < end:
        b = src.read(0.05)
        blocks.append(b)
        got += len(b)
    return SampleBlock.concat(blocks)


def read_until_state(src: Source, state: str, reads: int = 200) -> str:
    """Read from a ReconnectingSource (0.02 s each, at most ``reads`` times) until its
    link ``state`` is reached; returns the state it ended in (an event, not a clock)."""
    for _ in range(reads):
        src.read(0.02)
        if getattr(src, "state", None) == state:
            break
    return str(getattr(src, "state", ""))


class CollectSink:
    """A daemon status sink that keeps every status it is given, in order."""

    def __init__(self) -> None:
        self.lines: list[dict] = []

    def publish(self, status: dict) -> None:
        self.lines.append(status)

    def close(self) -> None:
        pass


def random_blocks(rng: np.random.Generator, n: int, read_max: int, big: int) -> list[int]:
    """Block sizes summing to ``n`` (samples), each drawn from single rows (1-7), reads
    (8 to ``read_max`` - 1) or a big block of ``big``: how a stream may be cut."""
    out, done = [], 0
    while done < n:
        size = int(rng.choice([rng.integers(1, 8), rng.integers(8, read_max), big]))
        out.append(min(size, n - done))
        done += out[-1]
    return out


def run_both_faces(log: Path, cert: Path | str, read_as: str = "") -> dict[str, Any]:
    """``log`` through both faces with certificate ``cert``: ``imudiag diagnose``'s report
    (no windows) and the daemon's status lines with samples, replaying it at full speed
    (``replay://LOG?speed=0&step=2``, ``read_as`` its further query, the reader's options):
    ``{"report": ..., "lines": [...]}``."""
    from imudiag.api import diagnose
    from imudiag.logs.options import options_from_query
    from imudiag.service.daemon import Daemon, DaemonSettings

    query = dict(kv.split("=", 1) for kv in read_as.split("&") if kv)
    report = diagnose(str(log), str(cert), windows=False, log_options=options_from_query(query))
    sink = CollectSink()
    url = f"replay://{log}?speed=0&step=2" + (f"&{read_as}" if read_as else "")
    daemon = Daemon(DaemonSettings(source_url=url, certificate_path=str(cert)), [sink])
    assert daemon.run() == 0
    lines = [s for s in sink.lines if s["t"] is not None]
    return {"report": report, "lines": lines}


def named_faults(faults: list[dict[str, Any]]) -> set[tuple[str, str, str]]:
    """(triad, sensor or "", cause) of each fault of a verdict or a status."""
    return {(f["triad"], f.get("sensor") or "", f["cause"]) for f in faults}

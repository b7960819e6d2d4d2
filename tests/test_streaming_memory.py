"""Long logs stream in bounded memory: readers, ``imudiag diagnose`` and ``imudiag model-check``.

Logs are generated on the fly (the simulated board still in 6 attitudes for
5 s each with 2 s turns between, repeating, 200 Hz) at two lengths, N and 4N
samples, both far longer than the readers' blocks (4096 samples here) and
than a diagnosis window (16 still intervals, 112 s). The commands
run in-process under :mod:`tracemalloc` (numpy reports its array buffers to
it), and the peak traced memory is compared: streaming code holds a bounded
working set, so its peak may grow with the log by at most a small fraction of
the log's own size (``GROWTH_FRACTION`` of 7 float64 columns per sample).
"""

from __future__ import annotations

import importlib.util
import json
import tracemalloc
from collections.abc import Callable
from pathlib import Path

import pytest

from imudiag.certificate import default_certificate_path, load_default
from imudiag.cli import main as cli_main
from imudiag.logs import open_log, open_writer
from imudiag.sim.board import SimulatedBoard
from imudiag.sim.scenarios import scenario_motion

RATE_HZ = 200.0
N_SHORT = 30_000  #: samples (150 s)
N_LONG = 4 * N_SHORT  #: samples (600 s)
BLOCK = 4096  #: samples per block read
BYTES_PER_SAMPLE = 7 * 8  #: t and six outputs as float64
GROWTH_FRACTION = 0.25  #: allowed peak growth / growth of the log's in-memory size


def write_session(directory: Path, n: int) -> dict[str, Path]:
    """``n`` samples of the board in 6 attitudes (5 s dwell) as .csv, .npz and .bin logs."""
    cert = load_default()
    motion = scenario_motion("static", 4, {"n": "6", "dwell": "5", "turn": "2"})
    board = SimulatedBoard(cert, motion, RATE_HZ, seed=4, duration_s=n / RATE_HZ)
    paths = {ext: directory / f"session{ext}" for ext in (".csv", ".npz", ".bin")}
    meta = {"sample_rate": RATE_HZ}
    with (
        open_writer(paths[".csv"], meta) as csv,
        open_writer(paths[".npz"], meta) as npz,
        open(paths[".bin"], "wb") as raw,
    ):
        while not board.exhausted:
            data, block = board.generate(1 << 15)
            raw.write(data)
            csv.write(block)
            npz.write(block)
    return paths


@pytest.fixture(scope="module")
def sessions(tmp_path_factory: pytest.TempPathFactory) -> dict[int, dict[str, Path]]:
    base = tmp_path_factory.mktemp("streaming")
    out = {}
    for n in (N_SHORT, N_LONG):
        d = base / str(n)
        d.mkdir()
        out[n] = write_session(d, n)
    return out


def peak_traced_bytes(fn: Callable[[], object]) -> int:
    """Peak memory traced by tracemalloc while ``fn`` runs, bytes."""
    tracemalloc.start()
    try:
        tracemalloc.reset_peak()
        fn()
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def assert_bounded(name: str, peaks: dict[int, int]) -> None:
    growth = peaks[N_LONG] - peaks[N_SHORT]
    allowed = GROWTH_FRACTION * BYTES_PER_SAMPLE * (N_LONG - N_SHORT)
    mb = 1 / 2**20
    assert growth <= allowed, (
        f"{name}: peak memory {peaks[N_SHORT] * mb:.1f} MB for {N_SHORT} samples, "
        f"{peaks[N_LONG] * mb:.1f} MB for {N_LONG}: grew {growth * mb:.1f} MB, more than "
        f"{allowed * mb:.1f} MB ({GROWTH_FRACTION:g} of the log's growth): not streaming"
    )


def require_command(name: str) -> None:
    """Fail (never skip) when the build lacks a command these tests measure."""
    assert importlib.util.find_spec(f"imudiag.commands.{name}") is not None, (
        f"imudiag {name.replace('_', '-')} is missing from this build"
    )


@pytest.mark.parametrize("ext", [".csv", ".npz", ".bin"])
def test_readers_stream_in_bounded_memory(sessions, ext: str) -> None:
    def read(path: Path) -> int:
        count = 0
        with open_log(path, BLOCK) as reader:
            for block in reader:
                assert len(block) <= BLOCK
                count += len(block)
        return count

    counts = {}
    peaks = {}
    for n in (N_SHORT, N_LONG):
        peaks[n] = peak_traced_bytes(lambda n=n: counts.__setitem__(n, read(sessions[n][ext])))
    assert counts == {N_SHORT: N_SHORT, N_LONG: N_LONG}
    assert_bounded(f"open_log({ext})", peaks)


def test_diagnose_streams_in_bounded_memory(sessions, tmp_path: Path) -> None:
    """One format is enough here: the readers (all formats) are checked above.

    ``--no-windows``: the report's ``windows`` list (spec/reports.md) holds one
    entry per window, so it grows with the log by contract; what must stay
    bounded is everything else.
    """
    ext = ".npz"
    require_command("diagnose")
    peaks = {}
    for n in (N_SHORT, N_LONG):
        out = tmp_path / f"report-{n}.json"
        args = [
            "diagnose",
            str(sessions[n][ext]),
            "--certificate",
            str(default_certificate_path()),
            "--json",
            str(out),
            "--block-size",
            str(BLOCK),
            "--no-windows",
        ]
        codes: list[int] = []
        peaks[n] = peak_traced_bytes(lambda a=args, c=codes: c.append(cli_main(a)))
        assert codes == [0]
        report = json.loads(out.read_text())
        assert report["samples"] == n
        assert report["windows_run"] > 0
    assert_bounded(f"imudiag diagnose {ext}", peaks)


def test_model_check_streams_in_bounded_memory(sessions, tmp_path: Path) -> None:
    require_command("model_check")
    peaks = {}
    for n in (N_SHORT, N_LONG):
        out = tmp_path / f"model-{n}.json"
        args = [
            "model-check",
            str(sessions[n][".npz"]),
            "--certificate",
            str(default_certificate_path()),
            "--json",
            str(out),
        ]
        codes: list[int] = []
        peaks[n] = peak_traced_bytes(lambda a=args, c=codes: c.append(cli_main(a)))
        assert codes == [0] and out.stat().st_size > 0
    assert_bounded("imudiag model-check", peaks)

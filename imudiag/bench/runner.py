"""One bench run: the daemon as a real subprocess, the simulated board behind a pty.

:func:`run_bench` writes the daemon's configuration, plugs the board's pty
in behind a symlink, starts ``python -m imudiag run --source serial://LINK``,
feeds the scenario (sensor faults inside the simulator, transport faults in
the byte stream), waits until the daemon has processed the last sample, stops
it with SIGTERM and judges its status lines (:mod:`imudiag.bench.evaluate`).
"""

from __future__ import annotations

import signal
import sys
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from imudiag import certificate as certmod
from imudiag.errors import BenchError
from imudiag.reports import BENCH_FORMAT, header
from imudiag.sim.board import SimulatedBoard
from imudiag.sim.drive import DriveMotion
from imudiag.sim.scenarios import parse_effects, scenario_motion

from . import gnss
from .daemon_process import DaemonProcess, StatusRecord
from .devices import SOURCE_URLS, make_encoder
from .evaluate import Evaluation
from .feeder import BoardFeeder
from .scenario import BenchScenario

REPORT_FORMAT = BENCH_FORMAT


def diagnosis_available() -> bool:
    """True when the daemon can run the live window diagnosis: its own factory
    (``Daemon._make_diagnoser`` with the default settings) builds a diagnoser that
    offers ``faults`` and ``verdict()``."""
    from types import SimpleNamespace

    from imudiag.service.config import default_config
    from imudiag.service.daemon import Daemon, settings_from_config

    settings = settings_from_config(default_config())
    settings.diagnosis = True
    # no except: a diagnoser that cannot be built is a defect to see, not "pending"
    diagnoser = Daemon._make_diagnoser(
        SimpleNamespace(settings=settings),  # type: ignore[arg-type]  # a stand-in self
        certmod.load_default(),
    )
    return hasattr(diagnoser, "faults") and callable(getattr(diagnoser, "verdict", None))


class DaemonHost:
    """The feeder's view of the daemon: its status lines say when the port is open and how
    many bytes it has read."""

    def __init__(self, daemon: DaemonProcess) -> None:
        self.daemon = daemon

    def wait_connected(self, after_wall_s: float, timeout_s: float) -> float | None:
        """Wall time of the first status after ``after_wall_s`` with link ``connected``."""
        found = self.daemon.wait_record(
            lambda r: r.wall_s >= after_wall_s and r.status.get("link") == "connected",
            timeout_s,
            since=0,
        )
        return None if found is None else found[1].wall_s

    def wait_bytes_read(self, n: int, timeout_s: float) -> bool:
        """True once a status shows at least ``n`` bytes read."""
        found = self.daemon.wait_record(
            lambda r: r.status["counters"]["bytes"] >= n,
            timeout_s,
            since=0,
        )
        return found is not None


def daemon_args(
    config_path: Path,
    link: Path,
    certificate: str | None,
    diagnosis: bool,
    aiding_url: str | None = None,
    device: str = "native",
    rate_hz: float = 0.0,
) -> list[str]:
    """Command-line arguments of ``imudiag run`` for a bench run (the source URL of
    ``device`` on ``link``, samples at ``rate_hz``)."""
    source = SOURCE_URLS[device].format(path=link, rate=rate_hz)
    args = ["--config", str(config_path), "--source", source, "--status", "-"]
    if aiding_url:
        args += ["--aiding", aiding_url]
    if certificate:
        args += ["--certificate", certificate]
    if not diagnosis:
        args.append("--no-diagnosis")
    return args


def make_board(scenario: BenchScenario) -> SimulatedBoard:
    """The simulated board of ``scenario`` with its sensor faults."""
    cert = certmod.load(scenario.certificate) if scenario.certificate else certmod.load_default()
    return SimulatedBoard(
        cert,
        scenario_motion(scenario.motion, scenario.seed, scenario.motion_params),
        seed=scenario.seed,
        effects=parse_effects(scenario.effects),
        faults=[i.fault() for i in scenario.sensor_injections],
        duration_s=scenario.duration_s,
    )


def make_gnss_feed(scenario: BenchScenario, workdir: Path) -> gnss.GnssFeed | None:
    """The gpsd fed the drive's GNSS stream (not started), or None without ``aiding:``."""
    if scenario.aiding is None:
        return None
    motion = scenario_motion(scenario.motion, scenario.seed, scenario.motion_params)
    assert isinstance(motion, DriveMotion)  # the scenario's rules: aiding needs a drive
    return gnss.GnssFeed(motion, scenario.aiding.gnss_config(), scenario.seed, workdir)


@dataclass
class BenchRun:
    """Everything a bench run produced: the report, the daemon (its status records and
    stderr), the feeder (what was sent and injected, the board's pace)."""

    scenario: BenchScenario
    report: dict[str, Any]
    daemon: DaemonProcess
    feeder: BoardFeeder
    exit_status: int

    @property
    def records(self) -> list[StatusRecord]:
        """The daemon's status lines with their arrival times."""
        return self.daemon.records


def run_scenario(
    scenario: BenchScenario,
    diagnosis: bool | None = None,
    workdir: str | Path | None = None,
    extra_args: Sequence[str] = (),
    python: str = sys.executable,
    wall_bounds: bool = True,
) -> BenchRun:
    """Run ``scenario``: the daemon as a subprocess, the board behind a pty; judge it.

    diagnosis: None runs the window diagnosis when the daemon can; False never;
    True requires it (BenchError if it is not available). ``extra_args`` go to
    ``imudiag run`` (e.g. a second ``--status`` sink). ``wall_bounds=False`` judges the
    outages on their events only and reports their wall-clock figures (the test suite's
    real-time tier, whose verdicts must not depend on the machine's load).
    """
    available = diagnosis_available()
    if diagnosis and not available:
        raise BenchError(
            "the streaming diagnosis (imudiag.diagnosis.StreamingDiagnoser) is "
            "not available to the daemon in this build"
        )
    use_diagnosis = available if diagnosis is None else bool(diagnosis)
    if scenario.aiding is not None:
        gnss.require()  # before anything runs: exit 2 naming the packages
    with tempfile.TemporaryDirectory(prefix="imudiag-bench-", dir=workdir) as tmp:
        tmp_path = Path(tmp)
        config_path = tmp_path / "daemon.yaml"
        config_path.write_text(yaml.safe_dump(scenario.daemon, sort_keys=False))
        link = tmp_path / "imu0"
        board = make_board(scenario)
        certificate, encoder = scenario.certificate, None
        if scenario.device != "native":  # the device's output obeys its own certificate
            cert = certmod.load(certificate) if certificate else certmod.load_default()
            encoder = make_encoder(scenario.device, cert)
            certificate = str(tmp_path / f"{scenario.device}-certificate.yaml")
            encoder.certificate.save(certificate)
        feed = make_gnss_feed(scenario, tmp_path)
        feeder = BoardFeeder(
            board,
            link,
            scenario.transport_injections,
            scenario.speed,
            chunk_s=scenario.chunk_s,
            seed=scenario.seed,
            after_write=None if feed is None else feed.send_until,
            encoder=encoder,
        )
        t_start = time.monotonic()
        try:
            if feed is not None:
                feed.start()
            feeder.plug()
            args = daemon_args(
                config_path,
                link,
                certificate,
                use_diagnosis,
                None if feed is None else feed.url,
                scenario.device,
                board.rate_hz,
            )
            daemon = DaemonProcess([*args, *extra_args], python=python)
            try:
                exit_status = _play(scenario, feeder, daemon)
            finally:
                daemon.kill()
        finally:
            feeder.close()
            if feed is not None:
                feed.close()
        wall_s = time.monotonic() - t_start
    result = Evaluation(
        scenario,
        daemon.records,
        feeder.records,
        use_diagnosis,
        board.rate_hz,
        sent={"bytes": feeder.bytes_sent, "frames": feeder.sample_frames_sent},
        pace=feeder.pace,
        wall_bounds=wall_bounds,
    ).report()
    problems = []
    if exit_status != 0:
        problems.append(f"daemon exit status {exit_status} on SIGTERM")
    if daemon.bad_lines:
        problems.append(f"{len(daemon.bad_lines)} status lines were not JSON objects")
    report: dict[str, Any] = {
        **header(REPORT_FORMAT),
        "scenario": scenario.name,
        "source": scenario.source,
        "device": scenario.device,
        "description": scenario.description,
        "seed": scenario.seed,
        "speed": scenario.speed,
        "duration_s": scenario.duration_s,
        "diagnosis": use_diagnosis,
        "diagnosis_available": available,
        "wall_s": round(wall_s, 2),
        "status_lines": len(daemon.records),
        "daemon": {
            "exit_status": exit_status,
            "problems": problems,
            "stderr_tail": daemon.stderr_tail(1000) if problems else "",
        },
        **result,
    }
    report["passed"] = bool(result["passed"] and not problems)
    return BenchRun(scenario, report, daemon, feeder, exit_status)


def run_bench(
    scenario: BenchScenario,
    diagnosis: bool | None = None,
    workdir: str | Path | None = None,
    wall_bounds: bool = True,
) -> dict[str, Any]:
    """Run ``scenario`` and return its report (``format`` imudiag-bench/1, docs/bench.md);
    ``wall_bounds`` as for :func:`run_scenario`."""
    return run_scenario(scenario, diagnosis, workdir, wall_bounds=wall_bounds).report


def _play(scenario: BenchScenario, feeder: BoardFeeder, daemon: DaemonProcess) -> int:
    """Feed the whole session, wait for the daemon to process it, stop it; its exit status."""
    wall_budget = (
        scenario.duration_s / scenario.speed
        + sum(i.outage_s or 0.0 for i in scenario.transport_injections)
        + 30.0
    )
    feeder.start(DaemonHost(daemon))
    deadline = time.monotonic() + wall_budget
    while not feeder.join(0.2):
        if daemon.proc.poll() is not None:
            feeder.stop()
            raise BenchError(
                f"the daemon exited with status {daemon.proc.returncode} "
                f"during the run; stderr: {daemon.stderr_tail()}"
            )
        if time.monotonic() > deadline:
            raise BenchError(f"the board did not finish within {wall_budget:.0f} s")
    if feeder.error is not None:
        raise BenchError(
            f"board feeder: {feeder.error}; daemon exit status "
            f"{daemon.proc.poll()}; stderr: {daemon.stderr_tail()}"
        )
    t_last = feeder.t_end_s
    done = daemon.wait_record(  # the last sample is the last frame sent
        lambda r: r.status.get("t") is not None and r.status["t"] >= t_last - 1e-6,
        timeout_s=15.0,
        since=0,
    )
    if done is None:
        raise BenchError(
            f"the daemon did not process the last sample (t = {t_last:.3f} s); "
            f"exit status {daemon.proc.poll()}; stderr: {daemon.stderr_tail()}"
        )
    # a few more steady lines so the final state is on record
    daemon.wait_record(lambda r: r.wall_s > done[1].wall_s + 0.25, 2.0, since=done[0])
    return daemon.stop(signal.SIGTERM)


__all__ = [
    "BenchError",
    "BenchRun",
    "DaemonHost",
    "daemon_args",
    "diagnosis_available",
    "make_board",
    "make_gnss_feed",
    "run_bench",
    "run_scenario",
]

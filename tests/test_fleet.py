"""imudiag fleet (issue 28, docs/fleet.md): a small simulated fleet of short logs diagnosed
on a real two-worker Dask LocalCluster; every drifting unit ranked with its parameter, no
steady unit; every corrupt file a row with its reason; a real ``imudiag fleet`` killed
after its first records resumes to the same table; the report opened in real headless
Chromium."""

from __future__ import annotations

import json
import logging
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import PROJECT_DIR, run_imudiag_without

from imudiag.certificate import default_certificate_path
from imudiag.fleet.records import RECORDS, read_records
from imudiag.fleet.simulate import simulate_fleet
from imudiag.fleet.task import Job, diagnose_log
from imudiag.reports import FLEET_FORMAT

#: the real-time tier (tests/conftest.py):
#: a real Dask LocalCluster, killed fleet processes and a headless browser
pytestmark = pytest.mark.realtime

pytest.importorskip("dask.distributed", reason="the fleet extra (dask[distributed]) is needed")
pytest.importorskip("pyarrow", reason="the fleet extra (pyarrow) is needed")

VEHICLES, FLIGHTS = 4, 4


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    """4 vehicles x 4 flights of 30-36 s, two of them drifting, 3 corrupt files; the bundled
    certificate in one vehicle's folder and a map naming another's."""
    root = tmp_path_factory.mktemp("fleet") / "flights"
    truth = simulate_fleet(root, VEHICLES, FLIGHTS, seed=11, drifting=2, seconds=(30.0, 36.0))
    shutil.copy(default_certificate_path(), root / "unit-02" / "certificate.yaml")
    named = truth["vehicles"][2]["vehicle"]
    (root / "map.yaml").write_text(f"{named}: {default_certificate_path()}\n")
    return root, truth


@pytest.fixture(scope="module")
def two_workers(fleet: tuple[Path, dict], tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The fleet run by the library on a real LocalCluster of two worker processes, reached
    through its scheduler's address as an existing cluster is (``--scheduler``; the
    command's own LocalCluster runs in the resume test)."""
    from dask.distributed import LocalCluster

    import imudiag.fleet

    root, _ = fleet
    out = tmp_path_factory.mktemp("out")
    with LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    ) as cluster:
        records = imudiag.fleet.run(
            [str(root)],
            out,
            scheduler=cluster.scheduler_address,
            certificates=str(root / "map.yaml"),
            timeout_s=300,
        )
    assert len(records) == len(read_records(out))
    return out


def test_two_worker_cluster_ranks_the_drifting_units(
    fleet: tuple[Path, dict], two_workers: Path
) -> None:
    root, truth = fleet
    summary = json.loads((two_workers / "fleet.json").read_text())
    assert (summary["class"], summary["format"]) == ("FLEET", FLEET_FORMAT)
    records = read_records(two_workers)
    assert len({r["worker_pid"] for r in records if "worker_pid" in r}) == 2  # both worked
    by_name = {v["vehicle"]: v for v in summary["vehicles"]}
    assert set(by_name) == {v["vehicle"] for v in truth["vehicles"]}
    drifting = {v["vehicle"]: v["drifting"] for v in truth["vehicles"] if v["drifting"]}
    assert len(drifting) == 2
    assert set(summary["look_at"]) == set(drifting)  # every drifting unit, no steady one
    for name, drift in drifting.items():
        v = by_name[name]
        assert v["look_at"] is True
        top = v["reasons"][0]
        assert (top["triad"], top["sensor"], top["cause"]) == (
            drift["triad"],
            drift["sensor"],
            drift["cause"],
        )
        assert [(r["sensor"], r["cause"]) for r in v["reasons"]] == [
            (drift["sensor"], drift["cause"])
        ]
        assert top["unit"] == drift["unit"]
        # the sign and size of the drift per log: the simulated step is within 3 std
        step = drift["offsets"][1] - drift["offsets"][0]
        assert abs(top["slope"]["per_log"] - step) < 3 * top["slope_std"]["per_log"]
        assert top["slope"]["per_day"] is not None and top["slope_std"]["per_day"] > 0
        # the simulated offsets pass the limit between two flights; the first flagged
        # flight is the first whose offset is beyond it
        first = next(k for k, o in enumerate(drift["offsets"]) if abs(o) > drift["limit"])
        assert top["crosses_limit_index"] in (first, first + 1)
    for v in summary["vehicles"]:
        assert v["logs"] >= FLIGHTS
        if v["vehicle"] not in drifting:
            assert v["look_at"] is False and v["reasons"] == []


def test_every_corrupt_file_is_a_row_with_its_reason(
    fleet: tuple[Path, dict], two_workers: Path
) -> None:
    root, truth = fleet
    records = {Path(r["path"]).relative_to(root).as_posix(): r for r in read_records(two_workers)}
    corrupt = {c["path"] for c in truth["corrupt"]}
    assert len(corrupt) == 3
    errors = {k for k, r in records.items() if r["status"] == "error"}
    assert errors == corrupt
    for path in corrupt:
        reason = records[path]["reason"]
        assert path.split("/")[-1] in reason and len(reason) > 20
    summary = json.loads((two_workers / "fleet.json").read_text())
    assert sorted(Path(e["path"]).name for e in summary["errors"]) == sorted(
        Path(p).name for p in corrupt
    )
    flights = sum(len(v["flights"]) for v in truth["vehicles"])
    assert summary["logs"] == flights + 3 and summary["ok"] == flights


def test_records_carry_the_contract(fleet: tuple[Path, dict], two_workers: Path) -> None:
    root, truth = fleet
    import pyarrow.parquet as pq

    records = read_records(two_workers)
    for r in records:
        for key in ("path", "vehicle", "start", "status", "reason"):
            assert key in r
        if r["status"] == "ok":
            assert r["report"]["class"] == "DIAGNOSIS" and r["reason"] is None
            assert r["start"].startswith("2026-")
    sources = {
        Path(r["path"]).parent.name: r["certificate_source"] for r in records if r["status"] == "ok"
    }
    assert sources["unit-02"] == "certificate.yaml in the vehicle's folder"
    assert sources["unit-03"].startswith("--certificates ")
    assert sources["unit-01"].startswith("bundled")
    named = {r["vehicle_source"] for r in records if r["status"] == "ok"}
    assert named == {"log metadata 'vehicle'", "folder name (the log names no vehicle)"}
    table = pq.read_table(two_workers / "logs.parquet")
    assert table.num_rows == len(records)
    assert sorted(table.column("path").to_pylist()) == sorted(r["path"] for r in records)


class DirectoryWatch:
    """Linux inotify on a folder: :meth:`wait` returns when a file in it is created, written
    or closed (or after ``bound_s``, so the caller can look at its process again)."""

    IN_MODIFY, IN_CLOSE_WRITE, IN_CREATE = 0x2, 0x8, 0x100

    def __init__(self, folder: Path) -> None:
        import ctypes

        self.libc = ctypes.CDLL(None, use_errno=True)
        self.fd = self.libc.inotify_init1(os.O_NONBLOCK | os.O_CLOEXEC)
        if self.fd < 0:
            pytest.skip("no inotify on this system")
        mask = self.IN_MODIFY | self.IN_CLOSE_WRITE | self.IN_CREATE
        if self.libc.inotify_add_watch(self.fd, str(folder).encode(), mask) < 0:
            raise OSError(ctypes.get_errno(), f"inotify_add_watch {folder}")

    def wait(self, bound_s: float = 2.0) -> None:
        import select

        ready, _, _ = select.select([self.fd], [], [], bound_s)
        if ready:
            try:
                os.read(self.fd, 65536)
            except BlockingIOError:
                pass

    def close(self) -> None:
        os.close(self.fd)


def _lines(path: Path) -> int:
    try:
        return path.read_bytes().count(b"\n")
    except FileNotFoundError:
        return 0


def test_the_first_logs_are_diagnosed_while_the_last_is_still_hashed(
    fleet: tuple[Path, dict], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Each log is submitted once hashed (imudiag/fleet/feed.py), largest first: the hash of
    the smallest log (the last) is held until the first record is written, which a run that
    hashed every log before its first task could never write."""
    import threading

    import imudiag.fleet
    import imudiag.fleet.runner as runner

    root, _ = fleet
    logs = sorted((root / "unit-01").glob("flight-00[123].*"), key=lambda p: p.stat().st_size)
    assert len(logs) == 3 and logs[0].stat().st_size < logs[1].stat().st_size
    last = str(logs[0].absolute())
    first_record = threading.Event()
    held: list[bool] = []
    describe = runner.describe

    def held_describe(path: Path, known: dict | None = None):  # type: ignore[no-untyped-def]
        if str(path) == last:
            held.append(first_record.wait(300))  # a bound never reached: the run's own end
        return describe(path, known)

    monkeypatch.setattr(runner, "describe", held_describe)
    records = imudiag.fleet.run(
        [str(p) for p in logs], tmp_path, workers=1, on_record=lambda r: first_record.set()
    )
    assert held == [True]
    assert sorted(r["path"] for r in records) == sorted(str(p.absolute()) for p in logs)
    written = read_records(tmp_path)
    assert written[-1]["path"] == last and all(r["status"] == "ok" for r in written)


def test_two_copies_of_one_log_are_diagnosed_once(fleet: tuple[Path, dict], tmp_path: Path) -> None:
    """The same content under two names (a log copied into another folder) is one task and
    one record: the copy found later, once hashed, is skipped, and the progress's total
    drops to the logs left."""
    import imudiag.fleet

    root, _ = fleet
    original = next(iter(sorted((root / "unit-03").glob("flight-001.*"))))
    other = next(iter(sorted((root / "unit-04").glob("flight-002.*"))))
    copy = tmp_path / "copies" / ("again" + "".join(original.suffixes))
    copy.parent.mkdir()
    shutil.copyfile(original, copy)
    seen: list[tuple[str, float | None, int]] = []
    records = imudiag.fleet.run(
        [str(original), str(other), str(copy)],
        tmp_path / "out",
        workers=1,
        progress=lambda what, fraction, done: seen.append((what, fraction, done)),
    )
    assert len(records) == 2
    assert {r["path"] for r in records} == {str(original.absolute()), str(other.absolute())}
    assert seen[-1] == ("2/2 logs", 1.0, 2)


def test_a_killed_run_resumes_to_the_same_table(
    fleet: tuple[Path, dict], two_workers: Path, tmp_path: Path
) -> None:
    """A real ``imudiag fleet`` killed (SIGKILL to its process group: the command, the
    Dask scheduler in it, the nannies and workers) once its first records are on disk; the
    same command again skips what was recorded and ends with the table of the clean run."""
    root, _ = fleet
    out = tmp_path / "out"
    out.mkdir()
    cmd = [sys.executable, "-m", "imudiag", "fleet", str(root), "--out", str(out)]
    cmd += ["--workers", "1", "--certificates", str(root / "map.yaml"), "--quiet"]
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    proc = subprocess.Popen(
        cmd,
        cwd=PROJECT_DIR,
        env=env,
        start_new_session=True,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    watch = DirectoryWatch(out)  # wait on the folder's changes, not on a clock
    try:
        while _lines(out / RECORDS) < 2 and proc.poll() is None:
            watch.wait()
        assert proc.poll() is None, proc.communicate()
    finally:
        watch.close()
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    first = read_records(out)
    total = len(read_records(two_workers))
    assert 2 <= len(first) < total
    assert not (out / "fleet.json").exists()
    resumed = subprocess.run(
        cmd, cwd=PROJECT_DIR, env=env, capture_output=True, text=True, timeout=600, check=False
    )
    assert resumed.returncode == 0, resumed.stderr
    again = read_records(out)
    clean = {r["sha256"]: r for r in read_records(two_workers)}
    assert sorted(r["sha256"] for r in again) == sorted(clean)
    assert {r["sha256"] for r in first} <= {r["sha256"] for r in again}
    for r in again:
        c = clean[r["sha256"]]
        assert (r["path"], r["vehicle"], r["status"], r["reason"]) == (
            c["path"],
            c["vehicle"],
            c["status"],
            c["reason"],
        )
        assert r.get("parameters") == c.get("parameters")
    s1 = json.loads((out / "fleet.json").read_text())
    s2 = json.loads((two_workers / "fleet.json").read_text())
    assert s1["look_at"] == s2["look_at"] and s1["errors"] == s2["errors"]
    # once more: everything is recorded, nothing runs, the summary is rebuilt the same
    third = subprocess.run(
        cmd, cwd=PROJECT_DIR, env=env, capture_output=True, text=True, timeout=600, check=False
    )
    assert third.returncode == 0, third.stderr
    assert _lines(out / RECORDS) == len(again)
    assert json.loads((out / "fleet.json").read_text())["vehicles"] == s1["vehicles"]


CHROMIUM, CHROMEDRIVER = shutil.which("chromium"), shutil.which("chromedriver")


def test_the_report_renders_in_headless_chromium(
    fleet: tuple[Path, dict], two_workers: Path, tmp_path: Path
) -> None:
    """report.html opened in real headless Chromium (Debian's chromium and chromium-driver,
    installed by .ci/run) through Selenium: the fleet table and the ranked list render, the
    trend figures have a size, the console has no error, and nothing outside the file is
    fetched (every host name resolves to nothing, so a fetch would be a console error)."""
    if not (CHROMIUM and CHROMEDRIVER):
        pytest.skip(
            "no chromium + chromedriver on this machine (Debian: apt-get install "
            "chromium chromium-driver; .ci/run does it as root)"
        )
    webdriver = pytest.importorskip("selenium.webdriver", reason="selenium (test extra)")
    from selenium.webdriver.chrome.service import Service
    from selenium.webdriver.common.by import By

    summary = json.loads((two_workers / "fleet.json").read_text())
    html = (two_workers / "report.html").read_text()
    for outside in ("src=", 'href="http', "@import", "url(", "<script", "<link"):
        assert outside not in html
    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for flag in (
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--no-first-run",
        f"--user-data-dir={tmp_path / 'profile'}",
        "--host-resolver-rules=MAP * ~NOTFOUND",
    ):
        opts.add_argument(flag)
    opts.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    os.environ.setdefault("SE_OFFLINE", "true")  # Selenium Manager: never download a driver
    driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=opts)
    try:
        driver.get((two_workers / "report.html").as_uri())
        assert driver.title == "imudiag fleet report"
        rows = driver.find_elements(By.CSS_SELECTOR, "#fleet tbody tr")
        assert len(rows) == len(summary["vehicles"])
        assert [r.find_element(By.TAG_NAME, "td").text for r in rows] == [
            v["vehicle"] for v in summary["vehicles"]
        ]
        ranked = driver.find_elements(By.CSS_SELECTOR, "#look-at li")
        assert [li.text.split(":")[0] for li in ranked] == summary["look_at"]
        logs = driver.find_elements(By.CSS_SELECTOR, "#logs tbody tr")
        assert len(logs) == summary["logs"]
        figures = driver.find_elements(By.CSS_SELECTOR, "figure svg")
        assert figures and all(f.size["width"] > 100 and f.size["height"] > 100 for f in figures)
        errors = [e for e in driver.get_log("browser") if e["level"] in ("SEVERE", "WARNING")]
        assert errors == []
    finally:
        driver.quit()


def test_without_the_extra_the_command_names_it(tmp_path: Path) -> None:
    r = run_imudiag_without("distributed", "fleet", str(tmp_path), "--out", str(tmp_path / "o"))
    assert r.returncode == 2
    assert "pip install 'imudiag[fleet]'" in r.stderr and len(r.stderr.splitlines()) == 1


def _job(path: Path, **kw: object) -> Job:
    from imudiag.fleet.discovery import describe

    info = describe(path)
    return Job(info.path, info.sha256, info.size, info.mtime_ns, str(path.parent), **kw)


def test_the_task_uses_the_certificate_given_and_stops_at_its_timeout(
    fleet: tuple[Path, dict], tmp_path: Path
) -> None:
    """The per-log task alone (no Dask): ``--certificate`` wins over the folder's
    certificate.yaml and is in the record; a timeout makes an error row with the reason."""
    root, _ = fleet
    log = next((root / "unit-02").glob("flight-001.*"))
    cert = tmp_path / "mine.yaml"
    shutil.copy(default_certificate_path(), cert)
    rec = diagnose_log(_job(log, certificate=str(cert)))
    assert rec["status"] == "ok" and rec["certificate_source"] == "--certificate"
    assert rec["certificate"] == str(cert)
    assert rec["certificate_sha256"] and rec["parameters"]
    assert "windows" not in rec["report"]
    rec = diagnose_log(_job(log))
    assert rec["certificate_source"] == "certificate.yaml in the vehicle's folder"
    late = diagnose_log(_job(log, timeout_s=1e-9))
    assert late["status"] == "error" and late["reason"].startswith("timeout: ")
    bad = tmp_path / "bad.yaml"
    bad.write_text("accel: [1, 2\n")
    rec = diagnose_log(_job(log, certificate=str(bad)))
    assert rec["status"] == "error" and rec["reason"].startswith("loading the certificate: ")


def test_a_drive_with_its_gnss_beside_gets_the_moving_base_diagnosis(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A simulated urban drive with its GNSS stream as ``LOG.gnss``: the record's report
    carries the moving-base section equal to ``imudiag diagnose LOG --gnss GNSS``'s (run
    with the window-fit loops the worker ran: the compiled ones where numba is installed;
    with the plain ones, equal within the reports' cross-processor tolerance), its start is
    the first sample's UTC time, and its vehicle is its folder (said so)."""
    from conftest import run_imudiag

    log = tmp_path / "car-7" / "drive.npz"
    log.parent.mkdir()
    gnss = Path(f"{log}.gnss")
    r = run_imudiag(
        "simulate",
        "urban",
        "--param",
        "length=120",
        "--seed",
        "4",
        "--out",
        str(log),
        "--gnss",
        str(gnss),
        "-q",
    )
    assert r.returncode == 0, r.stderr
    rec = diagnose_log(_job(log))
    assert rec["status"] == "ok" and rec["gnss"] == str(gnss)
    assert (rec["vehicle"], rec["vehicle_source"]) == (
        "car-7",
        "folder name (the log names no vehicle)",
    )
    assert rec["start"] == "2026-01-01T00:00:00+00:00"
    out = tmp_path / "report.json"
    if rec["kernels"] == "numba":
        monkeypatch.setenv("IMUDIAG_KERNELS", "numba")
    r = run_imudiag("diagnose", str(log), "--gnss", str(gnss), "--json", str(out))
    assert r.returncode == 0, r.stderr
    assert rec["report"]["moving_base"] == json.loads(out.read_text())["moving_base"]
    if rec["kernels"] == "numba":  # and the single process on the plain loops
        from tests.test_diagnose_frozen_reports import hardware_differences

        monkeypatch.setenv("IMUDIAG_KERNELS", "plain")
        r = run_imudiag("diagnose", str(log), "--gnss", str(gnss), "--json", str(out))
        assert r.returncode == 0, r.stderr
        plain = json.loads(out.read_text())["moving_base"]
        diff = hardware_differences(rec["report"]["moving_base"], plain, "moving_base")
        assert not diff, "; ".join(diff[:8])


def test_simulate_fleet_writes_mixed_logs_and_the_truth(tmp_path: Path) -> None:
    from conftest import run_imudiag

    out = tmp_path / "fleet"
    r = run_imudiag(
        "simulate",
        "fleet",
        "--vehicles",
        "2",
        "--flights",
        "4",
        "--drifting",
        "1",
        "--corrupt",
        "2",
        "--flight-seconds",
        "20:22",
        "--seed",
        "5",
        "--out",
        str(out),
        "-q",
    )
    assert r.returncode == 0, r.stderr
    truth = json.loads((out / "truth.json").read_text())
    flights = [f for v in truth["vehicles"] for f in v["flights"]]
    assert len(flights) == 8 and all((out / f["path"]).is_file() for f in flights)
    assert {f["format"] for f in flights} == {".csv", ".npz", ".csv.gz", ".bin"}
    assert {f["type"] for f in flights} == {"multiposition", "static"}
    drifting = [v["drifting"] for v in truth["vehicles"] if v["drifting"]]
    assert len(drifting) == 1 and len(drifting[0]["offsets"]) == 4
    assert abs(drifting[0]["offsets"][-1]) > drifting[0]["limit"] > abs(drifting[0]["offsets"][0])
    assert [c["how"] for c in truth["corrupt"]] == ["truncated", "garbage-row"]
    bad = run_imudiag("simulate", "fleet", "--out", str(tmp_path / "x"))
    assert bad.returncode == 2 and "--vehicles N and --flights M" in bad.stderr


def test_the_local_workers_are_forked_warm_with_the_malloc_and_memory_settings(
    fleet: tuple[Path, dict], tmp_path: Path
) -> None:
    """The local workers are forked from a forkserver that has loaded what every worker
    keeps (:data:`imudiag.fleet.runner.FORKSERVER_PRELOAD`) and runs no thread but its own
    (Arrow's allocator thread off: nothing holds a lock as it forks); before any task each
    worker holds the diagnosis' modules and the compiled kernels, and its first log's
    warm-up has nothing left to load. A worker's own environment holds Dask's trimming
    and the mmap threshold the runner adds (:data:`~imudiag.fleet.runner.WORKER_MALLOC`,
    tests/test_fleet_warm.py), its Dask configuration the eased monitoring (:data:`~imudiag.
    fleet.runner.QUIET_MONITORING`: the dashboard is off) and no pause (:data:`~imudiag.
    fleet.runner.WORKER_MEMORY`), and it gives its free heap back after a log above half its
    memory limit; the scheduler gives each worker one log at a time (:data:`~imudiag.fleet.
    runner.ONE_LOG_PER_WORKER`)."""
    import glob
    import sys

    import dask
    from dask.distributed import Client

    import imudiag.fleet
    from imudiag.fleet.allocator import RELEASE_ABOVE_BYTES
    from imudiag.fleet.runner import (
        ONE_LOG_PER_WORKER,
        QUIET_MONITORING,
        WORKER_MEMORY,
        local_cluster,
        worker_start_method,
    )
    from imudiag.fleet.task import release_mark

    def state() -> dict:
        import imudiag.fleet.task as task
        from imudiag.kernels import _STATE

        return {
            "ppid": os.getppid(),
            "preloaded": "imudiag.fleet.forkserver" in sys.modules,
            "modules": all(name in sys.modules for name in task.WARM_MODULES),
            "kernels": _STATE["loaded"],
            "mark": task.release_mark(),
        }

    assert worker_start_method() == "forkserver"
    assert release_mark() == RELEASE_ABOVE_BYTES  # not in a worker: no limit to go by
    names = ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_", "MALLOC_ARENA_MAX")
    keys = [*QUIET_MONITORING, *WORKER_MEMORY, "distributed.worker.multiprocessing-method"]
    with local_cluster(2, "1GiB") as cluster, Client(cluster) as client:
        seen = list(client.run(lambda: {k: os.environ.get(k) for k in names}).values())
        settings = list(client.run(lambda: {k: dask.config.get(k) for k in keys}).values())
        states = list(client.run(state).values())
        servers = {s["ppid"] for s in states}
        threads = {pid: len(glob.glob(f"/proc/{pid}/task/*")) for pid in servers}
        saturation = client.run_on_scheduler(
            lambda dask_scheduler: dask_scheduler.WORKER_SATURATION
        )
        (record,) = imudiag.fleet.run(
            sorted(str(p) for p in (fleet[0] / "unit-01").glob("flight-001.*")),
            tmp_path,
            scheduler=cluster.scheduler_address,
        )
    malloc = {
        "MALLOC_MMAP_THRESHOLD_": "33554432",
        "MALLOC_TRIM_THRESHOLD_": "65536",
        "MALLOC_ARENA_MAX": "1",
    }
    assert seen == [malloc, malloc]
    expected = {
        **QUIET_MONITORING,
        "distributed.worker.memory.pause": False,
        "distributed.worker.multiprocessing-method": "forkserver",
    }
    assert settings == [expected, expected]
    assert QUIET_MONITORING["distributed.worker.profile.enabled"] is False
    # one log at a time on a worker: no log queued behind one that kills it is counted
    assert saturation == ONE_LOG_PER_WORKER["distributed.scheduler.worker-saturation"] == 1.0
    assert len(servers) == 1 and os.getpid() not in servers  # both forked from one server
    assert threads == {next(iter(servers)): 1}
    warm = {"ppid": next(iter(servers)), "preloaded": True, "modules": True, "kernels": True}
    assert states == [{**warm, "mark": 2**29}, {**warm, "mark": 2**29}]  # half of 1 GiB
    assert record["status"] == "ok" and record["kernels"] == "numba"
    assert record["warm_up_cpu_s"] < 0.05  # nothing left to load: the first parse only


def test_a_log_that_kills_its_worker_is_a_row_with_the_reason(
    fleet: tuple[Path, dict], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A worker of an existing cluster (spawned, as Dask starts them) whose memory limit,
    150 MiB, is below what a fleet task needs (an idle worker holds about 65 MB, the first
    task's warm-up loads the compiled kernels, about 230 MB in all) is killed by its nanny
    while running the log. The scheduler tries the log on as many workers as its own
    configuration says (``allowed-failures``: 2 here, whatever ``retries`` the client
    asks, which only a local cluster takes), and the record names that count; the run
    itself ends normally with its summary. (imudiag's own local workers start warm, so
    the least limit it takes, :data:`imudiag.fleet.runner.MIN_MEMORY_LIMIT`, is above an
    idle worker's: tests/test_option_validation.py, and below.)"""
    import dask
    from dask.distributed import LocalCluster

    import imudiag.fleet
    from imudiag import kernels

    assert kernels.available(), "the fleet extra installs numba; the kill needs its kernels"
    monkeypatch.delenv("IMUDIAG_KERNELS", raising=False)  # the workers load the kernels
    root, _ = fleet
    logs = sorted(str(p) for p in (root / "unit-02").glob("flight-001.*"))
    assert len(logs) == 1
    with (
        dask.config.set({"distributed.scheduler.allowed-failures": 2}),
        LocalCluster(
            n_workers=1,
            threads_per_worker=1,
            memory_limit="150MiB",
            dashboard_address=None,
            silence_logs=logging.CRITICAL,
        ) as cluster,
    ):
        records = imudiag.fleet.run(logs, tmp_path, scheduler=cluster.scheduler_address, retries=1)
    assert [r["path"] for r in records] == logs
    (r,) = records
    assert r["status"] == "error"
    assert r["reason"] == "killed its worker 3 time(s) (the worker memory limit, or a crash)"
    summary = json.loads((tmp_path / "fleet.json").read_text())
    assert summary["ok"] == 0 and len(summary["errors"]) == 1


def test_a_run_at_the_least_memory_limit_diagnoses_its_logs_one_after_another(
    fleet: tuple[Path, dict], tmp_path: Path
) -> None:
    """At :data:`imudiag.fleet.runner.MIN_MEMORY_LIMIT` one local worker, forked warm from
    the forkserver (about 180 MB resident, most of it shared), is neither restarted before
    its first log nor paused after one (Dask pauses a worker past 80 % of its limit, and the
    heap a log leaves kept it there: the run hung), and diagnoses the logs in turn. The
    command is a real process with a deadline: a hang fails the test."""
    from conftest import run_imudiag

    from imudiag.fleet.runner import MIN_MEMORY_LIMIT

    root, _ = fleet
    logs = sorted(str(p) for p in (root / "unit-03").glob("flight-00[1-3].*"))
    assert len(logs) == 3
    r = run_imudiag(
        "fleet",
        *logs,
        "--out",
        str(tmp_path),
        "--workers",
        "1",
        "--quiet",
        "--memory-limit",
        f"{MIN_MEMORY_LIMIT // 2**20}MiB",
        timeout=120,
    )
    assert r.returncode == 0, r.stderr
    records = read_records(tmp_path)
    assert sorted(rec["path"] for rec in records) == logs
    assert [rec["status"] for rec in records] == ["ok"] * 3, [rec["reason"] for rec in records]

"""A fleet worker pays its imports and its certificate parsing once (issue 28's per-log CPU in
a warm worker): the first task's :func:`imudiag.fleet.task.warm_up` imports everything a
per-log task imports, outside the log's ``cpu_s`` (``warm_up_cpu_s``), and
:func:`~imudiag.fleet.task.load_certificate_once` parses a certificate file once while it is
unchanged, each log getting its own copy. No Dask needed: the task is called as a worker
calls it, in a fresh interpreter."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from imudiag.errors import ImudiagError
from imudiag.fleet import task

ROOT = Path(__file__).resolve().parent.parent
CERT = ROOT / "config" / "default-certificate.yaml"

CHILD = """
import json, sys
from pathlib import Path
from imudiag.certificate import load_default
from imudiag.logs import open_writer
from imudiag.sim import multi_position, simulate
from imudiag.fleet import task

log = Path(sys.argv[1])
sim = simulate(load_default(), multi_position(n_attitudes=12, dwell_s=3.0, rate_hz=100, seed=4),
               seed=5)
with open_writer(log, {"sample_rate": 100, "units": "gyro=count accel=count"}) as w:
    w.write(sim.samples)
st = log.stat()
job = task.Job(str(log), "-", st.st_size, st.st_mtime_ns, str(log.parent))
first = task.diagnose_log(job)
task.warm_up()
before = {m for m in sys.modules if m.startswith("imudiag")}
second = task.diagnose_log(job)
after = {m for m in sys.modules if m.startswith("imudiag")}
print(json.dumps({"status": [first["status"], second["status"]], "reason": first["reason"],
                  "warm": [first["warm_up_cpu_s"], second["warm_up_cpu_s"]],
                  "new": sorted(after - before)}))
"""


def test_a_warm_worker_imports_nothing_more_for_a_log(tmp_path):
    out = subprocess.run(
        [sys.executable, "-c", CHILD, str(tmp_path / "flight.npz")],
        check=True,
        capture_output=True,
        text=True,
        cwd=ROOT,
        env={**os.environ, "OPENBLAS_NUM_THREADS": "1"},
    )
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["status"] == ["ok", "ok"], got["reason"]
    assert got["warm"][0] > 0.0 and got["warm"][1] < got["warm"][0]
    assert got["new"] == []  # warm_up imported everything a log needs


def test_a_certificate_is_parsed_once_while_its_file_is_unchanged(tmp_path, monkeypatch):
    path = tmp_path / "certificate.yaml"
    path.write_text(CERT.read_text())
    parsed = []
    monkeypatch.setattr(task, "_CERTIFICATES", {})
    from imudiag import api

    original = api.load_certificate

    def counted(p=None):
        parsed.append(p)
        return original(p)

    monkeypatch.setattr(api, "load_certificate", counted)
    a = task.load_certificate_once(str(path))
    b = task.load_certificate_once(str(path))
    assert len(parsed) == 1
    assert a is not b and a.accel is not b.accel  # each log its own copy
    np.testing.assert_array_equal(a.accel.bias, b.accel.bias)
    a.accel.bias[0] += 1.0  # a log that changed its copy changes no other log's
    assert task.load_certificate_once(str(path)).accel.bias[0] == b.accel.bias[0]
    # the file changed: parsed again
    path.write_text(path.read_text() + "\n# edited\n")
    st = path.stat()
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000))
    task.load_certificate_once(str(path))
    assert len(parsed) == 2
    # the bundled one (None) is cached too
    task.load_certificate_once(None)
    task.load_certificate_once(None)
    assert parsed.count(None) == 1


def test_a_missing_certificate_is_its_own_error(tmp_path):
    with pytest.raises(ImudiagError) as err:
        task.load_certificate_once(str(tmp_path / "nope.yaml"))
    assert "nope.yaml" in str(err.value)


def test_local_workers_keep_glibcs_mmap_threshold_under_dasks_trimming() -> None:
    """Dask's nanny spawns workers with ``MALLOC_TRIM_THRESHOLD_=65536``, which also fixed
    glibc's mmap threshold at 128 KiB (every larger numpy array mapped and faulted in anew:
    about 1.6x a task's CPU); the local workers get the 32 MiB glibc's own threshold slides
    up to, beside Dask's settings, and a user's own setting wins. (The spawned workers'
    environment: tests/test_fleet.py, real-time tier.)"""
    import dask

    from imudiag.fleet.runner import WORKER_MALLOC, worker_environment

    env = worker_environment()
    assert env["MALLOC_MMAP_THRESHOLD_"] == WORKER_MALLOC["MALLOC_MMAP_THRESHOLD_"] == "33554432"
    assert str(env["MALLOC_TRIM_THRESHOLD_"]) == "65536"  # Dask's own, kept
    assert str(env["OPENBLAS_NUM_THREADS"]) == "1"
    assert env["MALLOC_ARENA_MAX"] == WORKER_MALLOC["MALLOC_ARENA_MAX"] == "1"
    mine = {"MALLOC_MMAP_THRESHOLD_": "1048576"}
    with dask.config.set({"distributed.nanny.pre-spawn-environ": mine}):
        assert worker_environment() == {
            "MALLOC_MMAP_THRESHOLD_": "1048576",
            "MALLOC_ARENA_MAX": "1",
            "JE_ARROW_MALLOC_CONF": "background_thread:false",
        }


def test_the_monitoring_is_eased_only_where_nothing_shows_it_and_the_user_set_nothing() -> None:
    """Dask's profiler, event-loop check and system monitor feed the dashboard: a local
    cluster without one runs them less (:data:`QUIET_MONITORING`), with ``--dashboard`` as
    Dask ships them, and a key the user's Dask configuration sets (to other than Dask's
    default: the two are one value to Dask) keeps the user's value."""
    import dask

    from imudiag.fleet.runner import QUIET_MONITORING, monitoring_config

    assert monitoring_config(dashboard=False) == QUIET_MONITORING
    assert QUIET_MONITORING["distributed.worker.profile.enabled"] is False
    assert monitoring_config(dashboard=True) == {}
    mine = {
        "distributed.admin.tick.interval": "50ms",
        "distributed.admin.system-monitor.interval": 1,
    }
    with dask.config.set(mine):
        eased = monitoring_config(dashboard=False)
    assert eased == {"distributed.worker.profile.enabled": False}


def test_a_warm_worker_freezes_what_it_keeps_for_its_life() -> None:
    """After the warm-up the worker's modules and kernels sit in the collector's permanent
    generation (``gc.freeze``): no collection, nor the worker's exit, traverses them."""
    import gc

    from imudiag.fleet import task

    task.warm_up()
    assert task._FROZEN_IN == os.getpid() and gc.get_freeze_count() > 10_000


def test_a_memory_limit_no_worker_starts_under_is_refused_before_any_work(tmp_path) -> None:
    """The library refuses a size below the 256 MiB floor (the command: tests/
    test_option_validation.py) before it reads a log or starts a cluster; Dask's other
    forms of a limit ("auto", a fraction of the machine's memory, 0: none) pass to Dask."""
    import imudiag.fleet
    from imudiag.errors import BadInput
    from imudiag.fleet.runner import MIN_MEMORY_LIMIT, memory_limit_bytes

    for small in ("60MB", 60e6, MIN_MEMORY_LIMIT - 1):
        with pytest.raises(BadInput, match="below the 256 MiB a fleet worker needs"):
            imudiag.fleet.run([str(tmp_path)], tmp_path / "out", memory_limit=small)
    assert not (tmp_path / "out").exists()
    assert memory_limit_bytes("2GiB") == 2 * 2**30
    assert memory_limit_bytes(MIN_MEMORY_LIMIT) == MIN_MEMORY_LIMIT
    with pytest.raises(BadInput, match="--memory-limit 'lots': expected a size"):
        memory_limit_bytes("lots", "--memory-limit")


def test_the_local_workers_are_forked_unless_the_user_names_a_start_method(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A local cluster forks its workers from a warm forkserver where the platform has one;
    a start method the user's Dask configuration names wins, even Dask's own default
    (``spawn``) set in a ``DASK_`` variable, and then no forkserver is started. (The forked
    workers themselves: tests/test_fleet.py, real-time tier.)"""
    import multiprocessing

    import dask

    from imudiag.fleet.runner import start_forkserver, worker_start_method

    assert "forkserver" in multiprocessing.get_all_start_methods()  # Linux
    monkeypatch.delenv("DASK_DISTRIBUTED__WORKER__MULTIPROCESSING_METHOD", raising=False)
    assert worker_start_method() == "forkserver"
    with dask.config.set({"distributed.worker.multiprocessing-method": "fork"}):
        assert worker_start_method() == "fork"
        assert start_forkserver() is False
    monkeypatch.setenv("DASK_DISTRIBUTED__WORKER__MULTIPROCESSING_METHOD", "spawn")
    assert worker_start_method() == "spawn"
    assert start_forkserver() is False

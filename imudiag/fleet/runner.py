"""The fleet run on Dask's distributed scheduler: one task per log (:func:`.task.diagnose_log`)
on a LocalCluster of this machine's cores, or on an existing cluster; each record written as
its log completes; the summary and the report rebuilt from all records at the end."""

from __future__ import annotations

import contextlib
import logging
import os
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from ..atomic import write_text_atomic
from ..certificate import AUTO
from ..errors import BadInput
from ..logs.extras import MissingExtra
from .discovery import describe, expand, key_of
from .feed import Feed
from .records import RecordLog, read_records, write_table
from .task import Job, diagnose_log

EXTRA = "fleet"
#: Default per-log timeout, s of wall time.
DEFAULT_TIMEOUT_S = 1800.0
#: Default memory limit of each local worker (Dask's, per worker process).
DEFAULT_MEMORY_LIMIT = "2GiB"
#: The least memory limit of a local worker, bytes (256 MiB): a worker forked from the warm
#: forkserver holds about 180 MB (its resident pages, most shared with the server and the
#: other workers, all counted by the nanny), and a nanny whose worker passes 95 % of its
#: limit restarts it, before it takes a log too, over and over: the run would not end.
MIN_MEMORY_LIMIT = 256 * 2**20
#: Default times a log whose worker died is tried again on another worker.
DEFAULT_RETRIES = 1
SUMMARY = "fleet.json"
REPORT = "report.html"
#: Progress callback: (what, fraction done or None, logs done).
Progress = Callable[[str, float | None, int], None]


def require() -> None:
    """:class:`MissingExtra` (exit 2) naming ``pip install 'imudiag[fleet]'`` when Dask's
    distributed scheduler or pyarrow is missing."""
    for module in ("dask.distributed", "pyarrow.parquet"):
        try:
            __import__(module)
        except ImportError:
            raise MissingExtra(
                f"imudiag fleet needs the Python package {module.split('.')[0]!r}, not "
                f"installed: pip install 'imudiag[{EXTRA}]'"
            ) from None


def load_certificate_map(path: str) -> dict[str, str]:
    """``--certificates MAP.yaml``: vehicle -> certificate path (relative paths are taken
    from the map's folder; ``auto``: the data sheet each log names). BadInput naming the
    file and key otherwise."""
    from ..yamlio import YamlError, parse, read_text

    try:
        doc = parse(read_text(path))
    except YamlError as exc:
        raise BadInput(f"{path}: {exc}") from None
    except OSError as exc:
        raise BadInput(f"{path}: cannot read: {exc.strerror or exc}") from None
    if not isinstance(doc, dict):
        raise BadInput(f"{path}: expected a mapping of vehicle to certificate file")
    base = Path(path).absolute().parent
    out: dict[str, str] = {}
    for vehicle, cert in doc.items():
        if not isinstance(cert, str) or not cert:
            raise BadInput(f"{path}: {vehicle}: expected a certificate file name, got {cert!r}")
        if cert == AUTO:  # the data sheet each of the vehicle's logs names
            out[str(vehicle)] = AUTO
            continue
        p = Path(cert).expanduser()
        p = p if p.is_absolute() else base / p
        if not p.is_file():
            raise BadInput(f"{path}: {vehicle}: no such certificate file: {p}")
        out[str(vehicle)] = str(p)
    return out


#: glibc malloc settings of the local workers, over Dask's nanny environment: Dask sets
#: ``MALLOC_TRIM_THRESHOLD_=65536`` there (so a worker gives freed memory back), which also
#: fixes glibc's mmap threshold at 128 KiB, where it otherwise slides up with use: every
#: numpy array over 128 KiB was mapped anew and its pages faulted in again, about 1.6x the
#: CPU of a task (docs/benchmarks.md, "Fleet"). 32 MiB is the most glibc's own sliding
#: threshold reaches; the trimming stays. One malloc arena: the task's thread otherwise
#: gets an arena of its own, whose heaps (64 MiB at most) are unmapped and mapped again as a
#: log's arrays come and go (7 % of a fleet task's CPU). A setting of the user's Dask
#: configuration wins.
#: Each worker's warm-up then keeps freed memory for the whole log as well, and gives it back
#: after a log past a mark (:mod:`.allocator`: a worker on any scheduler, not only these).
#: Arrow's own allocator (jemalloc, in pyarrow: the CSV reader's) without its background
#: purging thread, which it starts as pyarrow is imported: the forkserver the workers are
#: forked from (:data:`FORKSERVER_PRELOAD`) then runs no thread but its own, so nothing can
#: hold a lock as it forks; the purging is done by the allocating thread (the CSV logs' CPU
#: the same within 2 %, docs/benchmarks.md, "Session 39").
WORKER_MALLOC = {
    "MALLOC_MMAP_THRESHOLD_": str(32 * 2**20),
    "MALLOC_ARENA_MAX": "1",
    "JE_ARROW_MALLOC_CONF": "background_thread:false",
}


def worker_environment() -> dict[str, Any]:
    """The environment a local worker is spawned with (Dask's ``distributed.nanny.
    pre-spawn-environ`` under :data:`WORKER_MALLOC`)."""
    import dask
    import distributed  # noqa: F401 - its defaults join dask's configuration on import

    configured = dask.config.get("distributed.nanny.pre-spawn-environ", default={}) or {}
    return {**WORKER_MALLOC, **configured}


#: Dask's monitoring of a local cluster whose dashboard is off (nothing shows what it
#: gathers), eased: each worker's statistical profiler (a sample of the task thread's stack
#: every 10 ms, holding the GIL), every server's event-loop check (every 20 ms; each second
#: still catches a loop blocked for the 3 s Dask warns at) and the system monitor (CPU,
#: memory and I/O counters every 0.5 s; the nanny's memory limit has its own check every
#: 0.1 s). On two cores they took about a tenth of the CPU the logs left (docs/benchmarks.md,
#: "Session 38"). ``--dashboard`` keeps Dask's defaults; a setting of the user's Dask
#: configuration wins.
QUIET_MONITORING: dict[str, Any] = {
    "distributed.worker.profile.enabled": False,
    "distributed.admin.tick.interval": "1s",
    "distributed.admin.system-monitor.interval": "2s",
}


def monitoring_config(dashboard: bool) -> dict[str, Any]:
    """The settings of :data:`QUIET_MONITORING` a local cluster starts under: none with the
    dashboard on, else each one the user's Dask configuration leaves at Dask's default (a
    key set to that default is the same to Dask)."""
    return {} if dashboard else unless_set_by_user(QUIET_MONITORING)


#: Dask's memory management of a local worker, as a fleet task needs it: no pause. Dask
#: pauses a worker whose memory passes 80 % of its limit until it falls back, which a
#: worker's modules and the heap a log leaves (kept for the next log, :mod:`.allocator`)
#: need not do: with a limit of 400 MiB the worker paused after its first log and the run
#: hung. A task keeps no data in its worker for others, so pausing frees nothing; the
#: nanny still restarts a worker past 95 % of its limit (the log's row then says so).
WORKER_MEMORY: dict[str, Any] = {"distributed.worker.memory.pause": False}
#: One log at a time on each local worker (Dask's ``worker-saturation`` 1.0; Dask's 1.1 gives
#: a one-thread worker a second task to hold in its queue). The scheduler counts a worker's
#: death against every task the worker holds, so a log queued behind one that killed its
#: worker was counted too, and recorded as a killer after ``--retries`` such deaths. The same
#: throughput (2 workers, 200 logs: 12.7-13.1 s against 12.8-13.4 s).
ONE_LOG_PER_WORKER: dict[str, Any] = {"distributed.scheduler.worker-saturation": 1.0}


def unless_set_by_user(settings: dict[str, Any]) -> dict[str, Any]:
    """The keys of ``settings`` that the user's Dask configuration leaves at Dask's default
    (a key set to that default is the same to Dask), with their values."""
    import dask
    import distributed  # noqa: F401 - its defaults join dask's configuration on import

    shipped = dask.config.merge(*dask.config.defaults)
    return {
        key: value
        for key, value in settings.items()
        if dask.config.get(key, default=None) == dask.config.get(key, default=None, config=shipped)
    }


#: The modules a local cluster's forkserver imports before it forks any worker: Dask's
#: worker (as Dask preloads it) and :mod:`.forkserver`, whose import loads what every fleet
#: worker keeps (:func:`.task.preload`). Each worker then starts warm, one load paid for
#: all (on two cores the second worker's own start took about 1 s of CPU from the logs),
#: its pages shared among the workers, and a worker restarted after a kill is back, warm, in
#: about 0.05 s (a spawned one: 0.3-0.4 s, then its warm-up at its first log).
FORKSERVER_PRELOAD = ("distributed", "imudiag.fleet.forkserver")


def worker_start_method() -> str:
    """How a local cluster starts its worker processes: ``forkserver`` (forked from a
    warm server, :data:`FORKSERVER_PRELOAD`) where the platform has it (Linux, macOS) and
    the user's Dask configuration leaves ``distributed.worker.multiprocessing-method`` at
    Dask's default (a file, a ``DASK_`` variable or ``dask.config.set`` naming ``spawn``
    keeps it); else the configured method."""
    import multiprocessing

    import dask
    import distributed  # noqa: F401 - its defaults join dask's configuration on import

    key = "distributed.worker.multiprocessing-method"
    configured = dask.config.get(key)
    shipped = dask.config.get(key, config=dask.config.merge(*dask.config.defaults))
    set_by_user = configured != shipped or _in_user_config(key)
    if set_by_user or "forkserver" not in multiprocessing.get_all_start_methods():
        return str(configured)
    return "forkserver"


def _in_user_config(key: str) -> bool:
    """Whether ``key`` is set in the user's Dask configuration files or ``DASK_``
    environment variables (whatever its value)."""
    import dask

    node: Any = dask.config.collect()
    for part in key.split("."):
        if not isinstance(node, dict):
            return False
        name = dask.config.canonical_name(part, node)  # dashes or underscores
        if name not in node:
            return False
        node = node[name]
    return True


def start_forkserver() -> bool:
    """Start the forkserver the local workers are forked from, where
    :func:`worker_start_method` chooses it, so that it loads :data:`FORKSERVER_PRELOAD`
    while this process goes on (hashing the logs, starting the scheduler); whether it runs.
    It starts under :func:`worker_environment` (set in this process's environment, as
    Dask's nanny sets it before starting each worker), which it keeps for its life. One
    server serves the process: a later local cluster forks its workers from the same one,
    with its modules and environment (a choice of ``IMUDIAG_KERNELS`` made since still
    reaches each task, :func:`local_cluster`)."""
    import multiprocessing
    from multiprocessing import forkserver

    if worker_start_method() != "forkserver":
        return False
    os.environ.update({name: str(value) for name, value in worker_environment().items()})
    # before Dask's own list (Dask sets it on its first use in this process, too late then)
    multiprocessing.get_context("forkserver").set_forkserver_preload(list(FORKSERVER_PRELOAD))
    forkserver.ensure_running()
    return True


@contextlib.contextmanager
def local_cluster(
    workers: int | None, memory_limit: str | float | None, dashboard: bool = False
) -> Iterator[Any]:
    """A LocalCluster of ``workers`` processes (default: this machine's cores), one thread
    each, started (:func:`worker_start_method`) with :func:`worker_environment` under
    :data:`WORKER_MEMORY`, :data:`ONE_LOG_PER_WORKER` and :func:`monitoring_config`, which
    hold for the cluster's life (a worker restarted after a kill starts as the others did);
    closed after the block."""
    import dask
    from dask.distributed import LocalCluster

    # the scheduler always serves /health on 8787 (the dashboard stays off unless asked
    # for); another cluster on the machine moves it to a free port: not worth a warning
    warnings.filterwarnings("ignore", message="Port 8787 is already in use")
    method = worker_start_method()
    settings = {
        "distributed.nanny.pre-spawn-environ": worker_environment(),
        "distributed.worker.multiprocessing-method": method,
        **unless_set_by_user({**WORKER_MEMORY, **ONE_LOG_PER_WORKER}),
        **monitoring_config(dashboard),
    }
    # a choice of kernels made after a forkserver started reaches the forked workers too
    env = {k: os.environ[k] for k in ("IMUDIAG_KERNELS",) if k in os.environ}
    with dask.config.set(settings):
        if method == "forkserver":
            start_forkserver()
        cluster = LocalCluster(
            n_workers=workers or os.cpu_count() or 1,
            threads_per_worker=1,
            processes=True,
            memory_limit=memory_limit,
            dashboard_address=":8787" if dashboard else None,
            silence_logs=logging.ERROR,
            env=env,
        )
        try:
            yield cluster
        finally:
            cluster.close()


@contextlib.contextmanager
def _client(
    scheduler: str | None,
    workers: int | None,
    memory_limit: str | float | None,
    retries: int,
    dashboard: bool,
) -> Iterator[Any]:
    import dask
    from dask.distributed import Client

    for name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(name, "1")  # the workers' numpy: one BLAS thread each
    with dask.config.set({"distributed.scheduler.allowed-failures": retries}):
        if scheduler:
            try:
                client = Client(scheduler, timeout="30s")
            except OSError as exc:
                raise BadInput(f"--scheduler {scheduler}: cannot connect: {exc}") from None
            try:
                yield client
            finally:
                client.close()
            return
        with local_cluster(workers, memory_limit, dashboard) as cluster:
            client = Client(cluster)
            if dashboard:
                print(f"imudiag fleet: dashboard at {client.dashboard_link}", flush=True)
            try:
                yield client
            finally:
                client.close()


def _lost(job: Job, exc: BaseException, retries: int) -> dict[str, Any]:
    """The record of a log whose task failed outside the diagnosis (its worker died)."""
    from .identity import folder_vehicle

    name = type(exc).__name__
    if name == "KilledWorker":
        # the scheduler's own count (an existing cluster's configuration, not --retries)
        tries = int(getattr(exc, "allowed_failures", retries)) + 1
        reason = f"killed its worker {tries} time(s) (the worker memory limit, or a crash)"
    else:
        reason = f"the task failed: {name}: {exc}"
    return {
        "path": job.path,
        "sha256": job.sha256,
        "size": job.size,
        "mtime_ns": job.mtime_ns,
        "vehicle": folder_vehicle(job.path),
        "vehicle_source": "folder name (the log could not be read)",
        "start": None,
        "status": "error",
        "reason": reason,
    }


def rebuild(out: str | Path) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """Rebuild ``logs.parquet``, ``fleet.json`` and ``report.html`` in ``out`` from its
    ``logs.jsonl``; returns the records and the summary."""
    import json

    from .html import write_report
    from .trends import summarize

    records = read_records(out)
    summary = summarize(records)
    write_table(records, out)
    write_text_atomic(Path(out) / SUMMARY, json.dumps(summary, indent=1, allow_nan=False) + "\n")
    write_report(summary, records, Path(out) / REPORT)
    return records, summary


def memory_limit_bytes(value: str | float, where: str = "memory_limit") -> int:
    """A worker memory limit (bytes, or text such as ``"2GiB"`` or ``"500MB"``) in bytes;
    BadInput naming ``where`` when it is not a size or is below :data:`MIN_MEMORY_LIMIT`."""
    from dask.utils import parse_bytes

    try:
        limit = parse_bytes(value)
    except (ValueError, TypeError):
        limit = -1
    if not limit > 0:
        raise BadInput(f"{where} {value!r}: expected a size such as 2GiB or 500MB")
    if limit < MIN_MEMORY_LIMIT:
        raise BadInput(
            f"{where} {value!r}: below the {MIN_MEMORY_LIMIT // 2**20} MiB a fleet worker needs "
            "before its first log (its nanny would restart it over and over)"
        )
    return int(limit)


def run(
    paths: list[str] | str,
    out: str | Path,
    *,
    certificate: str | None = None,
    certificates: str | None = None,
    scheduler: str | None = None,
    workers: int | None = None,
    memory_limit: str | float | None = DEFAULT_MEMORY_LIMIT,
    timeout_s: float | None = DEFAULT_TIMEOUT_S,
    retries: int = DEFAULT_RETRIES,
    dashboard: bool = False,
    redo: bool = False,
    config: dict[str, Any] | None = None,
    progress: Progress | None = None,
    on_record: Callable[[dict[str, Any]], None] | None = None,
) -> list[dict[str, Any]]:
    """Diagnose every log of ``paths`` (files, folders, globs) on Dask and write ``out``
    (docs/fleet.md); returns the table: one record per log, in the order of ``logs.jsonl``.

    Logs already recorded in ``out/logs.jsonl`` (same content hash) are skipped unless
    ``redo``. ``workers``: local worker processes (default: this machine's cores), ignored
    with ``scheduler`` (``tcp://HOST:8786``, an existing cluster that sees the same paths).
    ``memory_limit``: per local worker, bytes or text such as ``"2GiB"`` (at least
    :data:`MIN_MEMORY_LIMIT`), or Dask's other forms (``"auto"``, a fraction of the
    machine's memory, 0 or None: no limit); a log that kills its worker is tried
    ``retries`` more times, then recorded with the reason.
    ``timeout_s``: per log, s of wall time. ``config``: :class:`DiagnosisConfig` fields.
    """
    require()
    if memory_limit not in (None, "auto") and not (
        isinstance(memory_limit, int | float) and 0 <= memory_limit <= 1
    ):  # a size no worker can start under, before any work (Dask's other forms pass)
        memory_limit_bytes(memory_limit)
    if isinstance(paths, str | os.PathLike):
        paths = [os.fspath(paths)]
    if certificate and certificate != AUTO:
        from ..certificate import load

        load(certificate)  # a bad --certificate is bad input, before any work
    cmap = load_certificate_map(certificates) if certificates else {}
    found = expand([os.fspath(p) for p in paths])
    outdir = Path(out)
    outdir.mkdir(parents=True, exist_ok=True)
    roots = {}
    for text in paths:
        p = Path(text)
        if p.is_dir():
            roots[str(p.absolute())] = p.absolute()
    previous = [] if redo else read_records(outdir)
    known: dict[tuple[str, int, int], str] = {
        (r["path"], r["size"], r["mtime_ns"]): r["sha256"]
        for r in previous
        if isinstance(r.get("size"), int) and isinstance(r.get("mtime_ns"), int)
    }
    done = {r["sha256"] for r in previous}

    # the logs by size, largest first (a stat each; a bag's files summed): the last tasks to
    # finish are then short ones, no worker left alone with a long log at the end
    absolute = [log.absolute() for log in found]
    sized = sorted(((log, key_of(log)) for log in absolute), key=lambda item: -item[1][1])
    # logs recorded already as they are now (same path, size and time): no hash to read
    pending = [(log, key) for log, key in sized if known.get(key) not in done]

    def make_jobs() -> Iterator[Job]:
        """The logs to diagnose, largest first, each hashed as it comes (unless known): not
        one already done, nor one twice."""
        queued: set[str] = set()
        for log, _ in pending:
            info = describe(log, known)
            if info.sha256 in done or info.sha256 in queued:
                skipped[0] += 1
                continue
            queued.add(info.sha256)
            root = next(
                (r for r in roots.values() if r == log or r in log.parents),
                log.parent,
            )
            yield Job(
                path=info.path,
                sha256=info.sha256,
                size=info.size,
                mtime_ns=info.mtime_ns,
                root=str(root),
                certificate=(
                    str(Path(certificate).absolute())
                    if certificate and certificate != AUTO
                    else certificate
                ),
                certificates=cmap,
                certificates_source=certificates,
                timeout_s=timeout_s,
                config=dict(config or {}),
            )

    skipped = [0]  # logs found done (or twice) once hashed

    def collect(client: Any, feed: Feed[Job]) -> None:
        """Submit each job the feed makes and write each record as its log completes."""
        from dask.distributed import as_completed

        if redo and (outdir / "logs.jsonl").exists():
            (outdir / "logs.jsonl").unlink()

        def total() -> int:  # the logs to diagnose, as far as known yet
            return len(pending) - skipped[0]

        if progress:
            progress(f"0/{total()} logs", 0.0 if total() else 1.0, 0)
        jobs: dict[str, Job] = {}  # by task key, while its task runs
        # each result gathered on Dask's event loop as its task ends, not by a call from
        # this thread per log; a failed task's outcome is its exception, not raised here
        running = as_completed(with_results=True, raise_errors=False)

        def submit(job: Job) -> None:
            fut = client.submit(diagnose_log, job, key=f"diagnose-{job.sha256}", pure=False)
            jobs[fut.key] = job
            running.add(fut)

        feed.attach(submit)
        with RecordLog(outdir) as log_file:
            finished = 0
            while True:
                feed.more.clear()
                for fut, outcome in running:
                    job = jobs.pop(fut.key)
                    if fut.status == "finished":
                        record = outcome
                    else:  # a dead worker (or a cancelled task) is the log's row
                        exc = outcome[1] if isinstance(outcome, tuple) else outcome
                        record = _lost(job, exc, retries)
                    log_file.append(record)
                    if on_record:
                        on_record(record)
                    finished += 1
                    fut.release()
                    if progress:
                        n = max(total(), finished)
                        progress(f"{finished}/{n} logs", finished / n, finished)
                feed.check()
                if feed.ended.is_set() and running.is_empty():
                    return
                if running.is_empty():
                    feed.more.wait()

    if pending:
        if not scheduler:  # the workers' server loads while the logs are hashed
            start_forkserver()
        # hashed in a thread (their content, GBs), each log submitted once hashed, while
        # the workers start and then work
        feed = Feed(make_jobs).start()
        try:
            with _client(scheduler, workers, memory_limit, retries, dashboard) as client:
                try:
                    collect(client, feed)
                finally:
                    feed.close()  # no submission to a client being closed
        finally:
            feed.close()
    elif progress:  # everything recorded already: no cluster
        progress("0/0 logs", 1.0, 0)
    records, _ = rebuild(outdir)
    return records


__all__ = ["DEFAULT_MEMORY_LIMIT", "DEFAULT_TIMEOUT_S", "rebuild", "require", "run"]

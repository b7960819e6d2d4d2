"""The per-log task: one log diagnosed by the library's :func:`imudiag.diagnose` into one
record (docs/fleet.md). It runs in a Dask worker and never raises for a bad log: a log
that cannot be read, whose certificate is bad, or that runs past its time is a record with
``status: error`` and the reason."""

from __future__ import annotations

import hashlib
import os
import resource
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import numpy as np

from ..certificate import AUTO
from ..errors import ImudiagError
from ..reports import finite_or_null
from .allocator import RELEASE_ABOVE_BYTES, keep_freed_memory, release_freed_memory

#: Certificate file names looked for in a log's folder and the folders above it (up to the
#: folder named on the command line).
FOLDER_CERTIFICATES = ("certificate.yaml", "certificate.yml")
#: Triads and parameter kinds of a diagnosis report's windows, in order.
TRIADS = ("accel", "gyro")
#: A log's GNSS stream sits beside it as ``LOG.gnss`` or ``LOG.gnss.gz`` (a ``gpspipe -w``
#: log in UTC Unix time, as ``imudiag simulate --gnss`` writes): the record's report then
#: carries the moving-base diagnosis (``moving_base``), as ``imudiag diagnose --gnss
#: FILE``; without one, the log's own GNSS where it has some (``--gnss auto``).
GNSS_SUFFIXES = (".gnss", ".gnss.gz")
#: A multi-IMU log's other instances are diagnosed where logged at this fraction of the log's
#: IMU rate or more (the ULog reader's own rule for raw topics against sensor_combined).
MIN_INSTANCE_RATE_FRACTION = 0.5
#: Report keys left out of a record (the per-window estimates: the record keeps each
#: parameter's best-determined window instead).
DROPPED_REPORT_KEYS = ("windows",)


#: Modules a per-log task imports (the library's diagnosis, every log reader, the monitor, the
#: GNSS aiding the diagnosis looks for): imported by :func:`preload`, in the forkserver local
#: workers are forked from, or else by :func:`warm_up` at the start of a worker's first task,
#: outside the log's own CPU (``cpu_s``), so no log's figure pays them.
WARM_MODULES = (
    "imudiag.api",
    "imudiag.logs",
    "imudiag.monitor",
    "imudiag.diagnosis.session",
    "imudiag.aiding.log_clock",
    "imudiag.aiding.moving",
    "imudiag.fleet.identity",
)


#: Whether :func:`preload` has set this process's malloc (:mod:`.allocator`).
_ALLOCATOR_SET = False
#: The process whose warm-up has run its once-only part (pyarrow's first parse, the freeze
#: of its objects): a worker forked from a warm forkserver inherits the server's frozen
#: objects, then runs that part for its own.
_FROZEN_IN: int | None = None


def preload() -> None:
    """Load what a fleet worker keeps for its life, parsing nothing, so that no thread
    starts under the local workers' environment (a local cluster's forkserver preloads
    it, :mod:`.forkserver`, before forking workers; ``runner.WORKER_MALLOC``): this
    process's malloc settings (:mod:`.allocator`), :data:`WARM_MODULES`, and where the
    compiled kernels are used (numba installed; not with ``IMUDIAG_KERNELS=plain``) the
    window-fit kernels (:mod:`imudiag.diagnosis.kernels`) and pyarrow's CSV reader
    (:func:`imudiag.logs.arrow_csv.load`)."""
    import importlib

    global _ALLOCATOR_SET
    if not _ALLOCATOR_SET:
        # freed arrays kept for the next during a log, given back after it (allocator.py)
        keep_freed_memory()
        _ALLOCATOR_SET = True
    for name in WARM_MODULES:
        importlib.import_module(name)
    if _use_kernels():
        # the compile, or the load of numba's disk cache, is paid here once per worker
        from ..diagnosis import kernels
        from ..logs import arrow_csv

        kernels.load()
        arrow_csv.load()


def warm_up() -> float:
    """:func:`preload` in this process (a fleet worker; nothing left to load in one forked
    from a warm forkserver) and pyarrow's first CSV parse (its set-up, 0.01 s); the CPU of
    this thread it took, s (about 0 once done).

    Then the objects the worker holds are frozen (``gc.freeze``: its modules, Dask's, the
    compiled kernels, all kept for the worker's life): no later collection traverses them,
    nor the worker's exit, whose last collection made closing a local cluster wait 0.40 s
    instead of 0.08 (docs/benchmarks.md, "Session 38")."""
    import gc

    cpu0 = time.thread_time()
    preload()
    global _FROZEN_IN
    if _FROZEN_IN != os.getpid():  # once per process, not at every task
        if _use_kernels():
            from ..logs import arrow_csv

            arrow_csv.floats(b"0\n", 1, 1, [0])
        gc.freeze()
        _FROZEN_IN = os.getpid()
    return time.thread_time() - cpu0


def release_mark() -> int:
    """Resident memory above which this worker gives its free heap back after a log, bytes:
    :data:`~.allocator.RELEASE_ABOVE_BYTES`, or half the worker's Dask memory limit where
    that is lower (a worker on a cluster whose configuration pauses it at 80 % of its limit
    takes no log while its memory stays above that)."""
    try:
        from distributed import get_worker

        limit = get_worker().memory_manager.memory_limit
    except (ImportError, ValueError, AttributeError):  # not in a Dask worker
        limit = None
    if not limit:
        return RELEASE_ABOVE_BYTES
    return min(RELEASE_ABOVE_BYTES, int(limit) // 2)


def _use_kernels() -> bool:
    """Whether a task runs the compiled window-fit kernels: unless ``IMUDIAG_KERNELS=plain``
    in the worker's environment, where they load (numba installed)."""
    return os.environ.get("IMUDIAG_KERNELS", "").strip().lower() != "plain"


#: Certificates parsed in this worker, by (absolute path or None for the bundled one, size,
#: mtime_ns): a fleet's logs share a few certificates, and parsing the YAML was a tenth of a
#: short log's CPU. At most _CERTIFICATE_CACHE_SIZE, emptied when full.
_CERTIFICATES: dict[tuple[str | None, int, int], Any] = {}
_CERTIFICATE_CACHE_SIZE = 32


def load_certificate_once(path: str | None) -> Any:
    """The certificate at ``path`` (None: the bundled one) as
    :func:`imudiag.api.load_certificate` loads it, parsed once per worker while the file is
    unchanged (same size and modification time); each call gets its own copy."""
    from ..api import load_certificate

    key: tuple[str | None, int, int] = (None, 0, 0)
    if path is not None:
        try:
            st = os.stat(path)
        except OSError:
            return load_certificate(path)  # its own error, naming the file and the reason
        key = (str(Path(path).absolute()), st.st_size, st.st_mtime_ns)
    cert = _CERTIFICATES.get(key)
    if cert is None:
        cert = load_certificate(path)
        if len(_CERTIFICATES) >= _CERTIFICATE_CACHE_SIZE:
            _CERTIFICATES.clear()
        _CERTIFICATES[key] = cert
    return cert.copy()


class LogTimeout(ImudiagError):
    """A log's diagnosis ran past the per-log timeout."""


@dataclass
class Job:
    """What a worker needs to diagnose one log (all plain data: it is pickled to the worker).

    ``certificate``: the one for every log (``--certificate``), else ``certificates`` maps a
    vehicle to its certificate (``--certificates MAP.yaml``), else a ``certificate.yaml`` in
    the log's folder or above it up to ``root``, else the bundled one. ``timeout_s``: the
    diagnosis stops with a ``timeout`` error after this many seconds of wall time.
    """

    path: str
    sha256: str
    size: int
    mtime_ns: int
    root: str
    certificate: str | None = None
    certificates: dict[str, str] = field(default_factory=dict)
    certificates_source: str | None = None
    timeout_s: float | None = None
    config: dict[str, Any] = field(default_factory=dict)


def folder_certificate(path: str | Path, root: str | Path) -> Path | None:
    """The nearest ``certificate.yaml`` in the folder of ``path`` or above it, not above
    ``root``."""
    top = Path(root).absolute()
    here = Path(path).absolute().parent
    while True:
        for name in FOLDER_CERTIFICATES:
            if (here / name).is_file():
                return here / name
        if here == top or here == here.parent or top not in here.parents:
            return None
        here = here.parent


def choose_certificate(job: Job, vehicle: str, folder: str) -> tuple[str | None, str]:
    """The certificate a log uses (a path, None for the bundled one) and where it came from."""
    if job.certificate:
        return job.certificate, "--certificate"
    for name in (vehicle, folder):
        if name in job.certificates:
            return job.certificates[name], f"--certificates {job.certificates_source}: {name}"
    found = folder_certificate(job.path, job.root)
    if found is not None:
        return str(found), "certificate.yaml in the vehicle's folder"
    return None, "bundled (no --certificate, no map entry, no certificate.yaml)"


def best_estimates(report: dict[str, Any], cert: Any) -> list[dict[str, Any]]:
    """Each determined parameter's estimate in the log: the window that determined it best
    (smallest std), with the certificate's value, the limit and the unit."""
    from ..diagnosis.params import (
        CAUSES,
        PARAM_KEYS,
        cause_unit,
        certificate_vector,
        limit_vector,
        sensor_of,
    )

    out: list[dict[str, Any]] = []
    for triad in TRIADS:
        model = cert.triad(triad)
        certificate, limit = certificate_vector(model), limit_vector(model)
        best: dict[int, tuple[float, float, float, float]] = {}
        for w in report.get("windows") or []:
            fit = w.get(triad)
            if not fit:
                continue
            for k, key in enumerate(PARAM_KEYS):
                part = fit.get(key)
                if not part:
                    continue
                for j in range(3):
                    i = 3 * k + j
                    est, std = part["estimate"][j], part["std"][j]
                    if not part["determined"][j] or est is None or std is None:
                        continue
                    if not (np.isfinite(est) and np.isfinite(std)) or std <= 0:
                        continue
                    if i not in best or std < best[i][1]:
                        best[i] = (float(est), float(std), w.get("t_start"), w.get("t_end"))
        for i in sorted(best):
            est, std, t0, t1 = best[i]
            out.append(
                {
                    "triad": triad,
                    "sensor": sensor_of(triad, i),
                    "cause": CAUSES[i],
                    "estimate": est,
                    "std": std,
                    "certificate": float(certificate[i]),
                    "limit": float(limit[i]),
                    "unit": cause_unit(model, CAUSES[i]),
                    "window": [t0, t1],
                }
            )
    return out


def tagged(parameters: list[dict[str, Any]], instance: int | None) -> list[dict[str, Any]]:
    """``parameters`` (:func:`best_estimates`) each with the IMU ``instance`` they are of."""
    return [{"instance": instance, **p} for p in parameters]


def kept(report: dict[str, Any], cert: Any, instance: int | None) -> list[dict[str, Any]]:
    """The parameters a record keeps of the ``report`` of IMU ``instance`` (its best
    estimates, :func:`tagged`); the report loses :data:`DROPPED_REPORT_KEYS` in place."""
    parameters = tagged(best_estimates(report, cert), instance)
    for key in DROPPED_REPORT_KEYS:
        report.pop(key, None)
    return parameters


def other_instances(
    meta: dict[str, Any], cert: Any, diagnose_instance: Callable[[int], dict[str, Any]]
) -> list[dict[str, Any]]:
    """The diagnosis of each IMU instance of a multi-IMU log (``meta["imu_instances"]``: a
    ULog's, a DataFlash log's) other than the one the log's ``report`` is of
    (``meta["instance"]``): its ``instance``, ``rate_hz``, ``status`` (``ok``, ``error``
    or ``skipped``: logged at less than :data:`MIN_INSTANCE_RATE_FRACTION` of the log's
    IMU rate, as PX4's raw topics often are), ``reason``, ``samples``, ``parameters`` and
    ``report`` (without its windows). ``diagnose_instance(N)``: the report of instance N.
    An instance that fails, or runs past the log's time limit, is an ``error`` item with
    the reason: the log's own report, already made, is never lost to it."""
    out: list[dict[str, Any]] = []
    rate = meta.get("sample_rate")
    for entry in meta.get("imu_instances") or []:
        number = int(entry["instance"])
        if number == meta.get("instance"):
            continue
        item: dict[str, Any] = {
            "instance": number,
            "rate_hz": entry.get("rate_hz"),
            "status": "error",
            "reason": None,
            "samples": None,
            "parameters": [],
            "report": None,
        }
        out.append(item)
        if isinstance(rate, int | float) and not (
            float(entry.get("rate_hz") or 0.0) >= MIN_INSTANCE_RATE_FRACTION * rate
        ):
            item["status"] = "skipped"
            item["reason"] = (
                f"logged at {entry.get('rate_hz')} Hz, below {MIN_INSTANCE_RATE_FRACTION:g} "
                f"of the log's IMU rate ({rate:g} Hz): not diagnosed"
            )
            continue
        try:
            report = diagnose_instance(number)
        except LogTimeout as exc:  # the log's own report is kept: this instance ran late
            item["reason"] = f"instance {number}: {exc}"
            continue
        except ImudiagError as exc:
            item["reason"] = f"diagnosing instance {number}: {exc}"
            continue
        item["parameters"] = kept(report, cert, number)
        item.update(status="ok", samples=report.get("samples"), report=report)
    return out


def gnss_beside(path: str | Path) -> Path | None:
    """The GNSS stream recorded beside a log (:data:`GNSS_SUFFIXES`), or None."""
    for suffix in GNSS_SUFFIXES:
        candidate = Path(f"{path}{suffix}")
        if candidate.is_file():
            return candidate
    return None


def _peek(path: str) -> tuple[str, dict[str, Any], float | None]:
    """The log's format name, metadata and first sample time (s), reading one block."""
    from ..logs import log_format, open_log

    fmt = log_format(path)
    with open_log(path, block_size=1) as reader:
        t0 = None
        for block in reader:
            if len(block.t):
                t0 = float(block.t[0])
                break
        meta = dict(reader.meta)
    return fmt, meta, t0


def _cpu_s() -> float:
    """CPU time of this thread, s (the worker's other threads are other logs)."""
    return time.thread_time()


def _json_safe(meta: dict[str, Any]) -> dict[str, Any]:
    """A log's metadata as JSON: numbers, text, and lists and objects of them kept (a
    value not determined as null); anything else as its text."""
    import json

    out = {}
    for k, v in meta.items():
        v = finite_or_null(v)
        try:
            json.dumps(v, allow_nan=False)
        except (TypeError, ValueError):
            v = str(v)
        out[str(k)] = v
    return out


def diagnose_log(job: Job) -> dict[str, Any]:
    """Diagnose one log; the record of docs/fleet.md (``status`` ``ok`` or ``error``)."""
    try:
        warm_cpu = warm_up()  # the worker's imports, paid by its first task, outside cpu_s
    except Exception:  # noqa: BLE001 - an import that fails fails again below, as the row's reason
        warm_cpu = 0.0
    from ..api import diagnose
    from .identity import GNSS_CLOCK_START, folder_vehicle, identify, start_from_gnss_clock

    started, cpu0 = time.monotonic(), _cpu_s()
    folder = folder_vehicle(job.path)
    record: dict[str, Any] = {
        "path": job.path,
        "sha256": job.sha256,
        "size": job.size,
        "mtime_ns": job.mtime_ns,
        "vehicle": folder,
        "vehicle_source": "folder name (the log could not be read)",
        "start": None,
        "start_source": None,
        "format": None,
        "status": "error",
        "reason": None,
        "certificate": None,
        "certificate_source": None,
        "certificate_sha256": None,
        "worker_pid": os.getpid(),
        "kernels": None,
        "instance": None,
        "instances": [],
    }
    stage = "reading the log"
    try:
        fmt, meta, t0 = _peek(job.path)
        record["format"] = fmt
        record["meta"] = _json_safe(meta)
        stage = "identifying the vehicle"
        record.update(identify(job.path, fmt, meta, t0))
        cert_path, cert_source = choose_certificate(job, record["vehicle"], folder)
        record["certificate_source"] = cert_source
        stage = "loading the certificate"
        if cert_path == AUTO:  # the data sheet the log names (--certificate auto)
            from ..logs.datasheet import datasheet_of_log

            cert_path = str(datasheet_of_log(meta, job.path))
            cert_source += ": the log's data sheet"
            record["certificate_source"] = cert_source
        cert = load_certificate_once(cert_path)
        record["certificate"] = str(cert.source) if cert.source else cert_path
        if cert.source and Path(str(cert.source)).is_file():
            record["certificate_sha256"] = hashlib.sha256(
                Path(str(cert.source)).read_bytes()
            ).hexdigest()
        stage = "diagnosing"
        deadline = None if job.timeout_s is None else started + job.timeout_s

        def watch(what: str, fraction: float | None, done: int) -> None:
            if deadline is not None and time.monotonic() > deadline:
                raise LogTimeout(
                    f"timeout: the diagnosis ran past {job.timeout_s:g} s (while {what})"
                )

        gnss = gnss_beside(job.path)
        from ..diagnosis import kernels
        from ..logs import LogOptions

        def diagnose_instance(number: int | None) -> dict[str, Any]:
            """The log's report (of IMU instance ``number``; None: the reader's choice),
            with the compiled window fits in this task's thread only (docs/fleet.md)."""
            with kernels.switched(_use_kernels()) as compiled:
                record["kernels"] = (
                    "numba"
                    if compiled
                    else (
                        "plain (IMUDIAG_KERNELS=plain)" if not _use_kernels() else kernels.status()
                    )
                )
                return cast(
                    "dict[str, Any]",
                    diagnose(
                        job.path,
                        cert,
                        config=job.config or None,
                        progress=watch,
                        gnss=str(gnss) if gnss else "auto",
                        log_options=None if number is None else LogOptions(instance=number),
                    ),
                )

        report = diagnose_instance(None)
        record["gnss"] = (
            str(gnss) if gnss else ("the log's own" if "moving_base" in report else None)
        )
        if record["start"] is None:  # the log does not say: its GNSS time, where tied
            start = start_from_gnss_clock(report, t0)
            if start is not None:
                record["start"], record["start_source"] = start, GNSS_CLOCK_START
        record["instance"] = meta.get("instance")
        record["parameters"] = kept(report, cert, record["instance"])
        record["report"] = report
        record["samples"] = report.get("samples")
        record["status"] = "ok"
        stage = "diagnosing the log's other IMU instances"
        record["instances"] = other_instances(meta, cert, diagnose_instance)
    except LogTimeout as exc:
        record["reason"] = str(exc)
    except ImudiagError as exc:
        record["reason"] = f"{stage}: {exc}"
    except MemoryError:
        record["reason"] = f"{stage}: out of memory"
    except Exception as exc:  # noqa: BLE001 - any failure of one log is its row, never the run's
        where = traceback.extract_tb(exc.__traceback__)[-1]
        record["reason"] = (
            f"{stage}: {type(exc).__name__}: {exc} ({Path(where.filename).name}:{where.lineno})"
        )
    # the log's freed arrays back to the system past a mark (allocator.py)
    release_freed_memory(release_mark())
    record["cpu_s"] = _cpu_s() - cpu0
    record["warm_up_cpu_s"] = warm_cpu
    record["wall_s"] = time.monotonic() - started
    record["max_rss_kib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    # a value the diagnosis could not determine (NaN) is null, as in ``imudiag diagnose
    # --json`` (spec/reports.md): the record is written as strict JSON
    return cast("dict[str, Any]", finite_or_null(record))


__all__ = [
    "WARM_MODULES",
    "Job",
    "LogTimeout",
    "kept",
    "best_estimates",
    "choose_certificate",
    "diagnose_log",
    "load_certificate_once",
    "other_instances",
    "tagged",
    "preload",
    "release_mark",
    "warm_up",
]

"""The per-log records of a fleet run on disk: ``DIR/logs.jsonl`` (one JSON object a line,
each line appended whole and synced as its log completes) and the Parquet table rebuilt
from them (``DIR/logs.parquet``)."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from ..atomic import atomic_path

RECORDS = "logs.jsonl"  #: the per-log records
TABLE = "logs.parquet"  #: the same records as a Parquet table (pyarrow)


class RecordLog:
    """``DIR/logs.jsonl`` opened for appending: :meth:`append` writes one record as one
    line with a single ``write`` on an ``O_APPEND`` descriptor and syncs it, so a killed run
    leaves whole lines (and at worst one cut last line, which :func:`read_records`
    drops)."""

    def __init__(self, directory: str | Path) -> None:
        self.path = Path(directory) / RECORDS
        self._fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o666)
        if self.path.stat().st_size:  # a run cut in the middle of a line: end that line
            with open(self.path, "rb") as fh:
                fh.seek(-1, os.SEEK_END)
                if fh.read(1) != b"\n":
                    os.write(self._fd, b"\n")

    def append(self, record: dict[str, Any]) -> None:
        """Append ``record`` as one line, synced to disk."""
        line = json.dumps(record, allow_nan=False, separators=(",", ":")) + "\n"
        os.write(self._fd, line.encode())
        os.fsync(self._fd)

    def close(self) -> None:
        """Close the file."""
        os.close(self._fd)

    def __enter__(self) -> RecordLog:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def read_records(directory: str | Path) -> list[dict[str, Any]]:
    """The records of ``DIR/logs.jsonl`` (none when absent), the last one of each log
    (by content hash) kept, in the order first written; a line cut by a killed run is
    dropped."""
    path = Path(directory) / RECORDS
    if not path.exists():
        return []
    by_hash: dict[str, dict[str, Any]] = {}
    with open(path, encoding="utf-8") as fh:
        for line in fh:
            try:
                rec = json.loads(line)
            except json.JSONDecodeError:
                continue  # the cut last line of a killed run
            if isinstance(rec, dict) and "sha256" in rec:
                by_hash[rec["sha256"]] = rec
    return list(by_hash.values())


#: Scalar columns of the Parquet table: record key -> Arrow type name.
_COLUMNS = (
    ("path", "string"),
    ("vehicle", "string"),
    ("vehicle_source", "string"),
    ("start", "string"),
    ("status", "string"),
    ("reason", "string"),
    ("format", "string"),
    ("sha256", "string"),
    ("size", "int64"),
    ("certificate", "string"),
    ("certificate_source", "string"),
    ("samples", "int64"),
    ("instance", "int64"),
    ("cpu_s", "float64"),
    ("wall_s", "float64"),
)


def write_table(records: list[dict[str, Any]], directory: str | Path) -> Path:
    """Rebuild ``DIR/logs.parquet`` from ``records`` (atomically): one row per log, the
    scalar keys as columns, ``verdict_accel`` / ``verdict_gyro``, ``parameters`` (a list
    of estimate structs), ``report`` (the diagnosis report as JSON text) and
    ``instances`` (the other IMU instances' diagnoses as JSON text)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    cols: dict[str, Any] = {}
    for key, kind in _COLUMNS:
        cols[key] = pa.array([r.get(key) for r in records], type=getattr(pa, kind)())
    for triad in ("accel", "gyro"):
        cols[f"verdict_{triad}"] = pa.array(
            [(r.get("report") or {}).get("verdict", {}).get(triad) for r in records], pa.string()
        )
    param = pa.struct(
        [
            ("instance", pa.int64()),
            ("triad", pa.string()),
            ("sensor", pa.string()),
            ("cause", pa.string()),
            ("estimate", pa.float64()),
            ("std", pa.float64()),
            ("certificate", pa.float64()),
            ("limit", pa.float64()),
            ("unit", pa.string()),
        ]
    )
    cols["parameters"] = pa.array(
        [[{k: p.get(k) for k in param.names} for p in r.get("parameters") or []] for r in records],
        pa.list_(param),
    )
    cols["report"] = pa.array(
        [json.dumps(r["report"]) if r.get("report") else None for r in records], pa.string()
    )
    cols["instances"] = pa.array(  # the log's other IMU instances (docs/fleet.md), JSON text
        [json.dumps(r["instances"]) if r.get("instances") else None for r in records],
        pa.string(),
    )
    path = Path(directory) / TABLE
    with atomic_path(path) as tmp:
        pq.write_table(pa.table(cols), tmp)
    return path


__all__ = ["RECORDS", "TABLE", "RecordLog", "read_records", "write_table"]

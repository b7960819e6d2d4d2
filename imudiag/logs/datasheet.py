"""``--certificate auto`` for a log: the bundled data-sheet certificate its metadata names
(``datasheet``: a PX4 ULog's and an ArduPilot DataFlash log's IMU, the flight-controller
class; docs/logs.md), for ``imudiag diagnose``, the library and the fleet alike."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..certificate import AUTO, Certificate, CertificateError, datasheet_path, load, load_default
from .options import LogOptions


def datasheet_of_log(meta: dict[str, Any], log: str | Path, option: str = "--certificate") -> Path:
    """The bundled data-sheet certificate the metadata ``meta`` of the log ``log`` names
    (``datasheet``); CertificateError naming the log and the ``option`` that asked for it
    when it names none."""
    key = meta.get("datasheet")
    if not key:
        raise CertificateError(
            str(log),
            f"{option} auto: the log names no data-sheet certificate (autopilot logs do: "
            f"PX4 ULog, ArduPilot DataFlash); give a certificate file ({option} PATH)",
        )
    return datasheet_path(str(key))


def log_datasheet_path(
    log: Any, log_options: LogOptions | None = None, option: str = "--certificate"
) -> Path:
    """:func:`datasheet_of_log` of the log file ``log`` (its metadata read from its first
    block); CertificateError when ``log`` is not a file's path (samples in memory)."""
    if not isinstance(log, str | Path):
        raise CertificateError(
            AUTO, "a data-sheet certificate is named by a log file; give one for samples in memory"
        )
    from . import open_log

    with open_log(log, block_size=1, options=log_options) as reader:
        return datasheet_of_log(reader.meta, log, option)


def certificate_for_log(
    path: str | Path | None,
    log: Any = None,
    log_options: LogOptions | None = None,
    option: str = "--certificate",
) -> Certificate:
    """The certificate in the YAML file at ``path`` (None: the bundled one of the simulated
    board; ``"auto"``: the data sheet the log ``log`` names, :func:`log_datasheet_path`;
    ``option`` names where the ``auto`` came from in a refusal)."""
    if path is None:
        return load_default()
    if str(path) == AUTO:
        return load(log_datasheet_path(log, log_options, option))
    return load(path)


__all__ = ["certificate_for_log", "datasheet_of_log", "log_datasheet_path"]

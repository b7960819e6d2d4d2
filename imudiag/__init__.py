"""imudiag: onboard monitor and scalar diagnosis of a strapdown IMU.

Data flows one way: bytes -> frames -> samples -> monitor -> verdicts -> status.

The library API (docs/api.md) is importable from here::

    import imudiag

    cert = imudiag.load_certificate()                 # the bundled certificate
    report = imudiag.diagnose("session.csv", cert)    # the report of `imudiag diagnose`
    print(report["verdict"]["accel"], report["verdict"]["faults"])

Names are imported on first use, so ``import imudiag`` stays cheap for the daemon.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"

#: Public name -> module that defines it (imported when the name is first used).
_API: dict[str, str] = {
    # sources (the driver layer): a transport chosen by URL
    "open_source": "imudiag.drivers",
    "Source": "imudiag.drivers",
    "EndOfStream": "imudiag.drivers",
    # samples and logs
    "SampleBlock": "imudiag.samples",
    "open_log": "imudiag.logs",
    "read_log": "imudiag.logs",
    "write_log": "imudiag.logs",
    "LogOptions": "imudiag.logs",
    # certificates
    "Certificate": "imudiag.certificate",
    "load_certificate": "imudiag.api",
    # the per-sample monitor and the window diagnosis
    "Monitor": "imudiag.monitor",
    "MonitorConfig": "imudiag.monitor",
    "StreamingDiagnoser": "imudiag.diagnosis",
    "DiagnosisConfig": "imudiag.diagnosis",
    # whole recordings: the code path of `imudiag diagnose` and `imudiag calibrate`
    "diagnose": "imudiag.api",
    "calibrate": "imudiag.api",
    "moving_base": "imudiag.api",
    "DiagnosisReport": "imudiag.diagnosis.report",
    "CalibrationResult": "imudiag.diagnosis.calibrate",
    # the one exception family
    "ImudiagError": "imudiag.errors",
    "BadInput": "imudiag.errors",
    "CertificateError": "imudiag.errors",
    "SourceError": "imudiag.errors",
    "LogError": "imudiag.logs",
}

__all__ = [
    "__version__",
    "BadInput",
    "CalibrationResult",
    "Certificate",
    "CertificateError",
    "DiagnosisConfig",
    "DiagnosisReport",
    "EndOfStream",
    "ImudiagError",
    "LogError",
    "LogOptions",
    "Monitor",
    "MonitorConfig",
    "SampleBlock",
    "Source",
    "SourceError",
    "StreamingDiagnoser",
    "calibrate",
    "diagnose",
    "load_certificate",
    "moving_base",
    "open_log",
    "open_source",
    "read_log",
    "write_log",
]

if TYPE_CHECKING:  # the names as mypy and editors see them
    from .api import calibrate, diagnose, load_certificate, moving_base
    from .certificate import Certificate
    from .diagnosis import DiagnosisConfig, StreamingDiagnoser
    from .diagnosis.calibrate import CalibrationResult
    from .diagnosis.report import DiagnosisReport
    from .drivers import EndOfStream, Source, open_source
    from .errors import BadInput, CertificateError, ImudiagError, SourceError
    from .logs import LogError, LogOptions, open_log, read_log, write_log
    from .monitor import Monitor, MonitorConfig
    from .samples import SampleBlock


def __getattr__(name: str) -> Any:
    """Import a public name's module on first use (PEP 562)."""
    module = _API.get(name)
    if module is None:
        raise AttributeError(f"module 'imudiag' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_API))

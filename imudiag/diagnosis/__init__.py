"""The 18-parameter scalar diagnosis (Avrutov 2015, made statistical) and scalar calibration.

``StreamingDiagnoser(certificate, config=None)``: ``.update(block) -> list[WindowResult]``,
``.faults``, ``.undetermined``, ``.report(...)``. See ``docs/diagnosis.md``.
"""

from .config import DiagnosisConfig
from .intervals import IntervalCollector, MotionSegment, QuasiStaticInterval
from .params import TriadFit
from .stream import REPORT_FORMAT, StreamingDiagnoser, diagnose_samples
from .window import WindowResult, diagnose_window

__all__ = [
    "DiagnosisConfig",
    "IntervalCollector",
    "MotionSegment",
    "QuasiStaticInterval",
    "REPORT_FORMAT",
    "StreamingDiagnoser",
    "TriadFit",
    "WindowResult",
    "diagnose_samples",
    "diagnose_window",
]

"""The diagnosis report as a type: the documented keys of ``imudiag-diagnosis/1``.

The report stays a plain ``dict`` (its JSON is exactly ``imudiag diagnose --json``'s,
docs/spec/reports.md); these ``TypedDict`` types say which keys it has and what each
holds, for mypy and editors, and :func:`check_keys` holds a report to them (the tests
do, so a key added to the report without its entry here fails).
"""

from __future__ import annotations

from typing import Any, NotRequired, Required, TypedDict


class _F0Keys(TypedDict):
    checked: int
    failed: int


class F0Counts(_F0Keys, total=False):
    """The F0 checks of one triad: samples checked and failed; ``why`` (only when none
    was checked) the criterion that kept the check from running; ``unjudged`` (only while
    samples were checked but fewer than one check averages) why none was judged;
    ``check`` ``known_rate`` on a turntable (per plateau)."""

    why: str
    unjudged: str
    check: str


class _VerdictKeys(TypedDict):
    accel: str
    gyro: str
    faults: list[dict[str, Any]]
    undetermined: list[dict[str, Any]]


class Verdict(_VerdictKeys, total=False):
    """Per triad ``ok`` / ``fault`` / ``undetermined``; the faults (triad, sensor, cause,
    estimate, certificate, limit in the certificate's units, t_first s, ...) and what the
    data could not determine (triad, sensor, cause, reason); ``withdrawn`` (only when not
    empty): faults raised by windows mixing both sides of a step change, with the reason.
    (The optional key by a subclass with ``total=False``: under postponed annotations,
    ``Required``/``NotRequired`` are strings that Python 3.11's ``TypedDict`` cannot read.)
    """

    withdrawn: list[dict[str, Any]]


#: The report of :func:`imudiag.diagnose` and ``imudiag diagnose --json``.
DiagnosisReport = TypedDict(
    "DiagnosisReport",
    {
        "class": Required[str],  # "imudiag-diagnosis"
        "format": Required[str],  # "imudiag-diagnosis/1"
        "samples": Required[int],  # samples read
        "f0": Required[dict[str, F0Counts]],  # per triad
        "verdict": Required[Verdict],
        "method": Required[str],  # exact | linear | moving-base
        "intervals": Required[int],  # quasi-static intervals found
        "windows_run": Required[int],  # windows fitted
        "windows": Required[list[dict[str, Any]]],  # each window's estimates and std
        "log": NotRequired[str],  # the recording's name
        "certificate": NotRequired[str],  # the certificate's file, or "(bundled)"
        "certificate_warning": NotRequired[str],  # a data-sheet certificate's warning
        "sample_rate": NotRequired[float],  # Hz
        "noise": NotRequired[dict[str, Any]],  # measured noise per triad (output units)
        "unit_conversion": NotRequired[dict[str, Any]],  # the log's units converted
        "vibration": NotRequired[dict[str, Any]],  # the status's vibration object
        "wire": NotRequired[dict[str, int]],  # a raw .bin capture's receiver counters
        "self_test": NotRequired[int],  # samples flagged self-test (excluded)
        "adc_errors": NotRequired[int],  # samples flagged ADC error (excluded)
        "moving_base": NotRequired[dict[str, Any]],  # GNSS-aided section (docs/diagnosis.md)
    },
    total=False,
)


def check_keys(report: dict[str, Any]) -> None:
    """ValueError naming a key of ``report`` that :data:`DiagnosisReport` does not
    document, or a documented required key it lacks."""
    known = DiagnosisReport.__required_keys__ | DiagnosisReport.__optional_keys__
    extra = sorted(set(report) - known)
    missing = sorted(DiagnosisReport.__required_keys__ - set(report))
    if extra or missing:
        raise ValueError(f"diagnosis report: undocumented keys {extra}, missing keys {missing}")


__all__ = ["DiagnosisReport", "F0Counts", "Verdict", "check_keys"]

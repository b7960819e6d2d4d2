"""The library API: what a user's own Python code needs, importable as ``imudiag.<name>``.

See docs/api.md. The functions here are the code path of the commands:
:func:`diagnose` is ``imudiag diagnose`` and :func:`calibrate` is ``imudiag calibrate``
without the printing and the file writing.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

from . import validate
from .certificate import Certificate
from .diagnosis.calibrate import CalibrationResult
from .diagnosis.config import CERTIFICATE_NOISE, DiagnosisConfig
from .diagnosis.inputs import MagnitudeTable
from .diagnosis.report import DiagnosisReport
from .diagnosis.session import (
    DEFAULT_BLOCK_SIZE,
    ProgressCallback,
    Recording,
    calibrate_recording,
    diagnose_recording,
)
from .errors import BadInput
from .logs.datasheet import certificate_for_log
from .logs.options import LogOptions
from .samples import SampleBlock

if TYPE_CHECKING:
    from .aiding.moving import MovingConfig

#: A certificate argument: a loaded one, a YAML file's path, ``"auto"`` (the data sheet the
#: log names), or None for the bundled one.
CertificateLike = Certificate | str | Path | None


def load_certificate(
    path: str | Path | None = None, *, log: Any = None, log_options: LogOptions | None = None
) -> Certificate:
    """The certificate in the YAML file at ``path`` (None: the bundled one of the simulated
    board; ``"auto"``: the data sheet the log ``log`` names,
    :func:`~imudiag.logs.datasheet.log_datasheet_path`). Raises
    :class:`~imudiag.errors.CertificateError` naming the key and the reason."""
    return certificate_for_log(path, log, log_options)


def _certificate(
    cert: CertificateLike, log: Any = None, log_options: LogOptions | None = None
) -> Certificate:
    if isinstance(cert, Certificate):
        return cert
    return load_certificate(cert, log=log, log_options=log_options)


def _config(config: DiagnosisConfig | dict[str, Any] | None) -> DiagnosisConfig:
    if isinstance(config, DiagnosisConfig):
        return config
    try:
        return DiagnosisConfig.from_dict(dict(config or {}))
    except ValueError as exc:
        raise BadInput(f"config: {exc}") from None


def diagnose(
    data: Recording,
    certificate: CertificateLike = None,
    *,
    config: DiagnosisConfig | dict[str, Any] | None = None,
    rate_hz: float | None = None,
    magnitude: MagnitudeTable | str | Path | None = None,
    certificate_noise: bool = CERTIFICATE_NOISE,
    log_options: LogOptions | None = None,
    block_size: int = DEFAULT_BLOCK_SIZE,
    windows: bool = True,
    gnss: Any = "auto",
    moving: MovingConfig | None = None,
    progress: ProgressCallback | None = None,
) -> DiagnosisReport:
    """Diagnose a recording against a certificate: the report of ``imudiag diagnose --json``
    (a dict; :data:`~imudiag.diagnosis.report.DiagnosisReport` types its keys).

    ``data``: a log file's path (any format ``imudiag diagnose`` reads; ``log_options``
    say how to read a text table) or a :class:`~imudiag.samples.SampleBlock` (t in s,
    outputs in the certificate's units). ``config``: a
    :class:`~imudiag.diagnosis.DiagnosisConfig` or a dict of its fields. ``rate_hz``:
    the sample rate, Hz (default: the log's, else from ``t``). The verdict is in
    ``report["verdict"]`` (``ok`` / ``fault`` / ``undetermined`` per triad, the faults
    with sensor, cause and value, and what the data could not determine).

    ``gnss`` (as ``--gnss``): ``"auto"`` (default) the log's own GNSS where it has it
    (DataFlash GPS, ULog vehicle_gps_position / sensor_gps, ROS NavSatFix + velocity),
    its clock tied to GNSS time by a fitted offset and rate; ``"log"`` the same, refused
    (:class:`~imudiag.errors.BadInput`) when it cannot; ``"none"``; a gpsd TPV log's path;
    a :class:`~imudiag.aiding.tpv.GnssTrack` in the samples' clock; or
    :class:`~imudiag.logs.gnss_fixes.GnssFixes` of samples in memory. The moving-base
    diagnosis is then ``report["moving_base"]`` (``moving``: its
    :class:`~imudiag.aiding.moving.MovingConfig`). ``progress(what, fraction, samples)``:
    told how far each pass has got (an exception it raises ends the diagnosis:
    ``imudiag fleet``'s per-log timeout). ``certificate``: as :func:`load_certificate`
    (``"auto"``: the data sheet the log names).
    """
    cert = _certificate(certificate, data, log_options)
    report: DiagnosisReport = cast(
        DiagnosisReport,
        diagnose_recording(
            data,
            cert,
            _config(config),
            rate_hz=rate_hz,
            magnitude=magnitude,
            certificate_noise=certificate_noise,
            options=log_options,
            block_size=block_size,
            windows=windows,
            progress=progress,
        ),
    )
    from .aiding.log_clock import gnss_section_of  # the aiding code only when it is used

    section = gnss_section_of(
        data, cert, gnss, moving, report.get("sample_rate"), log_options, block_size
    )
    if section is not None:
        report["moving_base"] = section
    return report


def calibrate(
    data: Recording,
    like: CertificateLike = None,
    *,
    config: DiagnosisConfig | dict[str, Any] | None = None,
    rate_hz: float | None = None,
    magnitude: MagnitudeTable | str | Path | None = None,
    certificate_noise: bool = CERTIFICATE_NOISE,
    log_options: LogOptions | None = None,
    block_size: int = DEFAULT_BLOCK_SIZE,
) -> CalibrationResult:
    """Calibrate both triads from a multi-position recording, as ``imudiag calibrate``.

    ``like`` gives scale factors, units, limits and starting values. Returns a
    :class:`~imudiag.diagnosis.calibrate.CalibrationResult`: ``.certificate`` (save it
    with ``.save(path)``), ``.summary()`` (the ``--json`` summary) and
    ``.generalisation`` (the held-out check; ``generalises`` False means the command
    would refuse to write it), ``.gyro_generalisation`` (the same for the gyros'
    rotation calibration) and ``.refusals()`` (the reasons of the checks that failed).
    Raises :class:`~imudiag.errors.BadInput` when the recording cannot calibrate.
    """
    return calibrate_recording(
        data,
        _certificate(like),
        _config(config),
        rate_hz=rate_hz,
        magnitude=magnitude,
        certificate_noise=certificate_noise,
        options=log_options,
        block_size=block_size,
    )


def moving_base(
    samples: SampleBlock,
    gnss: Any,
    certificate: CertificateLike = None,
    *,
    moving: MovingConfig | None = None,
    rate_hz: float | None = None,
) -> dict[str, Any]:
    """GNSS-aided moving-base diagnosis of samples in memory against a GNSS stream: the
    ``moving_base`` section of ``imudiag diagnose --gnss`` (docs/diagnosis.md), without
    reading any log.

    ``samples``: a :class:`~imudiag.samples.SampleBlock` (t in s, outputs in the
    certificate's units; flagged samples are left out). ``gnss``: gpsd's stream as it
    comes (an iterable of its JSON objects, parsed dicts or lines of text: ``gpspipe -w``
    or a gpsd socket; SKY and the other classes are ignored), a
    :class:`~imudiag.aiding.tpv.GnssTrack`, a gpsd log's path (all in UTC Unix time, as
    the samples' ``t``), or the :class:`~imudiag.logs.gnss_fixes.GnssFixes` of the
    samples' own clock (tied to GNSS time by a fitted offset and rate). ``moving``: a
    :class:`~imudiag.aiding.moving.MovingConfig`. ``rate_hz``: the samples' rate, Hz
    (default from ``t``). Raises :class:`~imudiag.errors.BadInput` naming the argument.
    """
    from .aiding.log_clock import moving_base_for_recording
    from .aiding.tpv import GnssTrack, track_from_stream
    from .logs.gnss_fixes import GnssFixes

    cert = _certificate(certificate)
    if not isinstance(samples, SampleBlock) or len(samples) < 2:
        raise BadInput(f"samples: expected a SampleBlock of 2 or more samples, got {samples!r}")
    if rate_hz is not None:
        validate.sample_rate(rate_hz, "rate_hz")
    fixes: GnssFixes | None = None
    source: Any
    if isinstance(gnss, GnssFixes):
        fixes, source = gnss, "log"
    elif isinstance(gnss, GnssTrack):
        source = gnss
    elif isinstance(gnss, (str, Path)):
        if str(gnss) in ("auto", "log", "none"):
            raise BadInput(
                f"gnss: {gnss!r} names a log's own GNSS: give the stream, a GnssTrack, a "
                "gpsd log's path or the samples' GnssFixes"
            )
        source = str(gnss)
    else:
        try:
            items = iter(gnss)
        except TypeError:
            raise BadInput(
                f"gnss: expected gpsd objects, a GnssTrack or a path, got {gnss!r}"
            ) from None
        source = track_from_stream(items)
    section = moving_base_for_recording(
        samples, cert, source, fixes, moving, rate_hz, where="samples"
    )
    assert section is not None  # a GNSS source was given
    if not isinstance(gnss, (GnssFixes, GnssTrack, str, Path)):
        section["gnss"]["source"] = section["log"] = "gpsd stream"
    return section


__all__ = [
    "CertificateLike",
    "DiagnosisReport",
    "calibrate",
    "diagnose",
    "load_certificate",
    "moving_base",
]

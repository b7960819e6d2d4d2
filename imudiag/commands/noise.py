"""The unit's white noise measured from a log, beside the certificate's, for ``diagnose``
and ``calibrate``.

One pass over (at most the first ``MAX_SECONDS`` of) the log with
:class:`imudiag.noise_estimate.NoiseMeter` gives the white-noise density per
channel; the report shows it beside the certificate's, with their ratio, and
calls a disagreement beyond :data:`~imudiag.noise_estimate.NOISE_MISMATCH_FACTOR`
a finding. The still detector estimates its noise from the data unless
``--certificate-noise`` asks it to trust the certificate.
"""

from __future__ import annotations

import argparse
from typing import Any

import numpy as np

from ..certificate import Certificate
from ..diagnosis.inputs import log_rate_hz
from ..logs import open_log
from ..logs.options import LogOptions, log_options
from ..noise_estimate import NOISE_MISMATCH_FACTOR, NoiseMeter, compare
from ..quasistatic import BAD_FLAGS
from ..samples import FLAG_SELF_TEST

#: Longest stretch of the log read to measure the noise (s of sample time).
MAX_SECONDS = 600.0


def add_noise_argument(p: argparse.ArgumentParser) -> None:
    """The ``--certificate-noise`` option."""
    p.add_argument(
        "--certificate-noise",
        action="store_true",
        help="trust the certificate's noise density for the still detector instead of "
        "measuring the unit's white noise from the log (default: measured; both are reported)",
    )


def measure(
    log: str,
    cert: Certificate,
    rate: float | None,
    block_size: int,
    options: LogOptions | None = None,
) -> dict[str, Any]:
    """The report's ``noise`` part: measured white noise per triad beside the certificate's."""
    meter = None
    t0 = None
    with open_log(log, block_size=block_size, options=options) as reader:
        for block in reader:
            if meter is None:
                meter = NoiseMeter(rate or log_rate_hz(reader.meta, block, cert))
                t0 = float(block.t[0]) if len(block) else None
            good = None
            if block.flags is not None:
                flags = np.asarray(block.flags).astype(np.int64)
                good = (flags & (BAD_FLAGS | FLAG_SELF_TEST)) == 0
            meter.update(block.gyro, block.accel, good)
            if t0 is not None and len(block) and float(block.t[-1]) - t0 > MAX_SECONDS:
                break
    figures = meter.result() if meter is not None else None
    report: dict[str, Any] = {"method": None, "mismatch_factor": NOISE_MISMATCH_FACTOR}
    for name, fig in (figures or {}).items():
        tri = cert.triad(name)
        certified = tri.noise.density if tri.noise is not None else None
        if not np.all(np.isfinite(fig.density)):
            # a gyro-only log (--known-rate): nothing to measure on that triad
            report[name] = {"measured": None, "unit": f"{tri.output_unit}/sqrt(Hz)"}
            continue
        entry: dict[str, Any] = {"measured": fig.as_dict(), "unit": f"{tri.output_unit}/sqrt(Hz)"}
        entry.update(compare(fig.density, certified))
        report[name] = entry
        report["method"] = fig.method
    return report


def noise_for_detector(
    args: argparse.Namespace, cert: Certificate, rate: float | None
) -> tuple[bool, dict[str, Any]]:
    """Whether the still detector trusts the certificate's noise, and the report's ``noise``.

    By default it does not: it estimates the noise from the quietest windows of
    the data (a data-sheet figure 1.5x too low leaves no window still, a figure
    too high takes motion for rest). ``--certificate-noise`` trusts the certificate.
    """
    report = measure(args.log, cert, rate, args.block_size, log_options(args))
    use_cert = bool(getattr(args, "certificate_noise", False))
    for name in ("gyro", "accel"):
        has_cert = cert.triad(name).noise is not None and cert.triad(name).noise.density is not None
        used = "certificate" if use_cert and has_cert else "data"
        report.setdefault(name, {"measured": None})["detector_noise"] = used
    return use_cert, report


def noise_lines(report: dict[str, Any]) -> list[str]:
    """Console lines: the measured noise beside the certificate's, and any disagreement."""
    lines = []
    for name in ("gyro", "accel"):
        e = report.get(name)
        if not e or not e.get("measured"):
            continue
        meas = ", ".join(f"{v:.3g}" for v in e["measured"]["density"])
        text = f"{name} white noise measured [{meas}] {e['unit']} ({report['method']})"
        if e.get("certificate") is not None:
            cert = ", ".join(f"{v:.3g}" for v in e["certificate"])
            ratio = ", ".join(f"{v:.2f}" for v in e["ratio"])
            text += f", certificate [{cert}], ratio [{ratio}]"
        text += f"; still detector: {e['detector_noise']} noise"
        lines.append(text)
        if e.get("disagrees"):
            lines.append(
                f"  finding: the certificate's {name} noise differs from the unit's by more "
                f"than {report['mismatch_factor']}x on some axis: the certificate is wrong there"
                + (
                    " (the still detector estimates the noise from the data)"
                    if e["detector_noise"] == "data"
                    else ""
                )
            )
    return lines

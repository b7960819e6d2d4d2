"""The unit's white noise measured from a log, beside the certificate's, for ``diagnose``
and ``calibrate``.

The figures come from :func:`imudiag.diagnosis.session.measure_noise` (one pass over at
most the first 600 s of the log); the report shows them beside the certificate's, with
their ratio, and calls a disagreement beyond
:data:`~imudiag.noise_estimate.NOISE_MISMATCH_FACTOR` a finding. The still detector
estimates its noise from the data unless ``--certificate-noise`` asks it to trust the
certificate.
"""

from __future__ import annotations

import argparse
import math
from typing import Any


def add_noise_argument(p: argparse.ArgumentParser) -> None:
    """The ``--certificate-noise`` option."""
    p.add_argument(
        "--certificate-noise",
        action="store_true",
        help="trust the certificate's noise density for the still detector instead of "
        "measuring the unit's white noise from the log (default: measured; both are reported)",
    )


def _figure(value: float | None, spec: str) -> str:
    """A figure of the report for a console line: ``-`` where it has none (null or NaN)."""
    return "-" if value is None or not math.isfinite(value) else format(value, spec)


def noise_lines(report: dict[str, Any]) -> list[str]:
    """Console lines: the measured noise beside the certificate's, and any disagreement."""
    lines = []
    for name in ("gyro", "accel"):
        e = report.get(name)
        if not e or not e.get("measured"):
            continue
        meas = ", ".join(_figure(v, ".3g") for v in e["measured"]["density"])
        text = f"{name} white noise measured [{meas}] {e['unit']} ({report['method']})"
        if e.get("certificate") is not None:
            cert = ", ".join(f"{v:.3g}" for v in e["certificate"])
            text += f", certificate [{cert}]"
            if e.get("ratio") is not None:
                text += f", ratio [{', '.join(f'{v:.2f}' for v in e['ratio'])}]"
        text += f"; still detector: {e['detector_noise']} noise"
        lines.append(text)
        if e.get("unmeasured"):
            lines.append(
                f"  {', '.join(e['unmeasured'])}: no noise figure (a stuck or constant output, "
                "or every stretch of it flagged): no ratio judged on this triad"
            )
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

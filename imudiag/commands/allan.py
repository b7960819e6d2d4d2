"""``imudiag allan LOG [--json OUT]``: Allan deviation, PSD and noise identification of a log.

Per sensor (gx gy gz ax ay az): the white-noise density measured the one way
every command measures it (:mod:`imudiag.noise_estimate`), the overlapping Allan
deviation, the IEEE 952 readings (N, bias instability B, random walk K; see
:mod:`imudiag.noise_stats` for units and conventions) and the Welch PSD with its
white-noise level; the last two white-noise readings are cross-checks of the
first, and a disagreement beyond 25 % is named (coloured noise or quantisation).
Meaningful on a still recording (motion shows up as noise).
The samples are taken as uniformly spaced; gaps in ``t`` are counted and reported.
"""

from __future__ import annotations

import argparse
import math
import sys
from typing import Any

import numpy as np

from ..argtypes import finite_float, positive_int, rate_problem, sample_rate, writable_output_path
from ..atomic import write_text_atomic
from ..errors import BadInput
from ..logs import LogError, open_log
from ..logs.options import LogOptions, add_log_options, log_options
from ..logs.timing import stated_rate_problem, timing_report
from ..noise_estimate import METHOD as WHITE_NOISE_METHOD
from ..noise_estimate import NoiseMeter
from ..noise_stats import identify_noise, overlapping_allan, welch_psd
from ..reports import ALLAN_FORMAT, header, json_text

SENSORS = ("gx", "gy", "gz", "ax", "ay", "az")
FORMAT = ALLAN_FORMAT
#: Cross-check readings of the white noise further than this from the measured density
#: (as a ratio) are named on the console and in ``white_noise_note``.
CROSS_CHECK_TOLERANCE = 1.25
UNITS = {
    "tau": "s",
    "adev": "output units",
    "white_noise_density": "output units/sqrt(Hz), one-sided (the certificate's noise.density), "
    "measured by white_noise_method: the figure every command uses",
    "white_noise": "output units/sqrt(Hz) (IEEE 952 N, sigma at tau = 1 s; cross-check)",
    "density_one_sided": "output units/sqrt(Hz) (sqrt(2) N from the Allan curve; cross-check)",
    "psd_white_density": "output units/sqrt(Hz) (Welch PSD, 0.1-0.4 of the rate; cross-check)",
    "bias_instability": "output units (Allan minimum / 0.664)",
    "random_walk": "output units/sqrt(s) (the certificate's noise.bias_random_walk)",
    "psd": "output units^2/Hz, one-sided",
}


MIN_PSD_SEGMENT = 16  #: fewest samples per Welch segment


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``allan`` subcommand."""
    p = sub.add_parser(
        "allan",
        help="Allan deviation, PSD and noise identification of a sample log",
        description="Overlapping Allan deviation and Welch PSD of each sensor of a log, and "
        "the white noise, bias instability and random walk read from the Allan curve "
        "(IEEE Std 952). Use a still recording.",
    )
    p.add_argument("log", metavar="LOG", help="sample log (.csv, .csv.gz, .npz, .bin)")
    p.add_argument(
        "--json",
        type=writable_output_path(stdout=True),
        metavar="OUT",
        help="write the report as JSON ('-' for stdout)",
    )
    p.add_argument(
        "--sensors", default=",".join(SENSORS), help="comma-separated sensors (default all six)"
    )
    p.add_argument(
        "--start", type=finite_float("s"), metavar="S", help="ignore samples before t = S s"
    )
    p.add_argument(
        "--stop", type=finite_float("s"), metavar="S", help="ignore samples after t = S s"
    )
    p.add_argument(
        "--rate",
        type=sample_rate,
        metavar="HZ",
        help="sample rate (default: the log's sample_rate, else from t)",
    )
    add_log_options(p)
    p.add_argument(
        "--points-per-decade",
        type=positive_int("tau values per decade"),
        default=10,
        metavar="K",
        help="tau values per decade (default 10)",
    )
    p.add_argument(
        "--psd-segment",
        type=positive_int("samples per segment", minimum=MIN_PSD_SEGMENT),
        default=4096,
        metavar="N",
        help="samples per Welch segment (default 4096, at most N/8)",
    )
    p.set_defaults(func=run, inputs=("log",), outputs=("json",))


def _collect(
    path: str, start: float | None, stop: float | None, options: LogOptions | None = None
) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """t (N,) and outputs (N, 6) of the log within [start, stop]."""
    ts: list[np.ndarray] = []
    us: list[np.ndarray] = []
    with open_log(path, options=options) as reader:
        for block in reader:
            keep = np.ones(len(block), dtype=bool)
            if start is not None:
                keep &= block.t >= start
            if stop is not None:
                keep &= block.t <= stop
            ts.append(block.t[keep])
            us.append(np.hstack([block.gyro[keep], block.accel[keep]]))
        meta = dict(reader.meta)
    t = np.concatenate(ts) if ts else np.zeros(0)
    u = np.concatenate(us) if us else np.zeros((0, 6))
    return t, u, meta


def analyse(
    t: np.ndarray,
    u: np.ndarray,
    rate_hz: float,
    sensors: list[str],
    points_per_decade: int = 10,
    psd_segment: int = 4096,
) -> dict[str, Any]:
    """The per-sensor report for samples ``u`` (N, 6) at ``rate_hz``."""
    out: dict[str, Any] = {}
    n = u.shape[0]
    meter = NoiseMeter(rate_hz)
    meter.update(u[:, :3], u[:, 3:])
    figures = meter.result()
    nperseg = int(min(psd_segment, max(16, 1 << int(math.log2(max(n // 8, 16))))))
    for name in sensors:
        y = u[:, SENSORS.index(name)]
        allan = overlapping_allan(y, rate_hz, points_per_decade=points_per_decade)
        terms = identify_noise(allan)
        psd = welch_psd(y, rate_hz, nperseg)
        band = (psd.frequency >= 0.1 * rate_hz) & (psd.frequency <= 0.4 * rate_hz)
        white_psd = math.sqrt(float(np.mean(psd.density[band]))) if np.any(band) else None
        k = SENSORS.index(name)
        measured = None
        if figures is not None:
            d = float(figures["gyro" if k < 3 else "accel"].density[k % 3])
            measured = d if math.isfinite(d) else None
        readings = terms.as_dict()
        out[name] = {
            "white_noise_density": measured,
            "white_noise_method": WHITE_NOISE_METHOD,
            "white_noise_note": _cross_check(
                measured, readings.get("density_one_sided"), white_psd
            ),
            **readings,
            "psd_white_density": white_psd,
            "allan": {
                "tau": allan.tau.tolist(),
                "adev": allan.adev.tolist(),
                "error": allan.error.tolist(),
            },
            "psd": {
                "frequency": psd.frequency.tolist(),
                "density": psd.density.tolist(),
                "segments": psd.segments,
            },
        }
    return out


def run(args: argparse.Namespace) -> int:
    """Analyse the log; returns the exit code."""
    sensors = [s.strip() for s in args.sensors.split(",") if s.strip()]
    if not sensors:
        raise BadInput(f"--sensors: names no sensor; expected some of {' '.join(SENSORS)}")
    for s in sensors:
        if s not in SENSORS:
            raise BadInput(f"--sensors: unknown sensor {s!r}; expected {' '.join(SENSORS)}")
    t, u, meta = _collect(args.log, args.start, args.stop, log_options(args))
    if t.shape[0] < 16:
        raise LogError(args.log, f"{t.shape[0]} samples in the selected range; need at least 16")
    # a stuck output (one value throughout) has no Allan curve: every deviation is 0, and
    # the term fit divides by it (a LinAlgError traceback before 2026-11-29)
    stuck = [s for s in sensors if np.ptp(u[:, SENSORS.index(s)]) == 0]
    if stuck:
        raise LogError(
            args.log,
            f"{', '.join(stuck)}: the same value in every sample of the selected range "
            "(a stuck output has no noise to measure); leave "
            f"{'it' if len(stuck) == 1 else 'them'} out with --sensors",
        )
    dt = np.diff(t)
    median_dt = float(np.median(dt))
    timing = timing_report(t, meta)
    rate = args.rate
    if rate is not None:
        problem = stated_rate_problem(rate, t)
        if problem:
            raise BadInput(f"{args.log}: {problem}")
    else:
        # the log's numeric sample_rate, else the rate its time stamps show (a
        # descriptive sample_rate such as "about 90-100" is stated, not fatal)
        rate = timing.metadata_rate_hz or 1.0 / median_dt
    if timing.note:
        print(f"{args.log}: {timing.note}", file=sys.stderr)
    problem = rate_problem(rate)
    if problem:
        raise BadInput(f"{args.log}: sample_rate: {problem}")
    gaps = int(np.count_nonzero(dt > 1.5 / rate))
    report = {
        **header(FORMAT),
        "log": args.log,
        "samples": int(t.shape[0]),
        "rate_hz": rate,
        "duration_s": float(t[-1] - t[0]),
        "gaps": gaps,
        "timing": timing.as_dict(),
        "units": UNITS,
        "sensors": analyse(t, u, rate, sensors, args.points_per_decade, args.psd_segment),
    }
    # the table goes to stderr when the JSON report takes stdout
    _print_table(report, sys.stderr if args.json == "-" else sys.stdout)
    if args.json:
        text = json_text(report)
        if args.json == "-":
            sys.stdout.write(text + "\n")
        else:
            try:
                write_text_atomic(args.json, text + "\n")
            except OSError as exc:
                raise BadInput(f"{args.json}: cannot write: {exc.strerror or exc}") from None
    return 0


def _cross_check(
    measured: float | None, allan_density: float | None, psd_density: float | None
) -> str | None:
    """Why the cross-check readings disagree with the measured density, or None."""
    if measured is None or measured <= 0:
        return None
    off = []
    for label, v in (("Allan sqrt(2) N", allan_density), ("PSD", psd_density)):
        if v is not None and v > 0:
            r = v / measured
            if not 1.0 / CROSS_CHECK_TOLERANCE <= r <= CROSS_CHECK_TOLERANCE:
                off.append(f"{label} {r:.2f}x")
    if not off:
        return None
    return (
        "cross-checks off: " + ", ".join(off) + " (coloured noise, quantisation or motion "
        "in the record: trust the measured density for the white part)"
    )


def _fmt(v: float | None) -> str:
    return "-" if v is None else f"{v:.4g}"


def _print_table(report: dict[str, Any], out: Any) -> None:
    print(
        f"{report['log']}: {report['samples']} samples at {report['rate_hz']:g} Hz, "
        f"{report['duration_s']:.1f} s, {report['gaps']} gaps",
        file=out,
    )
    print(
        f"white noise: one-sided density, measured by {WHITE_NOISE_METHOD} (the figure "
        "calibrate, diagnose and model-check use; Allan N and the PSD are cross-checks "
        "in the JSON)",
        file=out,
    )
    print("sensor  white [u/rtHz]  B [u] (tau s)  K [u/rts]", file=out)
    notes = []
    for name, r in report["sensors"].items():
        b = f"{_fmt(r['bias_instability'])} ({r['bias_instability_tau']:.3g})"
        if not r["bias_floor"]:
            b = "<=" + b
        print(
            f"{name:6s}  {_fmt(r['white_noise_density']):>14s}  {b:>13s}  {_fmt(r['random_walk'])}",
            file=out,
        )
        if r["white_noise_note"]:
            notes.append(f"{name}: {r['white_noise_note']}")
    for line in notes:
        print(line, file=out)

"""``imudiag diagnose LOG --certificate CERT --json OUT``: replay a log through the monitor
and the sliding-window 18-parameter diagnosis, as the daemon would (spec/reports.md).

The per-sample F0 counts come from :class:`imudiag.monitor.Monitor`; the
verdict, faults, undetermined parameters and the per-window estimates from
:class:`imudiag.diagnosis.StreamingDiagnoser`. The log is streamed in blocks.
``--method linear`` runs the paper's literal linearised solution and
``--method moving-base`` the moving-base variant (with ``--magnitude FILE``,
independent magnitudes; without, the paper's own circular estimate), for
comparison with the default exact fit.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from ..argtypes import (
    named_paths,
    nonnegative_float,
    positive_float,
    positive_int,
    sample_rate,
    writable_directory,
    writable_output_path,
)
from ..atomic import write_text_atomic
from ..diagnosis.config import GYRO_MODES, METHODS, DiagnosisConfig
from ..diagnosis.known_rate import parse_known_rate
from ..diagnosis.session import DiagnosisTrace, diagnose_recording
from ..errors import BadInput
from ..logs import DEFAULT_BLOCK_SIZE
from ..logs.options import add_log_options, log_options
from ..progress import for_command
from ..reports import json_text
from .gnss import (
    add_gnss_arguments,
    check_gnss_options,
    moving_base_lines,
    moving_base_section,
    verdict_faults,
)
from .noise import add_noise_argument, noise_lines


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``diagnose`` subcommand."""
    p = sub.add_parser(
        "diagnose",
        help="F0 checks and the 18-parameter scalar diagnosis of a sample log",
        description="Replays a sample log through the per-sample F0 checks and the "
        "sliding-window 18-parameter scalar diagnosis, and says which sensor left its "
        "certificate and why (bias, scale factor, misalignment), or what the data "
        "cannot tell.",
    )
    add_common_arguments(p)
    p.add_argument(
        "--certificate",
        "-c",
        metavar="CERT",
        help="certificate to compare with (default: the bundled one), or 'auto': the bundled "
        "data-sheet certificate the log names (a PX4 ULog's, an ArduPilot DataFlash log's)",
    )
    p.add_argument(
        "--json",
        type=writable_output_path(stdout=True),
        metavar="OUT",
        help="write the report as JSON ('-' for stdout)",
    )
    p.add_argument(
        "--no-windows", action="store_true", help="leave the per-window estimates out of the report"
    )
    p.add_argument(
        "--window-intervals",
        type=positive_int("quasi-static intervals"),
        metavar="K",
        help="quasi-static intervals per window (default 24)",
    )
    p.add_argument(
        "--persist",
        type=positive_int("windows"),
        metavar="N",
        help="consecutive windows a fault must persist (default 2)",
    )
    p.add_argument(
        "--k-sigma",
        type=positive_float("std"),
        metavar="K",
        help="a fault deviates by more than K std (the estimate's and the certificate's "
        "stated uncertainty combined) as well as the limit (default 4)",
    )
    p.add_argument(
        "--min-dof",
        type=nonnegative_float("degrees of freedom"),
        metavar="N",
        help="redundant observations a window's fit needs to be judged (default 3)",
    )
    p.add_argument(
        "--plots",
        type=writable_directory,
        metavar="DIR",
        help="write PNG figures into DIR: each parameter's window estimates against the "
        "certificate (estimates_accel.png, estimates_gyro.png) and the F0 trace "
        "(f0_trace.png); needs matplotlib (pip install 'imudiag[plots]')",
    )
    add_gnss_arguments(p)
    p.set_defaults(func=run, inputs=("log", "certificate", "magnitude", "gnss"), outputs=("json",))


def add_common_arguments(p: argparse.ArgumentParser) -> None:
    """Arguments shared by ``diagnose`` and ``calibrate``."""
    p.add_argument("log", metavar="LOG", help="sample log (.csv, .csv.gz, .npz, .bin)")
    p.add_argument(
        "--method",
        choices=METHODS,
        default="exact",
        help="exact (default): quasi-static intervals, exact model; linear: the "
        "paper's literal linearised solution; moving-base: every sample with a "
        "per-sample magnitude",
    )
    p.add_argument(
        "--magnitude",
        metavar="FILE",
        help="moving-base: CSV t,accel,gyro of independent magnitudes (s, m/s^2, rad/s)",
    )
    p.add_argument(
        "--gyro-mode",
        choices=GYRO_MODES,
        default="auto",
        help="gyro fit: earth-rate (navigation grade), rotation (MEMS), auto "
        "(from the certificate's noise; default)",
    )
    p.add_argument(
        "--rate",
        type=sample_rate,
        metavar="HZ",
        help="sample rate (default: the log's sample_rate, else from t)",
    )
    p.add_argument(
        "--block-size",
        type=positive_int("samples per block"),
        default=DEFAULT_BLOCK_SIZE,
        metavar="N",
        help=f"samples per block read (default {DEFAULT_BLOCK_SIZE})",
    )
    p.add_argument(
        "--min-interval",
        type=positive_float("s"),
        metavar="S",
        help="shortest still stretch used, s (default "
        f"{DiagnosisConfig().min_interval_s:g}; each is weighted by its noise)",
    )
    p.add_argument(
        "--known-rate",
        metavar="RATE",
        help="gyros on a turntable turning at this rate, with a unit (33.333rpm, "
        "200deg/s, 3.49rad/s, 0.5rev/s): constant-rate plateaus are the intervals "
        "and the gyro fit uses this magnitude instead of Earth rate; stopped "
        "plateaus are set aside; a log without accelerometer columns is accepted "
        "and the accelerometers are not diagnosed or calibrated",
    )
    p.add_argument(
        "--quiet",
        "-q",
        action="store_true",
        help="no progress bar on standard error (drawn only on a terminal anyway)",
    )
    add_noise_argument(p)
    add_log_options(p)  # after --rate, which it shares


def check_plots(args: argparse.Namespace, files: tuple[str, ...]) -> None:
    """Before any work: matplotlib installed, ``--plots DIR`` usable, and none of the figure
    files an input of the command (exit 2 otherwise)."""
    if not args.plots:
        return
    from ..atomic import refuse_overwrite
    from ..plots import check_directory, require

    require()
    directory = check_directory(args.plots)
    refuse_overwrite(
        named_paths(args, args.inputs), [("--plots", str(directory / f)) for f in files]
    )


def plot_lines(paths: list[str]) -> list[str]:
    """The console lines naming the figures written."""
    return [f"plot: {p}" for p in paths]


def make_config(args: argparse.Namespace, **extra: Any) -> DiagnosisConfig:
    """The diagnosis configuration from command-line options."""
    d: dict[str, Any] = {"method": args.method, "gyro_mode": args.gyro_mode}
    for opt, key in (
        ("window_intervals", "window_intervals"),
        ("persist", "persist"),
        ("k_sigma", "k_sigma"),
        ("min_interval", "min_interval_s"),
        ("min_dof", "min_dof"),
    ):
        v = getattr(args, opt, None)
        if v is not None:
            d[key] = v
    if getattr(args, "known_rate", None) is not None:
        d["known_rate_rad_s"] = parse_known_rate(args.known_rate)
    if getattr(args, "no_windows", False):
        d["max_windows_kept"] = 16  # not listed: keep only what the predicates need
    d.update(extra)
    try:
        return DiagnosisConfig.from_dict(d)
    except ValueError as exc:
        raise BadInput(f"options: {exc}") from None


def write_json(report: dict, out: str) -> None:
    """Write ``report`` to ``out`` ('-' for standard output); a value not determined (NaN)
    is ``null``."""
    text = json_text(report)
    if out == "-":
        sys.stdout.write(text + "\n")
        sys.stdout.flush()
    else:
        try:
            write_text_atomic(out, text + "\n")
        except OSError as exc:
            raise BadInput(f"{out}: cannot write: {exc.strerror or exc}") from None


#: what the number of each per-sample check measures, for text
F0_MEASURES = {
    "f0": "F0, dimensionless",
    "rest_rate": "rest rate over its limit, dimensionless",
    "known_rate": "plateau F0 against the known rate, dimensionless",
}


def _stepped(step: dict | None, unit: str) -> str:
    """The summary's note of a bias taken after a step of the rest rate (a fault's
    ``step``), or ""."""
    if not step:
        return ""
    return (
        f"; its rest rate stepped from {step['before']:.6g} to {step['after']:.6g}{unit} at "
        f"t = {step['t_after']:.2f} s"
    )


def _since(t: float | None) -> str:
    """`` from t = 1.23 s`` (sample time, s), or nothing when it is not known."""
    return "" if t is None else f" from t = {t:.2f} s"


def _times(n: int) -> str:
    """``raised once``, ``raised 3 times``."""
    return "raised once" if n == 1 else f"raised {n} times"


def summary_lines(report: dict) -> list[str]:
    """A short human-readable account of a diagnosis report."""
    v = report["verdict"]
    lines = [
        f"samples {report['samples']}, quasi-static intervals {report.get('intervals')}, "
        f"windows {report.get('windows_run')}, method {report.get('method')}"
    ]
    for triad in ("accel", "gyro"):
        f0 = report["f0"].get(triad, {})
        lines.append(
            f"{triad}: {v[triad]} (F0 checked {f0.get('checked', 0)}, failed {f0.get('failed', 0)})"
        )
        if f0.get("why"):
            lines.append(f"  F0 checked nothing: {f0['why']}")
    for f in v["faults"]:
        if f.get("source") in ("moving_base", "gyro_turns"):
            continue  # said with the moving-base section's lines
        if f["cause"] == "noise" and f.get("estimate") is None:
            lines.append(f"  FAULT {f['triad']} {f['sensor']} noise: persistent excess at rest")
            continue
        if f["cause"] == "stuck":
            from ..monitor.stuck import stuck_words  # the monitor's, loaded by the diagnosis

            lines.append(
                f"  FAULT {f['triad']} {f['sensor']} stuck: {stuck_words(f)} "
                f"({_times(f['raised'])})"
            )
            continue
        if f["cause"] == "saturation":
            lines.append(
                f"  FAULT {f['triad']} saturation: persistent saturation flags"
                f"{_since(f['t_first'])} ({_times(f['raised'])})"
            )
            continue
        if f["cause"] == "f0":
            lines.append(
                f"  FAULT {f['triad']} {f['sensor'] or '(triad)'} f0: {f['failed']} of "
                f"{f['checked']} checks beyond the limit {f['limit']:.6g} (rms "
                f"{f['check']} {f['estimate']:.3g}; "
                f"{F0_MEASURES.get(f['check'], 'dimensionless')}), persistent from t = "
                f"{f['t_first']:.2f} s"
            )
            continue
        unit = f" {f['unit']}" if f.get("unit") else ""
        lines.append(
            f"  FAULT {f['triad']} {f['sensor']} {f['cause']}: estimate "
            f"{f['estimate']:.6g}{unit}, certificate {f['certificate']:.6g}{unit}, limit "
            f"{f['limit']:.6g}{unit}, first at t = {f['t_first']:.2f} s"
            + _stepped(f.get("step"), unit)
        )
    for f in v.get("withdrawn", []):
        lines.append(
            f"  withdrawn {f['triad']} {f['sensor']} {f['cause']} (first at t = "
            f"{f['t_first']:.2f} s): {f['reason']}"
        )
    wire = report.get("wire")
    if wire:
        lines.append(
            f"wire capture: {wire['frames']} frames, {wire['crc_errors']} CRC errors, "
            f"{wire['lost']} lost, {wire['duplicates']} duplicates, "
            f"{wire['skipped_bytes']} bytes skipped of {wire['bytes']}"
        )
    for u in v["undetermined"]:
        lines.append(f"  undetermined {u['triad']} {u['sensor']} {u['cause']}: {u['reason']}")
    return lines


def run(args: argparse.Namespace) -> int:
    """Run the diagnosis over the log and write the report."""
    from ..plots.diagnosis import FILES  # the names only: matplotlib is imported to draw

    check_plots(args, FILES)
    from ..logs.datasheet import certificate_for_log

    cert = certificate_for_log(args.certificate, args.log, log_options(args))
    if cert.device.get("warning"):
        print(
            f"imudiag diagnose: warning: {cert.source}: {cert.device['warning']}", file=sys.stderr
        )
    cfg = make_config(args)
    if args.magnitude and cfg.method != "moving-base":
        raise BadInput("--magnitude: only the moving-base method uses independent magnitudes")
    if cfg.method == "moving-base" and not args.magnitude:
        print(
            "imudiag diagnose: warning: moving-base without --magnitude uses the magnitude "
            "estimated from the triad itself (the paper's eqs. 17-18), which cannot see "
            "faults",
            file=sys.stderr,
        )
    check_gnss_options(args)
    trace = DiagnosisTrace() if args.plots else None
    with for_command("diagnose", args.quiet) as progress:
        report = diagnose_recording(
            args.log,
            cert,
            cfg,
            rate_hz=args.rate,
            magnitude=args.magnitude,
            certificate_noise=args.certificate_noise,
            options=log_options(args),
            block_size=args.block_size,
            windows=not args.no_windows,
            progress=progress,
            trace=trace,
        )
    report["log"] = str(args.log)
    noise_report = report["noise"]
    section = moving_base_section(args, cert, report["sample_rate"])
    if section is not None:
        report["moving_base"] = section
        # every named fault in the top-level verdict, the drive's included (issue 25)
        for fault in verdict_faults(section):
            report["verdict"]["faults"].append(fault)
            report["verdict"][fault["triad"]] = "fault"
    if trace is not None:
        from ..plots.diagnosis import write_diagnosis_plots

        report["plots"] = [str(p) for p in write_diagnosis_plots(trace, cert, args.plots)]
    if args.json:
        write_json(report, args.json)
    out = sys.stderr if args.json == "-" else sys.stdout
    lines = summary_lines(report) + noise_lines(noise_report)
    if "moving_base" in report:
        lines += moving_base_lines(report["moving_base"])
    lines += plot_lines(report.get("plots", []))
    for line in lines:
        print(line, file=out)
    return 0

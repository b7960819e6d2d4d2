"""``imudiag calibrate LOG --like CERT --out CERT2``: scalar calibration from a
multi-position session (spec/reports.md).

Estimates biases, scale-factor errors and misalignment of both triads from
the quasi-static intervals of the log (and the rotations between them for
MEMS gyros), takes scale factors, units and limits from ``--like`` and writes a
certificate. The misalignment gauge is documented in
:mod:`imudiag.diagnosis.calibrate`. Prints the |a| spread over the intervals
before and after, and what the session could not determine.
"""

from __future__ import annotations

import argparse
import sys

from ..argtypes import writable_directory, writable_output_path
from ..diagnosis.config import SHORT_HOLDS
from ..diagnosis.session import calibrate_recording
from ..errors import BadInput
from ..logs.datasheet import certificate_for_log
from ..logs.options import log_options
from ..progress import for_command
from .diagnose import add_common_arguments, check_plots, make_config, plot_lines, write_json
from .noise import noise_lines


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``calibrate`` subcommand."""
    p = sub.add_parser(
        "calibrate",
        help="scalar calibration of both triads from a multi-position log",
        description="Scalar calibration from a multi-position session: biases, scale-factor "
        "errors and misalignment of both triads; scale factors, units and limits from --like.",
    )
    add_common_arguments(p)
    p.add_argument(
        "--like",
        required=True,
        metavar="CERT",
        help="certificate giving scale factors, units, limits and starting values; 'auto': "
        "the data sheet an autopilot's log names (PX4 ULog, ArduPilot DataFlash: the flight "
        "controller's IMU)",
    )
    p.add_argument(
        "--out",
        required=True,
        type=writable_output_path(),
        metavar="CERT2",
        help="certificate to write",
    )
    p.add_argument(
        "--json",
        type=writable_output_path(stdout=True),
        metavar="OUT",
        help="write a calibration summary as JSON ('-' for stdout)",
    )
    p.add_argument(
        "--force",
        action="store_true",
        help="write the certificate even when the held-out check says the "
        "calibration does not generalise (it then carries device.warning)",
    )
    p.add_argument(
        "--plots",
        type=writable_directory,
        metavar="DIR",
        help="write PNG figures into DIR: |a|/g - 1 of the intervals (accel_norm_residuals.png) "
        "and the gravity direction after the rotations (rotation_residuals.png) before and "
        "after; with --known-rate |w|/rate - 1 of the plateaus (gyro_norm_residuals.png); "
        "needs matplotlib (pip install 'imudiag[plots]')",
    )
    p.add_argument(
        "--short-holds",
        choices=SHORT_HOLDS,
        help="the short-hold detector (a 16-sample window, the minimum hold from the measured "
        "noise and the rate): auto (default) when the default detector keeps fewer than 18 "
        "holds or drops more than it keeps; always; never (the default with --min-interval)",
    )
    p.set_defaults(func=run, inputs=("log", "like", "magnitude"), outputs=("out", "json"))


def run(args: argparse.Namespace) -> int:
    """Calibrate from the log and write the certificate."""
    from ..plots.calibration import FILES  # the names only: matplotlib is imported to draw

    check_plots(args, FILES)
    like = certificate_for_log(args.like, args.log, log_options(args), "--like")
    short = args.short_holds or ("never" if args.min_interval is not None else "auto")
    cfg = make_config(args, short_holds=short)
    with for_command("calibrate", args.quiet) as progress:
        result = calibrate_recording(
            args.log,
            like,
            cfg,
            rate_hz=args.rate,
            magnitude=args.magnitude,
            certificate_noise=args.certificate_noise,
            options=log_options(args),
            block_size=args.block_size,
            progress=progress,
        )
    plots: list[str] = []
    if args.plots:
        from pathlib import Path

        from ..plots.calibration import write_calibration_plots

        written = write_calibration_plots(result, args.plots, Path(args.like).name)
        plots = [str(p) for p in written]
    noise_report = result.noise or {}
    check = result.generalisation or {}
    gcheck = result.gyro_generalisation or {}
    reasons = result.refusals()
    refused = bool(reasons)
    if refused:
        result.certificate.device["warning"] = (
            f"written with --force: the calibration does not generalise: {'; '.join(reasons)}"
        )
    else:
        unchecked = [
            c["reason"] for c in (check, gcheck) if c.get("generalises") is None and c.get("reason")
        ]
        if unchecked:
            result.certificate.device["calibration_check"] = "; ".join(unchecked)
    if refused and not args.force:
        print(
            f"imudiag calibrate: refused: {args.log}: {'; '.join(reasons)}; nothing written "
            f"(--force writes it with a warning)",
            file=sys.stderr,
        )
        if args.json:
            summary = result.summary()
            summary.update(log=str(args.log), like=str(args.like), out=None, refused=True)
            if args.plots:
                summary["plots"] = plots
            write_json(summary, args.json)
        for line in plot_lines(plots):
            print(line, file=sys.stderr)
        return 1
    try:
        result.certificate.save(args.out)
    except OSError as exc:
        raise BadInput(f"{args.out}: cannot write: {exc.strerror or exc}") from None
    summary = result.summary()
    summary["log"] = str(args.log)
    summary["like"] = str(args.like)
    summary["out"] = str(args.out)
    summary["noise"] = noise_report
    summary["refused"] = False
    if args.plots:
        summary["plots"] = plots
    if args.json:
        write_json(summary, args.json)
    out = sys.stderr if args.json == "-" else sys.stdout
    b, a = result.accel_spread_before, result.accel_spread_after
    kr = result.known_rate
    if kr is not None:
        print(
            f"{kr['plateaus']} plateaus at {kr['rate']:.6g} {kr['unit']} used "
            f"({kr['set_aside']} set aside, of {result.intervals} constant-rate intervals); "
            f"wrote {args.out}",
            file=out,
        )
        b, a = kr["norm_spread"]["before"], kr["norm_spread"]["after"]
        print(
            f"|w|/rate - 1 over the plateaus: rms {b['rms']:.3e} -> {a['rms']:.3e}, "
            f"peak-to-peak {b['peak_to_peak']:.3e} -> {a['peak_to_peak']:.3e}",
            file=out,
        )
    elif b is not None and a is not None:
        print(
            f"{result.intervals} quasi-static intervals, {result.attitudes} attitudes, "
            f"{result.rotations} rotations; wrote {args.out}",
            file=out,
        )
        print(
            f"|a|/g - 1 over the intervals: rms {b['rms']:.3e} -> {a['rms']:.3e}, "
            f"peak-to-peak {b['peak_to_peak']:.3e} -> {a['peak_to_peak']:.3e}",
            file=out,
        )
    if result.rotation_rms_before_deg is not None:
        print(
            f"gravity direction after integrated rotations, rms: "
            f"{result.rotation_rms_before_deg:.3f} -> {result.rotation_rms_after_deg:.3f} deg",
            file=out,
        )
    for line in noise_lines(noise_report):
        print(line, file=out)
    holds = result.holds or {}
    if holds.get("found"):
        dropped = "; ".join(f"{n} {why}" for why, n in holds["dropped"].items() if n)
        print(
            f"still holds: {holds['found']} found, {holds['used']} used"
            + (f", dropped: {dropped}" if dropped else "")
            + f"; detector: {holds['detector']}",
            file=out,
        )
    for c, what in ((check, "intervals"), (gcheck, "motions")):
        if c.get("leave_one_out_rms") is not None:
            if c.get("by") == "attitude":
                what, n_out = "attitudes", c["attitudes_held_out"]
            else:
                n_out = c["held_out"]
            print(
                f"held-out check: {c['quantity']} rms {c['leave_one_out_rms']:.3e} "
                f"leaving each of "
                f"{n_out} {what} out (in-sample {c['in_sample_rms']:.3e})",
                file=out,
            )
            if c.get("note"):
                print(f"  note: {c['note']}", file=out)
    if refused:
        print(f"WARNING: {result.certificate.device['warning']}", file=sys.stderr)
    else:
        for c in (check, gcheck):
            if c.get("reason"):
                print(f"  note: generalisation {c['reason']}", file=out)
    for r in result.rejected():
        what = (
            f"set aside {r['point']}"
            if "rate" in r
            else (f"rejected {r['point']}" if r.get("point") else "outliers left in")
        )
        print(f"  {what} ({r['triad']} fit): {r['reason']}", file=out)
    for u in result.undetermined:
        print(
            f"  undetermined {u['triad']} {u['sensor']} {u['cause']}: {u['reason']}",
            file=out,
        )
    for fit in (result.accel, result.gyro):
        prior = fit.extra.get("prior") or {}
        if prior.get("decided_by_prior"):
            shares = ", ".join(
                f"{n} {100 * sh:.0f} %"
                for n, sh in zip(prior["parameters"], prior["share"], strict=True)
                if n in prior["decided_by_prior"]
            )
            print(f"  decided by the prior toward --like ({fit.triad}): {shares}", file=out)
    for line in plot_lines(plots):
        print(line, file=out)
    return 0

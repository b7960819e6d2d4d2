"""``--gnss`` options of ``imudiag diagnose``: the moving-base diagnosis aided by GNSS."""

from __future__ import annotations

import argparse
import math

from ..argtypes import finite_float, positive_float
from ..certificate import Certificate
from ..errors import BadInput


def add_gnss_arguments(p: argparse.ArgumentParser) -> None:
    """Options of the GNSS-aided moving-base diagnosis (docs/moving-base.md)."""
    g = p.add_argument_group("moving base (GNSS aiding, docs/moving-base.md)")
    g.add_argument(
        "--gnss",
        metavar="auto|log|none|FILE",
        default="auto",
        help="GNSS for the moving-base F0 and accelerometer fit in motion: auto (default) "
        "the log's own GNSS where it has it (DataFlash GPS, ULog vehicle_gps_position/"
        "sensor_gps, ROS NavSatFix + velocity; its clock tied to GNSS time by a fitted "
        "offset and rate), log (the same, refused when it cannot), none, or a gpsd TPV log "
        "FILE (gpspipe -w, plain or .gz; both in UTC Unix time)",
    )
    g.add_argument(
        "--lever-arm",
        metavar="X,Y,Z",
        help="antenna position from the IMU in body axes, m (default: estimated from the "
        "turns, used on the axes it determines, 0 elsewhere)",
    )
    g.add_argument(
        "--gnss-latency",
        type=finite_float("s"),
        metavar="S",
        help="GNSS latency, s (default: estimated from the data)",
    )
    g.add_argument(
        "--gnss-interval",
        type=positive_float("s"),
        default=1.0,
        metavar="S",
        help="GNSS epoch used, s (whole GNSS periods; default 1)",
    )
    g.add_argument(
        "--gnss-window",
        type=positive_float("s"),
        default=180.0,
        metavar="S",
        help="moving-base fit window, s (default 180)",
    )


def parse_lever_arm(text: str | None) -> tuple[float, float, float] | None:
    """``X,Y,Z`` in m (None when not given: estimated); BadInput naming the option
    otherwise."""
    if not text:
        return None
    try:
        vals = tuple(float(x) for x in text.split(","))
    except ValueError:
        raise BadInput(f"--lever-arm: expected X,Y,Z in m, got {text!r}") from None
    if len(vals) != 3 or not all(math.isfinite(v) for v in vals):
        raise BadInput(f"--lever-arm: expected three finite numbers X,Y,Z in m, got {text!r}")
    return (vals[0], vals[1], vals[2])


def check_latency(latency_s: float | None) -> None:
    """BadInput when ``--gnss-latency`` (s) lies outside the +-``max_latency_s`` (s) the
    latency estimate searches (docs/moving-base.md: receivers report 0.02-0.2 s late): a
    value in ms given as seconds (2, -3, 120) would shift every GNSS epoch by seconds and
    raise false accelerometer faults. Names the reading in ms when that one fits."""
    if latency_s is None:
        return  # the aiding code is not imported for a log without GNSS options
    from ..aiding.moving import MovingConfig

    bound = MovingConfig.max_latency_s
    if abs(latency_s) <= bound:
        return
    hint = (
        f"; if {latency_s:g} is in ms, give --gnss-latency {latency_s / 1000:g}"
        if abs(latency_s) / 1000 <= bound
        else ""
    )
    raise BadInput(
        f"--gnss-latency: {latency_s:g} s is beyond the +-{bound:g} s a GNSS latency can be "
        f"(the range its estimate searches; the option is in s){hint}"
    )


def check_gnss_options(args: argparse.Namespace) -> None:
    """Validate the options before the log is read."""
    check_latency(getattr(args, "gnss_latency", None))
    if getattr(args, "gnss", None) in (None, "none"):
        _refuse_gnss_options(args, "needs GNSS (--gnss auto, log or FILE)")
        return
    if args.gnss == "auto" and not log_may_hold_gnss(args.log):
        check_gnss_options_without_log_gnss(args)
    parse_lever_arm(args.lever_arm)  # --gnss-interval and --gnss-window: checked when parsed


#: Log formats that may carry their own GNSS (``reader.gnss()``).
GNSS_LOG_FORMATS = ("dataflash", ".ulg", "rosbag1", "rosbag2")


def log_may_hold_gnss(path: str) -> bool:
    """Whether the log's format can carry GNSS fixes of its own (a CSV cannot)."""
    from ..logs import lookup

    try:
        return lookup(path).name in GNSS_LOG_FORMATS
    except BadInput:
        return False  # the reader says what is wrong with the file


def check_gnss_options_without_log_gnss(args: argparse.Namespace) -> None:
    """``--gnss auto`` on a log without GNSS of its own: the GNSS options are an error."""
    _refuse_gnss_options(args, "needs --gnss FILE (the log holds no GNSS of its own)")


def _refuse_gnss_options(args: argparse.Namespace, why: str) -> None:
    """BadInput naming the first GNSS option given (``--lever-arm``, ``--gnss-latency``)."""
    for opt in ("lever_arm", "gnss_latency"):
        if getattr(args, opt, None) is not None:
            raise BadInput(f"--{opt.replace('_', '-')}: {why}")


def moving_config(args: argparse.Namespace) -> object:
    """The moving-base configuration of the command line's ``--gnss-*`` options."""
    from ..aiding.moving import MovingConfig

    return MovingConfig(
        interval_s=args.gnss_interval,
        latency_s=args.gnss_latency,
        lever_arm_m=parse_lever_arm(args.lever_arm),
        window_s=args.gnss_window,
        step_s=args.gnss_window / 3.0,
    )


def moving_base_section(args: argparse.Namespace, cert: Certificate, rate_hz: float) -> dict | None:
    """The moving-base section of ``diagnose``'s report (None: no GNSS to run it with):
    the log read again, with its own GNSS fixes for ``--gnss auto|log``."""
    if args.gnss == "auto" and not log_may_hold_gnss(args.log):
        return None  # a CSV: the aiding code is not even imported
    from ..aiding.log_clock import gnss_section_of
    from ..logs.options import log_options

    section = gnss_section_of(
        args.log, cert, args.gnss, moving_config(args), rate_hz, log_options(args),
        args.block_size,
    )  # fmt: skip
    if section is None:
        check_gnss_options_without_log_gnss(args)
    return section


def verdict_faults(mb: dict) -> list[dict]:
    """The moving-base section's faults (the accelerometers in motion and the gyros in
    turns) as top-level ``verdict.faults`` entries (issue 25 item 6): ``triad``, ``sensor``
    and ``cause`` where the drive names them; where it cannot tell the alternatives apart,
    ``one_of`` lists them, ``sensor`` and ``cause`` are theirs when all share it (else
    None and ``one_of``); ``source`` says which check raised it."""
    out = []
    raised = [(f, "moving_base") for f in mb.get("faults", [])]
    raised += [(f, "gyro_turns") for f in (mb.get("gyro_turns") or {}).get("faults", [])]
    for f, source in raised:
        entry = {k: v for k, v in f.items() if k != "named"}
        entry.setdefault("triad", "gyro" if source == "gyro_turns" else "accel")
        entry["source"] = source
        alts = f.get("one_of")
        if not f.get("named") and alts:
            sensors = {o["sensor"] for o in alts}
            causes = {o["cause"] for o in alts}
            entry["sensor"] = sensors.pop() if len(sensors) == 1 else None
            entry["cause"] = causes.pop() if len(causes) == 1 else "one_of"
        entry.setdefault("sensor", None)
        out.append({k: entry[k] for k in ("triad", "sensor", "cause")} | entry)
    return out


def _with_unit(f: dict) -> str:
    """``estimate E U, certificate C U, limit L U`` of a named fault (U its ``unit``)."""
    u = f" {f['unit']}" if f.get("unit") else ""
    return (
        f"estimate {f['estimate']:.6g}{u}, certificate {f['certificate']:.6g}{u}, "
        f"limit {f['limit']:.6g}{u}"
    )


def _counts(counts: dict[str, int]) -> str:
    """``{"outlier": 3, "gap": 1}`` as ``3 outlier, 1 gap`` (``none`` when empty)."""
    return ", ".join(f"{n} {why}" for why, n in counts.items()) or "none"


def moving_base_lines(mb: dict) -> list[str]:
    """A short account of the moving-base section."""
    g = mb["gnss"]
    if "epochs" not in g:
        return [f"moving base: {mb.get('verdict')} ({mb.get('reason', '')})"]
    lat = g.get("latency", {})
    lines = [
        f"moving base: GNSS {g['fixes']} fixes every {g['period_s']} s, {g.get('used', 0)} of "
        f"{g['epochs']} epochs of {g['epoch_s']} s used (rejected: {_counts(g['rejected'])}), "
        f"latency {lat.get('used_s')} s"
        + ("" if lat.get("determined") else f" ({lat.get('reason')})")
    ]
    clock = g.get("clock", {})
    if clock.get("how") == "fitted":
        lines.append(
            f"  IMU clock tied to GNSS time: rate {clock['rate']:.6f} GNSS s per log s "
            f"({clock['drift_ppm']:+.0f} ppm), residual rms {1e3 * clock['residual_rms_s']:.1f} "
            f"ms, max {1e3 * clock['residual_max_s']:.1f} ms over {clock['fixes']} fixes"
        )
    lev = g.get("lever_arm")
    if lev:
        est = ", ".join(
            "undetermined" if not d else f"{v:+.2f} +- {s:.2f}"
            for v, s, d in zip(lev["estimate_m"], lev["std_m"], lev["determined"], strict=True)
        )
        src = "configured" if lev["configured"] else "estimated"
        lines.append(f"  lever arm used {lev['used_m']} m ({src}); estimate x, y, z: {est} m")
    if "f0" in mb:
        f0 = mb["f0"]
        lines.append(
            f"  accel F0 in motion: {f0['failed']} of {f0['checked']} epochs failed "
            f"(median F0 {f0['f0_median']}, threshold {f0['threshold_median']})"
        )
    lines.append(f"  accel in motion: {mb.get('verdict')} ({mb.get('windows_run', 0)} windows)")
    for f in mb.get("faults", []):
        if f["named"]:
            lines.append(f"  FAULT accel {f['sensor']} {f['cause']}: {_with_unit(f)}")
        else:
            alts = ", ".join(f"{o['sensor']} {o['cause']} {o['estimate']:.6g}" for o in f["one_of"])
            lines.append(f"  FAULT accel, one of: {alts} ({f['reason']})")
    for fd in mb.get("findings", []):
        if not fd["fault"]:
            lines.append(f"  finding (not a fault): {fd['text']}")
    if "gyro_turns" in mb:
        lines += gyro_turn_lines(mb["gyro_turns"])
    return lines


def gyro_turn_lines(gt: dict) -> list[str]:
    """A short account of the gyros in turns (``moving_base.gyro_turns``)."""
    head = f"  gyro in turns (no-slip assumption): {gt['verdict']}"
    if "turns" not in gt:
        return [f"{head} ({gt.get('reason', '')})"]
    tu, f0 = gt["turns"], gt["f0"]
    det = ", ".join(f"{d['sensor']} {d['cause']}" for d in gt["determined"]) or "nothing"
    lines = [
        f"{head}: {gt['used']} epochs in {tu['count']} turns ({tu['angle_deg_total']} deg), "
        f"gyro |omega| / course rate {tu['ratio_total']}, F0 failed in {f0['failed']} of "
        f"{f0['checked']} turns; determined: {det}"
    ]
    for f in gt["faults"]:
        if f.get("named"):
            lines.append(f"  FAULT gyro {f['sensor']} {f['cause']}: {_with_unit(f)}")
        else:
            lines.append(f"  FAULT gyro {f['cause']} in turns ({f0['persist']} failed)")
    return lines


__all__ = [
    "add_gnss_arguments",
    "check_gnss_options",
    "check_latency",
    "check_gnss_options_without_log_gnss",
    "moving_config",
    "gyro_turn_lines",
    "verdict_faults",
    "moving_base_lines",
    "moving_base_section",
    "parse_lever_arm",
]

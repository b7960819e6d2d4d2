"""``imudiag simulate SCENARIO --duration S --seed N --out LOG``: a simulated session to a log.

Scenarios, effects and faults are described in :mod:`imudiag.sim.scenarios`;
the log format follows the file name (``.csv``, ``.csv.gz``, ``.npz``, ``.bin``).
The session is simulated and written in chunks, so long sessions stream.
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

from ..argtypes import (
    nonnegative_int,
    positive_float,
    positive_int,
    rate_problem,
    sample_rate,
    seed,
    writable_directory,
    writable_output_path,
)
from ..certificate import load, load_default
from ..errors import BadInput
from ..logs import log_format, lookup, open_writer
from ..progress import for_command
from ..sim.drive import EPOCH_UNIX, gnss_reports, write_gpspipe_log
from ..sim.effects import Effects
from ..sim.faults import Fault
from ..sim.scenarios import (
    DRIVES,
    SCENARIOS,
    canonical_scenario,
    describe,
    parse_effects,
    parse_faults,
    scenario_motion,
)
from ..sim.simulator import Simulator, true_certificate

T = TypeVar("T")
CHUNK_S = 30.0  #: seconds simulated per written block
MAX_CHUNK = 1 << 18  #: samples simulated per written block at most (fast rates)
_BIN_META_LIMIT = 249  #: bytes of JSON a device-info frame holds

EPILOG = """\
effects (--effect, applied in order to the 'board' preset):
  board | none | all | noise:SCALE | quantize | saturation:LOW:HIGH
  bias_drift:S:K (u/sqrt(s))   bias_instability:S:SIGMA:TAU (u, s; Gauss-Markov)
  flicker:S:B[:TAU_LOW:TAU_HIGH] (u; flat Allan floor 0.664 B over that band, s)
  rate_ramp:S:R (u/s)   quantization:S:STEP (u; integrating output, Q = STEP/(rate sqrt 12))
  temperature:START:WARMUP:TAU[:RAMP] (degC, degC, s, degC/s)
  temperature_bias:S:C (u/degC)   temperature_scale:S:C (1/degC)
  g_sensitivity:GS:KX:KY:KZ (u per accel input unit)   scale_nonlinearity:S:Q (u/input^2)
  bias_step:S:T:SIZE (s, u)   periodic_disturbance:S:AMP:FREQ (u, Hz)
  adc_error:P   drop:P   jitter:SECONDS
  (S a sensor gx gy gz ax ay az, GS a gyro; u = output units, counts on the bundled board)
faults (--fault kind:sensor:t_s[:value]):
  bias (u), scale_factor (u per input unit), misalignment (pair ax/ay ax/az ay/az, rad),
  stuck [value], noise (sigma multiplier), dead [value]; e.g. bias:ax:30:150
scenario parameters (--param key=value):
  static: n dwell turn latitude      still: roll pitch yaw latitude
  multiposition: n dwell turn first_dwell latitude
  turntable: turn_rate axis ramp latitude
  vehicle: still accel speed cruise turn turn_deg final latitude
  urban, highway, hilly, aircraft: length (s, whole legs; default 600); sample time is UTC
    Unix seconds from 2026-01-01, and --gnss OUT writes the drive's GNSS as a gpspipe -w log
  bounds: latitude -90..90 deg; times, lengths and speed >= 0 (length, turn, accel > 0);
    n a whole number >= 1, loop 0 or 1; fault times >= 0 s. A finite scenario that ends
    before --duration is written whole, with a warning saying how long it is
"""


def _log_or_folder(text: str) -> str:
    """``--out``: an existing writable folder (``simulate fleet``; any other scenario
    refuses it when it runs), else a file path whose directory is writable."""
    if text and Path(text).expanduser().is_dir():
        return writable_directory(text)
    return writable_output_path()(text)


_log_or_folder.writes_file = True  # type: ignore[attr-defined]  # argtypes.output_dests


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``simulate`` subcommand."""
    p = sub.add_parser(
        "simulate",
        help="simulate an IMU session and write a sample log",
        description="Simulate the board along a scenario with the certificate's model, "
        "effects and faults, and write a sample log (.csv, .csv.gz, .npz, .bin).",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "scenario",
        metavar="SCENARIO",
        help=f"one of {', '.join(SCENARIOS)} (or default = static), or fleet: a folder of "
        "vehicles and their flights (--vehicles, --flights) with truth.json",
    )
    p.add_argument(
        "--out",
        required=True,
        type=_log_or_folder,
        metavar="LOG",
        help="log to write (fleet: the folder to write the fleet into)",
    )
    p.add_argument(
        "--duration",
        type=positive_float("s"),
        metavar="S",
        help="seconds to simulate (required for the endless static, still, turntable)",
    )
    p.add_argument("--seed", type=seed, default=0, help="random seed (default 0)")
    p.add_argument(
        "--rate",
        type=sample_rate,
        metavar="HZ",
        help="sample rate, Hz (default: the certificate's sample_rate)",
    )
    p.add_argument("--certificate", help="certificate YAML (default: the bundled one)")
    p.add_argument(
        "--effect",
        action="append",
        default=[],
        metavar="SPEC",
        help="an effect (repeatable; see below)",
    )
    p.add_argument(
        "--fault",
        action="append",
        default=[],
        metavar="KIND:SENSOR:T[:VALUE]",
        help="a fault (repeatable)",
    )
    p.add_argument(
        "--param",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="a scenario parameter (repeatable)",
    )
    p.add_argument(
        "--gnss",
        type=writable_output_path(),
        metavar="OUT",
        help="drive scenarios: also write the GNSS stream as a gpspipe -w log "
        "(5 Hz, 0.03/0.05 m/s noise, 0.12 s latency, multipath outliers)",
    )
    p.add_argument(
        "--true-certificate",
        type=writable_output_path(),
        metavar="CERT",
        help="also write the true model at the end (faults and effects applied)",
    )
    p.add_argument(
        "--quiet",
        "-q",
        action="store_true",
        help="no progress bar on standard error (drawn only on a terminal anyway)",
    )
    g = p.add_argument_group("fleet (imudiag simulate fleet --vehicles N --flights M --out DIR)")
    g.add_argument("--vehicles", type=positive_int("vehicles"), metavar="N", help="vehicles")
    g.add_argument("--flights", type=positive_int("flights"), metavar="M", help="flights each")
    g.add_argument(
        "--drifting",
        type=nonnegative_int("vehicles"),
        metavar="K",
        help="vehicles with a parameter drifting over their flights (default a third, >= 1)",
    )
    g.add_argument(
        "--corrupt",
        type=nonnegative_int("files"),
        default=3,
        metavar="K",
        help="extra corrupt or truncated files (default 3)",
    )
    g.add_argument(
        "--flight-seconds",
        metavar="MIN:MAX",
        help="flight length range, s (default 35:60)",
    )
    p.set_defaults(func=run, inputs=("certificate",), outputs=("out", "true_certificate"))


def _meta(
    args: argparse.Namespace,
    rate: float,
    device: str,
    scenario: str,
    effects: Effects,
    faults: list[Fault],
) -> dict:
    meta: dict = {
        "sample_rate": int(rate) if float(rate).is_integer() else rate,
        "device": device,
        "source": f"imudiag simulate {scenario} seed={args.seed}",
        "faults": ",".join(f.to_text() for f in faults),
        "effects": ",".join(describe(effects)),
    }
    if log_format(args.out) == ".bin":
        for key in ("effects", "faults"):  # a device-info frame holds 249 bytes of JSON
            if len(json.dumps(meta, separators=(",", ":")).encode()) > _BIN_META_LIMIT:
                del meta[key]
    return meta


def _parsed(option: str, parse: Callable[[list[str]], T], specs: list[str]) -> T:
    """``parse(specs)``, a ValueError becoming BadInput naming ``option``."""
    try:
        return parse(specs)
    except ValueError as exc:
        raise BadInput(f"{option}: {exc}") from None


def check_faults_in_session(faults: list[Fault], total: int, rate: float) -> None:
    """BadInput for a fault timed at or after the session's end (it would touch no sample).

    Sample ``i`` is at ``i / rate`` s from the start; the session ends at ``total / rate`` s.
    """
    end = total / rate
    last = (total - 1) / rate if total else 0.0
    for f in faults:
        if f.t_s > last:
            raise BadInput(
                f"--fault {f.to_text()}: at t = {f.t_s:g} s, at or after the end of the "
                f"session ({end:g} s, last sample at t = {last:g} s)"
            )


def check_free_space(
    out: str, bytes_per_sample: float, total: int, rate: float, duration: float | None
) -> None:
    """BadInput when ``total`` samples of about ``bytes_per_sample`` B each would not fit
    the free space of the filesystem holding ``out`` (checked before anything is written)."""
    need = bytes_per_sample * total
    directory = Path(out).expanduser().absolute().parent
    free = shutil.disk_usage(directory).free
    if need > free:
        count = str(total) if total < 10**15 else f"{float(total):.3g}"
        what = "--duration" if duration is not None else "the session"
        raise BadInput(
            f"{what}: {total / rate:g} s at {rate:g} Hz is {count} samples, about "
            f"{_size(need)} as {lookup(out).name} ({bytes_per_sample:g} B per sample), "
            f"more than the {_size(free)} free on the filesystem of {directory}"
        )


def shorter(scenario: str, length_s: float, duration_s: float) -> str:
    """What to say when the finite ``scenario`` (``length_s`` s) ends before ``--duration``
    ``duration_s`` s: the session written is the scenario's length, and how to get longer."""
    longer = (
        "--param length=S makes a longer drive"
        if scenario in DRIVES
        else "--param loop=1 repeats it"
        if scenario == "multiposition"
        else "its --param values make it longer"
    )
    return (
        f"--duration {duration_s:g} s: the {scenario} scenario ends at {length_s:g} s, so "
        f"{length_s:g} s are written, not {duration_s:g} s ({longer})"
    )


def _size(n: float) -> str:
    """``n`` bytes as text with a decimal unit (B to EB)."""
    for unit in ("B", "kB", "MB", "GB", "TB", "PB", "EB"):
        if n < 1000 or unit == "EB":
            return f"{n:.3g} {unit}"
        n /= 1000
    raise AssertionError("unreachable")


def _checked_out(args: argparse.Namespace, fleet: bool) -> None:
    """``--out``: a file to write (a folder for the fleet); BadInput otherwise."""
    check = writable_directory if fleet else writable_output_path()
    try:
        check(args.out)
    except argparse.ArgumentTypeError as exc:
        raise BadInput(f"--out: {exc}") from None


def run_fleet(args: argparse.Namespace) -> int:
    """``imudiag simulate fleet``: the simulated fleet and its truth.json."""
    from ..fleet.simulate import FLIGHT_SECONDS, simulate_fleet

    if not args.vehicles or not args.flights:
        raise BadInput("fleet: --vehicles N and --flights M are required")
    seconds = FLIGHT_SECONDS
    if args.flight_seconds:
        try:
            lo, _, hi = args.flight_seconds.partition(":")
            seconds = (float(lo), float(hi or lo))
        except ValueError:
            raise BadInput(f"--flight-seconds {args.flight_seconds!r}: expected MIN:MAX") from None
        if not (0 < seconds[0] <= seconds[1] < math.inf):
            raise BadInput(f"--flight-seconds {args.flight_seconds!r}: need 0 < MIN <= MAX")
    cert = load(args.certificate) if args.certificate else load_default()
    rate = float(args.rate) if args.rate is not None else 100.0
    with for_command("simulate", args.quiet) as bar:
        truth = simulate_fleet(
            args.out,
            args.vehicles,
            args.flights,
            seed=args.seed,
            drifting=args.drifting,
            corrupt=args.corrupt,
            seconds=seconds,
            rate_hz=rate,
            certificate=cert,
            progress=bar,
        )
    drifting = [v for v in truth["vehicles"] if v["drifting"]]
    print(
        f"{args.out}: {args.vehicles} vehicles x {args.flights} flights, "
        f"{len(drifting)} drifting, {len(truth['corrupt'])} corrupt files; truth.json"
    )
    return 0


def run(args: argparse.Namespace) -> int:
    """Simulate and write the log; returns the exit code."""
    fleet = args.scenario == "fleet"
    _checked_out(args, fleet)
    if fleet:
        return run_fleet(args)
    for opt in ("vehicles", "flights", "drifting", "flight_seconds"):
        if getattr(args, opt) is not None:
            raise BadInput(f"--{opt.replace('_', '-')}: only for the fleet scenario")
    out_format = lookup(args.out)  # an unknown format fails before any work
    cert = load(args.certificate) if args.certificate else load_default()
    try:
        scenario = canonical_scenario(args.scenario)
    except ValueError as exc:
        raise BadInput(f"SCENARIO: {exc}") from None
    params = {}
    for item in args.param:
        key, sep, value = item.partition("=")
        if not sep:
            raise BadInput(f"--param {item!r}: expected KEY=VALUE")
        params[key.strip()] = value.strip()
    try:
        motion = scenario_motion(scenario, args.seed, params)
    except ValueError as exc:
        raise BadInput(f"--param: {exc}") from None
    effects = _parsed("--effect", parse_effects, args.effect)
    faults = _parsed("--fault", parse_faults, args.fault)
    rate = float(args.rate) if args.rate is not None else float(cert.sample_rate)
    problem = rate_problem(rate)
    if problem:
        where = "--rate" if args.rate is not None else f"{cert.source}: sample_rate"
        raise BadInput(f"{where}: {problem}")
    total = motion.n_samples(rate)
    if args.duration is not None:  # finite and > 0: checked when parsed
        want = int(round(args.duration * rate))
        if total is not None and total < want:
            print(
                f"imudiag simulate: warning: {shorter(scenario, total / rate, args.duration)}",
                file=sys.stderr,
            )
        total = want if total is None else min(total, want)
    elif total is None:
        raise BadInput(f"--duration: required for the endless scenario {scenario!r}")
    check_faults_in_session(faults, total, rate)
    check_free_space(args.out, out_format.bytes_per_sample, total, rate, args.duration)

    drive = scenario in DRIVES
    if args.gnss and not drive:
        raise BadInput(f"--gnss: only the drive scenarios ({', '.join(DRIVES)}) have GNSS")
    device = str(cert.device.get("model", "simulated IMU"))
    meta = _meta(args, rate, device, scenario, effects, faults)
    sim = Simulator(cert, effects, faults, args.seed, meta=dict(meta))
    chunk = max(1, min(MAX_CHUNK, int(round(CHUNK_S * rate))))
    written = 0
    with open_writer(args.out, meta=meta) as writer, for_command("simulate", args.quiet) as bar:
        done = 0
        while done < total:
            n = min(chunk, total - done)
            block = sim.step(motion.sample(rate, done, n))
            if drive:
                block.t = block.t + EPOCH_UNIX
            writer.write(block)
            done += n
            bar("simulating", done / total, done)
        written = writer.samples_written
    if args.gnss:
        write_gpspipe_log(args.gnss, gnss_reports(motion, seed=args.seed))  # type: ignore[arg-type]
    if args.true_certificate:
        t_end = (total - 1) / rate if total else 0.0
        true_certificate(cert, effects, faults, t_end, rate).save(args.true_certificate)
    print(
        f"{args.out}: {written} samples, {total / rate:g} s at {rate:g} Hz, "
        f"scenario {scenario}, seed {args.seed}"
    )
    return 0

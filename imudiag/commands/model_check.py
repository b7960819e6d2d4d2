"""``imudiag model-check LOG --certificate CERT --json OUT``: what the certificate's model
gets wrong on a recorded session, the named cause, the extended model and its gain
(spec/reports.md)."""

from __future__ import annotations

import argparse
import sys
from typing import Any

from ..argtypes import positive_float, positive_int, seed, writable_directory, writable_output_path
from ..certificate import load
from ..errors import BadInput
from ..logs.options import LogOptions, add_log_options, log_options
from ..progress import Progress, for_command

MIN_CHUNK_S = 0.05  #: --chunk must be longer, s
MIN_BLOCK_SIZE = 64  #: fewest samples per block read


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``model-check`` subcommand."""
    p = subparsers.add_parser(
        "model-check",
        help="compare a recorded session with a simulation of the certificate's model, "
        "name what it misses, extend the model and measure the gain",
        description=(
            "Simulate the recorded session with the certificate's model (the quasi-static "
            "parts: measured gravity direction, zero rate), compare with the measurement, "
            "test every effect of the catalogue (bias_drift, temperature_bias, "
            "temperature_scale, g_sensitivity, scale_nonlinearity, bias_step, "
            "periodic_disturbance), report the significant ones that also improve the fit "
            "of held-out data, and the gain of the extended model."
        ),
    )
    p.add_argument("log", metavar="LOG", help="sample log (.csv, .csv.gz, .npz, .bin)")
    add_log_options(p)
    p.add_argument(
        "--certificate", required=True, metavar="CERT", help="calibration certificate (YAML)"
    )
    p.add_argument(
        "--json",
        default="-",
        type=writable_output_path(stdout=True),
        metavar="OUT",
        help="report file, '-' for standard output (default)",
    )
    p.add_argument(
        "--extended-certificate",
        type=writable_output_path(),
        metavar="FILE",
        help="write the certificate with the fitted extended-model blocks",
    )
    p.add_argument(
        "--plots",
        type=writable_directory,
        metavar="DIR",
        help="write PNG figures into DIR (needs matplotlib: pip install 'imudiag[plots]')",
    )
    p.add_argument(
        "--quiet",
        "-q",
        action="store_true",
        help="no progress bar on standard error (drawn only on a terminal anyway)",
    )
    p.add_argument("--seed", type=seed, default=0, help="seed of the simulations (default 0)")
    p.add_argument(
        "--chunk",
        type=positive_float("s", above=MIN_CHUNK_S),
        default=None,
        metavar="S",
        help="length of the quasi-static chunks, s (default 1)",
    )
    p.add_argument(
        "--z-min",
        type=positive_float("std"),
        default=None,
        metavar="Z",
        help="significance an effect needs (default 5)",
    )
    p.add_argument(
        "--block-size",
        type=positive_int("samples per block", minimum=MIN_BLOCK_SIZE),
        default=None,
        metavar="N",
        help="samples per block read from the log (default 8192)",
    )
    p.set_defaults(
        func=run, _parser=p, inputs=("log", "certificate"), outputs=("json", "extended_certificate")
    )


def run(args: argparse.Namespace) -> int:
    """Run the model check; returns the exit code."""
    from ..modelcheck import ModelCheckConfig, model_check
    from ..modelcheck import report as report_mod

    cfg = ModelCheckConfig()
    if args.chunk is not None:  # the option values are checked when parsed
        cfg.chunk_s = args.chunk
        cfg.min_chunk_s = min(cfg.min_chunk_s, args.chunk / 2)
    if args.z_min is not None:
        cfg.z_min = args.z_min
    if args.plots:
        from ..plots import check_directory, require

        require()
        check_directory(args.plots)
    cert = load(args.certificate)
    try:
        kw = {"block_size": args.block_size} if args.block_size else {}
        options = log_options(args)
        log: Any = args.log
        with for_command("model-check", args.quiet) as progress:
            if options.given():  # a text table read with the user's names
                log = _table_source(args.log, options, args.block_size, progress)
            result = model_check(log, cert, seed=args.seed, config=cfg, progress=progress, **kw)
    except ValueError as exc:
        if type(exc).__name__ in ("LogError", "CertificateError"):
            raise
        raise BadInput(f"{args.log}: {exc}") from None
    if args.plots:
        from ..modelcheck.plots import write_plots

        result.report["plots"] = [str(p) for p in write_plots(result, args.plots)]
    report_mod.write(result.report, args.json)
    if args.extended_certificate:
        result.extended.save(args.extended_certificate)
    out = sys.stdout if args.json != "-" else sys.stderr
    for line in report_mod.summary(result.report):
        print(line, file=out)
    for path in result.report.get("plots", []):
        print(f"plot: {path}", file=out)
    return 0


def _table_source(
    path: str, options: LogOptions, block_size: int | None, progress: Progress
) -> Any:
    """A block source reading ``path`` with the user's log options (each pass told to
    ``progress``)."""
    from ..logs import DEFAULT_BLOCK_SIZE, open_log

    passes = [0]

    def blocks() -> Any:
        passes[0] += 1
        with open_log(path, block_size=block_size or DEFAULT_BLOCK_SIZE, options=options) as r:
            for block in r:
                yield block
                progress(f"pass {passes[0]}", r.fraction_read(), r.samples_read)

    return blocks

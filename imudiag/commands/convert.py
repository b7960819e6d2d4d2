"""``imudiag convert IN OUT``: copy a sample log into another format, streaming.

Formats by file name: ``.csv``, ``.csv.gz``, ``.npz``, ``.bin`` (spec/sample-log.md).
The output appears only when the whole input has been read and checked: a bad
input (exit 2, ``file:line: reason``) leaves no output file behind; an output that
is the input is refused (``imudiag.cli`` checks each command's declared files).
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from ..argtypes import positive_int, writable_output_path
from ..errors import BadInput
from ..logs import DEFAULT_BLOCK_SIZE, log_format, open_log, open_writer
from ..logs.options import add_log_options, log_options, units_from_meta
from ..progress import for_command
from ..samples import SampleBlock


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``convert`` subcommand."""
    p = subparsers.add_parser(
        "convert",
        help="convert a sample log between .csv, .csv.gz, .npz and .bin",
        description=(
            "Convert a sample log between formats, chosen by file name "
            "(.csv, .csv.gz, .npz, .bin). Streams in blocks, so logs larger than memory "
            "convert. Writing .bin rounds outputs to integer counts, t to microseconds and "
            "temp to 0.01 degC, as the wire protocol carries them."
        ),
    )
    p.add_argument("input", metavar="IN", help="log to read")
    p.add_argument(
        "output",
        type=writable_output_path(),
        metavar="OUT",
        help="log to write (replaced if it exists)",
    )
    p.add_argument(
        "--block-size",
        type=positive_int("samples per block"),
        default=DEFAULT_BLOCK_SIZE,
        metavar="N",
        help=f"samples per block (default {DEFAULT_BLOCK_SIZE})",
    )
    p.add_argument(
        "--no-meta",
        action="store_true",
        help="do not copy the metadata (e.g. when it does not fit a .bin device-info frame)",
    )
    p.add_argument(
        "--quantum",
        metavar="SPEC",
        help="writing .bin from a log not in counts: the quantisation, in the log's units per "
        "count, e.g. gyro=0.001,accel=0.0001 (outputs become round(value / quantum) counts)",
    )
    p.add_argument(
        "--quiet",
        "-q",
        action="store_true",
        help="no progress bar on standard error (drawn only on a terminal anyway)",
    )
    add_log_options(p)
    p.set_defaults(func=run, inputs=("input",), outputs=("output",))


def run(args: argparse.Namespace) -> int:
    """Convert ``args.input`` to ``args.output``; returns the exit code."""
    log_format(args.output)  # reject an unknown output format before reading anything
    quantum = _parse_quantum(args.quantum) if args.quantum else None
    to_bin = log_format(args.output) == ".bin"
    if quantum is not None and not to_bin:
        raise BadInput("--quantum: only writing a .bin capture (integer counts) needs it")
    with (
        open_log(args.input, block_size=args.block_size, options=log_options(args)) as reader,
        for_command("convert", args.quiet) as bar,
    ):
        meta = {} if args.no_meta else dict(reader.meta)
        units = units_from_meta(reader.meta)
        if quantum is not None and not args.no_meta:
            meta["units"] = "gyro=count accel=count"
            meta["quantum"] = ",".join(f"{k}={v:g}" for k, v in quantum.items())
        with open_writer(args.output, meta=meta) as writer:
            if to_bin and quantum is None:
                physical = {k: u for k, u in units.items() if u != "count"}
                if physical:
                    stated = ", ".join(f"{k} in {u}" for k, u in physical.items())
                    raise BadInput(
                        f"{args.input}: the log is not in counts ({stated}); a .bin capture holds "
                        "integer counts: give --quantum gyro=Q,accel=Q (the log's units per count) "
                        "or write .csv / .npz"
                    )
            for block in reader:
                bar("converting", reader.fraction_read(), reader.samples_read)
                if quantum is not None:
                    block.gyro = block.gyro / quantum["gyro"]
                    block.accel = block.accel / quantum["accel"]
                elif to_bin:
                    _check_counts(args.input, block, writer.samples_written)
                writer.write(block)
        n = writer.samples_written
    print(f"{args.input} -> {args.output}: {n} samples")
    return 0


def _parse_quantum(text: str) -> dict[str, float]:
    """``gyro=Q,accel=Q`` (log units per count, > 0) -> {"gyro": Q, "accel": Q}."""
    out: dict[str, float] = {}
    for part in text.split(","):
        key, _, value = part.partition("=")
        key = key.strip()
        if key not in ("gyro", "accel"):
            raise BadInput(f"--quantum: expected gyro=Q,accel=Q, got {part!r}")
        try:
            q = float(value)
        except ValueError:
            raise BadInput(f"--quantum: {key}: not a number: {value!r}") from None
        if not (q > 0 and math.isfinite(q)):
            raise BadInput(f"--quantum: {key}: must be a finite value > 0, got {value!r}")
        out[key] = q
    if set(out) != {"gyro", "accel"}:
        raise BadInput("--quantum: give both, e.g. gyro=0.001,accel=0.0001")
    return out


def _check_counts(path: str, block: SampleBlock, done: int) -> None:
    """Refuse outputs that are not whole counts (a .bin would round them away)."""
    for name, values in (("gyro", block.gyro), ("accel", block.accel)):
        bad = np.flatnonzero(np.any(values != np.rint(values), axis=1))
        if bad.size:
            i = int(bad[0])
            raise BadInput(
                f"{path}: sample {done + i} (t = {float(block.t[i])!r} s): {name} output "
                f"{values[i].tolist()} is not in integer counts; a .bin capture holds counts: "
                "give --quantum gyro=Q,accel=Q (the log's units per count) or write .csv / .npz"
            )

"""``imudiag convert IN OUT``: copy a sample log into another format, streaming.

Formats by file name: ``.csv``, ``.csv.gz``, ``.npz``, ``.bin`` (spec/sample-log.md).
The output appears only when the whole input has been read and checked: a bad
input (exit 2, ``file:line: reason``) leaves no output file behind.
"""

from __future__ import annotations

import argparse
import os

from ..errors import BadInput
from ..logs import DEFAULT_BLOCK_SIZE, log_format, open_log, open_writer


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
    p.add_argument("output", metavar="OUT", help="log to write (replaced if it exists)")
    p.add_argument(
        "--block-size", type=int, default=DEFAULT_BLOCK_SIZE, metavar="N",
        help=f"samples per block (default {DEFAULT_BLOCK_SIZE})",
    )
    p.add_argument(
        "--no-meta", action="store_true",
        help="do not copy the metadata (e.g. when it does not fit a .bin device-info frame)",
    )
    p.set_defaults(func=run, inputs=("input",), outputs=("output",))


def run(args: argparse.Namespace) -> int:
    """Convert ``args.input`` to ``args.output``; returns the exit code."""
    if args.block_size < 1:
        raise BadInput(f"--block-size: must be >= 1, got {args.block_size}")
    log_format(args.output)  # reject an unknown output format before reading anything
    both = os.path.exists(args.input) and os.path.exists(args.output)
    if both and os.path.samefile(args.input, args.output):
        raise BadInput(f"{args.output}: output is the input file")
    with open_log(args.input, block_size=args.block_size) as reader:
        meta = {} if args.no_meta else reader.meta
        with open_writer(args.output, meta=meta) as writer:
            for block in reader:
                writer.write(block)
        n = writer.samples_written
    print(f"{args.input} -> {args.output}: {n} samples")
    return 0

"""``imudiag certificate import|export``: calibrations of other tools to and from certificates.

``import FILE --format imu_tk|imucal|kalibr|ikalibr [--like CERT] --out CERT`` maps the
tool's model onto the certificate's exactly (docs/interop.md); what the file does not carry
(limits, noise, temperature, units, ...) comes from ``--like`` (default: the bundled
certificate), and the command prints which field came from where. ``export CERT --format
... --out FILE`` is the inverse and prints what the format cannot hold. imu_tk's two files
are named by a prefix: ``PREFIX_acc.calib`` and ``PREFIX_gyro.calib`` (or ``--accel`` and
``--gyro`` on import).
"""

from __future__ import annotations

import argparse

from ..argtypes import writable_output_path
from ..atomic import refuse_overwrite
from ..certificate import default_certificate_path, load, loads
from ..errors import BadInput
from ..interop import DEFAULT_GAUGE, FORMATS, GAUGES, output_paths, read, to_certificate, write
from ..interop import imu_tk as imu_tk_files
from ..logs.options import parse_units


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``certificate`` subcommand with ``import`` and ``export``."""
    p = sub.add_parser(
        "certificate",
        help="import or export a calibration of imu_tk, imucal, Kalibr or iKalibr",
        description="Convert calibrations between imudiag certificates and the files of "
        "imu_tk, imucal, Kalibr and iKalibr (docs/interop.md).",
    )
    actions = p.add_subparsers(dest="action", metavar="ACTION", required=True)
    imp = actions.add_parser(
        "import",
        help="a tool's calibration file to a certificate",
        description="Read a tool's calibration and write a certificate; fields the file does "
        "not carry come from --like, and the command says which field came from where.",
    )
    imp.add_argument(
        "input",
        metavar="FILE",
        nargs="?",
        help="the tool's file (imu_tk: PREFIX naming PREFIX_acc.calib and PREFIX_gyro.calib, "
        "or either of the two files)",
    )
    imp.add_argument("--format", required=True, choices=FORMATS, help="the tool's format")
    imp.add_argument("--accel", metavar="FILE", help="imu_tk: the accelerometer .calib file")
    imp.add_argument("--gyro", metavar="FILE", help="imu_tk: the gyroscope .calib file")
    imp.add_argument(
        "--like",
        metavar="CERT",
        help="certificate giving what the file lacks: units, limits, noise, temperature "
        "(default: the bundled certificate)",
    )
    imp.add_argument(
        "--units",
        metavar="SPEC",
        help="imu_tk: the units of the data imu_tk calibrated, which its files are in and do "
        "not state: gyro=rad/s|deg/s|count,accel=m/s^2|g|count (needed without --like)",
    )
    imp.add_argument(
        "--gauge",
        choices=GAUGES,
        default=DEFAULT_GAUGE,
        help="symmetric: re-frame so the accelerometer N is symmetric, as imudiag calibrate "
        "writes it (the rotation is printed); tool: keep the tool's frame "
        f"(default {DEFAULT_GAUGE})",
    )
    imp.add_argument(
        "--out",
        required=True,
        type=writable_output_path(),
        metavar="CERT",
        help="certificate to write",
    )
    imp.set_defaults(
        func=run_import,
        command_name="certificate import",
        inputs=("input", "accel", "gyro", "like"),
        outputs=("out",),
    )
    exp = actions.add_parser(
        "export",
        help="a certificate to a tool's calibration file",
        description="Write a certificate in a tool's format; the command says what the "
        "format cannot hold.",
    )
    exp.add_argument("input", metavar="CERT", help="certificate to export")
    exp.add_argument("--format", required=True, choices=FORMATS, help="the tool's format")
    exp.add_argument(
        "--out",
        required=True,
        type=writable_output_path(),
        metavar="FILE",
        help="file to write (imu_tk: PREFIX, writing PREFIX_acc.calib and PREFIX_gyro.calib)",
    )
    exp.set_defaults(
        func=run_export, command_name="certificate export", inputs=("input",), outputs=("out",)
    )


def _import_sources(args: argparse.Namespace) -> list[tuple[str, str]]:
    if args.format == "imu_tk":
        if not args.input and not (args.accel and args.gyro):
            raise BadInput("imu_tk: give FILE (the PREFIX) or both --accel and --gyro")
        names = imu_tk_files.paths(args.input) if args.input else {}
        return [("--accel", args.accel or names["accel"]), ("--gyro", args.gyro or names["gyro"])]
    if args.accel or args.gyro:
        raise BadInput(f"--accel/--gyro: only the imu_tk format has two files, not {args.format}")
    if args.units:
        raise BadInput(
            f"--units: only imu_tk's files leave their units unstated, not {args.format}"
        )
    if not args.input:
        raise BadInput(f"{args.format}: FILE is required")
    return [("FILE", args.input)]


def _imu_tk_units(args: argparse.Namespace, like_path: str) -> dict[str, str]:
    """The output units of an imu_tk calibration: its files are in the units of the data
    imu_tk was given (raw counts, or SI), which they do not state. ``--units`` states them;
    without it they are --like's output units (and a note says so); with neither, BadInput
    (the bundled certificate's counts would label SI data as counts)."""
    units = parse_units(args.units) if args.units else {}
    missing = [t for t in ("gyro", "accel") if t not in units]
    if missing and not args.like:
        raise BadInput(
            f"imu_tk: its .calib files are in the units of the data imu_tk calibrated, which "
            f"they do not state ({' and '.join(missing)}): give --units "
            "gyro=UNIT,accel=UNIT (gyro=rad/s,accel=m/s^2 for SI data, count for raw counts) "
            "or --like CERT whose output units are the data's"
        )
    return units


def run_import(args: argparse.Namespace) -> int:
    """Import a tool's calibration into a certificate."""
    if args.units:
        parse_units(args.units)  # a bad value is refused before any file is read
    sources = _import_sources(args)
    refuse_overwrite(sources, [("--out", args.out)])
    like_path = args.like or str(default_certificate_path())
    like = load(like_path)
    ic = read(args.format, args.input or "", accel=args.accel, gyro=args.gyro)
    stated = _imu_tk_units(args, like_path) if args.format == "imu_tk" else {}
    for name, unit in stated.items():
        ic.triad(name).output_unit = unit
    cert, prov = to_certificate(ic, like, gauge=args.gauge)
    for name in stated:
        prov.fields[f"{name}.output_unit"] = "--units"
    if args.format == "imu_tk":
        said = ", ".join(
            f"{n} in {cert.triad(n).output_unit} ({'--units' if n in stated else '--like'})"
            for n in ("gyro", "accel")
        )
        prov.notes.append(
            f"imu_tk: its files are in the units of the data it calibrated: outputs {said}"
        )
    note = f"imported from {args.format} ({', '.join(p for _, p in sources)})"
    cert.device = {**cert.device, "calibrated": note}
    prov.fields["device.calibrated"] = "import"
    loads(cert.dumps(), source=args.out)  # the rules of a certificate, checked before writing
    cert.save(args.out)
    print(f"imudiag certificate import: wrote {args.out} ({args.format}, gauge {args.gauge})")
    files = " + ".join(p for _, p in sources)
    for line in prov.lines(files, like_path):
        print(f"  {line}")
    return 0


def run_export(args: argparse.Namespace) -> int:
    """Export a certificate in a tool's format."""
    outs = output_paths(args.format, args.out)
    refuse_overwrite([("CERT", args.input)], [("--out", p) for p in outs])
    cert = load(args.input)
    written, notes = write(args.format, cert, args.out)
    print(f"imudiag certificate export: wrote {', '.join(written)} ({args.format})")
    for n in notes:
        print(f"  note: {n}")
    return 0

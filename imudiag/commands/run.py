"""``imudiag run``: the monitor daemon (spec/reports.md).

With no arguments: the simulated board (``sim://``), the bundled certificate,
JSON status lines on standard output. A configuration file (``--config``)
sets everything; command-line options override it.
"""

from __future__ import annotations

import argparse
import logging
import sys
from typing import Any

from ..aiding.gpsd_client import DEFAULT_URL as DEFAULT_AIDING_URL
from ..argtypes import positive_float
from ..errors import BadInput
from ..service.config import DaemonConfig

#: the defaults --help names: the one definition (config/imudiag.yaml equals it)
_DEFAULTS = DaemonConfig()


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``run`` subcommand."""
    p = sub.add_parser(
        "run",
        help="run the monitor daemon",
        description="Run the monitor daemon: read the IMU, check every sample, diagnose "
        "the sensors against the certificate, write status.",
    )
    p.add_argument("--config", help="daemon configuration YAML (default: the bundled one)")
    p.add_argument(
        "--source",
        help="input URL: serial:///dev/ttyACM0?baud=921600, hid://VID:PID, usb://VID:PID, "
        f"replay://PATH?speed=1, sim://SCENARIO?seed=N (default {_DEFAULTS.source})",
    )
    p.add_argument(
        "--certificate",
        help="certificate YAML (default: the bundled one), or 'auto': the bundled data-sheet "
        "certificate the device names (docs/devices.md)",
    )
    p.add_argument(
        "--status",
        action="append",
        help="status sink: '-' for JSON lines on stdout, or a serial URL for NMEA sentences "
        "(repeatable; default '-')",
    )
    p.add_argument(
        "--status-rate",
        type=positive_float("Hz"),
        help=f"steady status rate, Hz (default {_DEFAULTS.status_rate_hz:g})",
    )
    p.add_argument(
        "--nmea-rate",
        type=positive_float("Hz"),
        help=f"steady NMEA status rate, Hz (default {_DEFAULTS.nmea_rate_hz:g})",
    )
    p.add_argument(
        "--no-data-timeout",
        type=positive_float("s"),
        help=f"seconds without frames -> no_data (default {_DEFAULTS.no_data_timeout_s:g})",
    )
    p.add_argument("--no-diagnosis", action="store_true", help="per-sample checks only")
    p.add_argument("--log-level", help="debug, info, warning, error, critical")
    p.add_argument(
        "--aiding",
        nargs="?",
        const=DEFAULT_AIDING_URL,
        metavar="URL",
        help=f"GNSS aiding from gpsd (default {DEFAULT_AIDING_URL}): the moving-base "
        "F0 and accelerometer check in motion (docs/moving-base.md)",
    )
    p.set_defaults(func=run)


def _overrides(args: argparse.Namespace) -> dict[str, Any]:
    """Command-line options as DaemonConfig field names (None: not given)."""
    return {
        "source": args.source,
        "certificate": args.certificate,
        "status": args.status,
        "status_rate_hz": args.status_rate,
        "nmea_rate_hz": args.nmea_rate,
        "no_data_timeout_s": args.no_data_timeout,
        "log_level": args.log_level,
        "aiding": args.aiding,
    }


def run(args: argparse.Namespace) -> int:
    """Build the daemon from configuration and options and run it until stopped."""
    from ..certificate import CertificateError
    from ..drivers.base import SourceError
    from ..service.config import default_config, load_config, merge_cli
    from ..service.daemon import Daemon, settings_from_config
    from ..service.logging_setup import setup_logging
    from ..service.sinks import make_sinks

    config = load_config(args.config) if args.config else default_config()
    config = merge_cli(config, _overrides(args))
    setup_logging(config.log_level)
    settings = settings_from_config(config)
    if args.no_diagnosis:
        settings.diagnosis = False
    try:
        sinks = make_sinks(config)
        daemon = Daemon(settings, sinks)
    except SourceError as exc:
        raise BadInput(str(exc)) from None
    except CertificateError:
        raise
    daemon.install_signal_handlers()
    logging.getLogger("imudiag.daemon").info(
        "monitoring %s with certificate %s",
        settings.source_url,
        daemon.certificate_file,
    )
    try:
        return daemon.run()
    except BrokenPipeError:
        sys.stderr.close()
        return 0

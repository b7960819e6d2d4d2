"""Daemon configuration: bundled defaults, site files, command-line overrides, every rule."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import yaml

from imudiag.errors import BadInput
from imudiag.service.config import (
    SCHEMA,
    ConfigError,
    DaemonConfig,
    bundled_config_path,
    default_config,
    load_config,
    merge_cli,
)

PROJECT_DIR = Path(__file__).parent.parent


def write(tmp_path: Path, text: str, name: str = "imudiag.yaml") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def test_bundled_file_is_the_single_source_of_defaults() -> None:
    path = bundled_config_path()
    assert path.is_file() and path.resolve() == (PROJECT_DIR / "config" / "imudiag.yaml").resolve()
    config = default_config()
    assert config == DaemonConfig()  # dataclass defaults and the file agree
    assert config.origin == str(path)
    assert config.source.startswith("sim://") and config.certificate is None
    assert config.status_stdout and config.status_serial is None


def test_bundled_file_sets_and_documents_every_key() -> None:
    text = bundled_config_path().read_text(encoding="utf-8")
    doc = yaml.safe_load(text)
    for path in SCHEMA:
        node = doc
        for part in path:
            assert part in node, f"{'.'.join(path)} missing from the bundled file"
            node = node[part]
    lines = text.splitlines()
    for path in SCHEMA:
        leaf = path[-1]
        line = next(x for x in lines if re.match(rf"\s*{leaf}:", x))
        assert "#" in line or leaf in ("source", "certificate", "log_level"), line
    # the top-level keys carry their comment above or on the line
    for key in ("source", "certificate", "log_level"):
        i = next(i for i, x in enumerate(lines) if x.startswith(f"{key}:"))
        assert "#" in lines[i] or lines[i - 1].startswith("#"), key


def test_docs_describe_every_key() -> None:
    text = (PROJECT_DIR / "docs" / "service.md").read_text(encoding="utf-8")
    for path in SCHEMA:
        assert f"`{'.'.join(path)}`" in text, f"docs/service.md does not describe {path}"


def test_site_file_overrides_only_what_it_lists(tmp_path: Path) -> None:
    path = write(
        tmp_path,
        "source: serial:///dev/imu0?baud=921600\n"
        "status:\n  serial: /dev/ttyS1\n  nmea_rate_hz: 2\n"
        "monitor: {f0_persistence_k: 4, f0_persistence_n: 10}\n"
        "log_level: WARNING\n",
    )
    config = load_config(path)
    assert config.source == "serial:///dev/imu0?baud=921600"
    assert config.status_serial == "/dev/ttyS1"
    assert config.nmea_rate_hz == 2.0 and isinstance(config.nmea_rate_hz, float)
    assert (config.f0_persistence_k, config.f0_persistence_n) == (4, 10)
    assert config.log_level == "warning"
    assert config.status_rate_hz == DaemonConfig().status_rate_hz
    assert config.origin == str(path)


def test_empty_file_and_empty_section_mean_defaults(tmp_path: Path) -> None:
    assert load_config(write(tmp_path, "")) == DaemonConfig()
    assert load_config(write(tmp_path, "status:\n", "b.yaml")) == DaemonConfig()


def test_relative_certificate_is_relative_to_the_file(tmp_path: Path) -> None:
    (tmp_path / "certs").mkdir()
    cert = tmp_path / "certs" / "board.yaml"
    cert.write_text("format: imudiag-certificate/1\n")
    config = load_config(write(tmp_path, "certificate: certs/board.yaml\n"))
    assert Path(config.certificate) == cert


BAD_CONFIGS = [
    # (yaml text, key path named, reason fragment)
    ("sourse: sim://\n", "sourse", "unknown key"),
    ("status:\n  rate: 2\n", "status.rate", "unknown key; known: "),
    ("status: [1, 2]\n", "status", "expected a mapping"),
    ("monitor: 3\n", "monitor", "expected a mapping"),
    ("- 1\n- 2\n", "(document)", "expected a mapping of keys"),
    ("status: {rate_hz: fast}\n", "status.rate_hz", "expected a number, got 'fast'"),
    ("status: {rate_hz: true}\n", "status.rate_hz", "expected a number"),
    ("status: {rate_hz: 0}\n", "status.rate_hz", "out of range (0, 100]"),
    ("status: {rate_hz: -1}\n", "status.rate_hz", "out of range"),
    ("status: {rate_hz: .nan}\n", "status.rate_hz", "finite"),
    ("status: {nmea_rate_hz: 1000}\n", "status.nmea_rate_hz", "out of range (0, 20]"),
    ("status: {stdout: 1}\n", "status.stdout", "expected true or false"),
    ("status: {serial: ''}\n", "status.serial", "non-empty string"),
    ("status: {serial: 5}\n", "status.serial", "non-empty string"),
    ("status: {nmea_queue: 0}\n", "status.nmea_queue", "out of range [1, 100000]"),
    ("monitor: {f0_persistence_k: 2.5}\n", "monitor.f0_persistence_k", "expected an integer"),
    ("monitor: {f0_persistence_k: 60}\n", "monitor.f0_persistence_k", "exceeds f0_persistence_n"),
    ("monitor: {stuck_samples: 1}\n", "monitor.stuck_samples", "out of range [2,"),
    ("monitor: {no_data_timeout_s: 0}\n", "monitor.no_data_timeout_s", "out of range"),
    ("reconnect: {min_s: 2, max_s: 1}\n", "reconnect.max_s", "below reconnect min_s"),
    ("diagnosis: {window_intervals: 8}\n", "diagnosis.window_intervals", "out of range [9,"),
    ("diagnosis: {window_max_s: -3}\n", "diagnosis.window_max_s", "out of range"),
    ("log_level: loud\n", "log_level", "expected one of debug, info"),
    ("source: /dev/ttyACM0\n", "source", "not a source URL"),
    ("source: 'ftp://x'\n", "source", "unknown source scheme 'ftp'"),
    ("source: null\n", "source", "non-empty string"),
    ("certificate: missing.yaml\n", "certificate", "no such certificate file"),
    ("certificate: 12\n", "certificate", "non-empty string"),
    ("status:\n  rate_hz: 1\n  rate_hz: 2\n", "line 3", "duplicate key 'rate_hz'"),
    ("status: {rate_hz: 1\n", "line 2", "not valid YAML"),
]


@pytest.mark.parametrize(("text", "key", "reason"), BAD_CONFIGS)
def test_bad_configuration_names_file_key_and_reason(
    tmp_path: Path, text: str, key: str, reason: str
) -> None:
    path = write(tmp_path, text)
    with pytest.raises(ConfigError) as info:
        load_config(path)
    err = info.value
    assert isinstance(err, BadInput)  # the CLI turns it into exit status 2
    assert err.source == str(path)
    assert err.key == key
    assert reason in err.reason
    assert str(err).startswith(f"{path}: {key}: ")


def test_unreadable_file(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="cannot read"):
        load_config(tmp_path / "nope.yaml")
    path = tmp_path / "latin1.yaml"
    path.write_bytes(b"source: \xe9\n")
    with pytest.raises(ConfigError, match="not UTF-8"):
        load_config(path)


# ---------------------------------------------------------------------------
# command line


def test_cli_overrides_the_file(tmp_path: Path) -> None:
    base = load_config(write(tmp_path, "status: {rate_hz: 2}\nlog_level: debug\n"))
    merged = merge_cli(
        base,
        {
            "source": "replay:///data/run.csv?speed=0",
            "status_rate_hz": 5,
            "nmea_rate_hz": None,  # not given: the file's value stays
            "log_level": None,
            "func": print,  # argparse leftovers are ignored
            "command": "run",
            "config": "x.yaml",
        },
    )
    assert merged.source == "replay:///data/run.csv?speed=0"
    assert merged.status_rate_hz == 5.0
    assert merged.log_level == "debug" and merged.nmea_rate_hz == base.nmea_rate_hz
    assert base.status_rate_hz == 2.0  # frozen: the original is untouched


@pytest.mark.parametrize(
    ("status", "stdout", "serial"),
    [
        ("-", True, None),
        (["-"], True, None),
        ("/dev/ttyS1", False, "/dev/ttyS1"),
        (["-", "serial:///dev/ttyUSB0?baud=115200"], True, "serial:///dev/ttyUSB0?baud=115200"),
    ],
)
def test_cli_status_sinks(status, stdout: bool, serial: str | None) -> None:
    merged = merge_cli(DaemonConfig(status_serial="/dev/ttyS9"), {"status": status})
    assert (merged.status_stdout, merged.status_serial) == (stdout, serial)


@pytest.mark.parametrize(
    ("args", "option", "reason"),
    [
        ({"status_rate_hz": 0.0}, "--status-rate", "out of range"),
        ({"nmea_rate_hz": "x"}, "--nmea-rate", "expected a number"),
        ({"no_data_timeout_s": -1.0}, "--no-data-timeout", "out of range"),
        ({"log_level": "chatty"}, "--log-level", "expected one of"),
        ({"source": "nonsense"}, "--source", "not a source URL"),
        ({"certificate": "/no/such/cert.yaml"}, "--certificate", "no such certificate file"),
        ({"status": []}, "--status", "expected '-' or a serial URL"),
        ({"status": ["a", "b"]}, "--status", "only one serial status link"),
        ({"reconnect_max_s": 0.1}, "--reconnect-max-s", "below reconnect min_s"),
    ],
)
def test_cli_bad_values_name_the_option(args: dict, option: str, reason: str) -> None:
    with pytest.raises(ConfigError) as info:
        merge_cli(DaemonConfig(), args)
    assert info.value.source == "command line"
    assert info.value.key == option
    assert reason in info.value.reason


def test_cli_conflict_with_the_file_names_the_option(tmp_path: Path) -> None:
    base = load_config(write(tmp_path, "monitor: {f0_persistence_k: 5, f0_persistence_n: 8}\n"))
    with pytest.raises(ConfigError) as info:
        merge_cli(base, {"f0_persistence_n": 4})
    assert info.value.key == "--f0-persistence-n"
    assert "exceeds f0_persistence_n = 4" in info.value.reason
    custom = merge_cli(base, {"f0_persistence_n": 9}, option_names={})
    assert custom.f0_persistence_n == 9


def test_one_definition_of_the_daemon_defaults() -> None:
    """Issue 12 item 12: a daemon built in code (DaemonSettings()), the configuration's
    dataclass, the bundled file, the monitor's and the diagnosis's own defaults agree."""
    from imudiag.aiding.gpsd_client import DEFAULT_URL
    from imudiag.diagnosis.config import DiagnosisConfig
    from imudiag.monitor import MonitorConfig
    from imudiag.service.daemon import DaemonSettings, settings_from_config

    config = default_config()
    from_file = settings_from_config(config)
    in_code = DaemonSettings()
    for key in (
        "source_url",
        "certificate_path",
        "status_period_s",
        "no_data_timeout_s",
        "read_interval_s",
        "reconnect_min_s",
        "reconnect_max_s",
        "aiding_url",
    ):
        assert getattr(in_code, key) == getattr(from_file, key), key
    # the reconnect back-off stays below WatchdogSec / 2 (systemd/imudiag.service)
    unit = (PROJECT_DIR / "systemd" / "imudiag.service").read_text(encoding="utf-8")
    watchdog_s = float(re.search(r"^WatchdogSec=(\d+(?:\.\d+)?)s?$", unit, re.M).group(1))
    assert in_code.reconnect_max_s < watchdog_s / 2
    monitor = MonitorConfig()
    assert (monitor.persistence_k, monitor.persistence_n) == (
        config.f0_persistence_k,
        config.f0_persistence_n,
    )
    assert monitor.stuck_samples == config.stuck_samples
    assert monitor.static_window_s == config.static_window_s
    assert from_file.monitor == monitor
    diagnosis = DiagnosisConfig()
    assert diagnosis.window_intervals == config.diagnosis_window_intervals
    assert diagnosis.window_max_s == config.diagnosis_window_max_s
    assert diagnosis.persist == config.diagnosis_persist_windows
    assert DEFAULT_URL.startswith("gpsd://")


def test_run_help_shows_the_defaults_in_force() -> None:
    """`imudiag run --help` names the defaults of the one definition, never a stale one."""
    from imudiag.aiding.gpsd_client import DEFAULT_URL
    from imudiag.cli import build_parser

    parser = build_parser()
    run = next(a for a in parser._subparsers._group_actions[0].choices.items() if a[0] == "run")[1]
    text = " ".join(run.format_help().split())
    config = DaemonConfig()
    assert f"default {config.source}" in text
    assert f"default {config.status_rate_hz:g}" in text
    assert f"default {config.no_data_timeout_s:g}" in text
    assert f"default {DEFAULT_URL}" in text

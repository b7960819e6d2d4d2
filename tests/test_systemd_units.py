"""systemd units, udev rules and journald logging: the system-integration files.

``systemd-analyze verify`` and ``systemd-analyze security --offline`` check the
units where systemd-analyze is installed; ``udevadm verify`` the rules where
udevadm is (systemd >= 254); the rules are also parsed and checked here.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from imudiag.service.config import default_config

PROJECT_DIR = Path(__file__).parent.parent
SYSTEMD_DIR = PROJECT_DIR / "systemd"
UNITS = ("imudiag.service", "imudiag@.service")
INSTALLED_BINARY = "/usr/local/bin/imudiag"
SYSTEMD_ANALYZE = shutil.which("systemd-analyze")
UDEVADM = shutil.which("udevadm")
needs_analyze = pytest.mark.skipif(SYSTEMD_ANALYZE is None, reason="systemd-analyze not installed")


def parse_unit(path: Path) -> dict[str, list[tuple[str, str]]]:
    """Sections of a unit file as lists of (key, value), repeated keys kept in order."""
    sections: dict[str, list[tuple[str, str]]] = {}
    current = None
    for raw in path.read_text(encoding="utf-8").splitlines():
        line = raw.strip()
        if not line or line.startswith(("#", ";")):
            continue
        if line.startswith("[") and line.endswith("]"):
            current = sections.setdefault(line[1:-1], [])
            continue
        assert current is not None, f"{path}: {raw!r} outside a section"
        key, sep, value = line.partition("=")
        assert sep, f"{path}: not a key=value line: {raw!r}"
        current.append((key.strip(), value.strip()))
    return sections


def values(unit: dict[str, list[tuple[str, str]]], section: str, key: str) -> list[str]:
    return [v for k, v in unit.get(section, []) if k == key]


def one(unit: dict[str, list[tuple[str, str]]], section: str, key: str) -> str:
    found = values(unit, section, key)
    assert len(found) == 1, f"[{section}] {key}= expected once, found {found}"
    return found[0]


def seconds(value: str) -> float:
    """A systemd time span such as 10s, 2min 30s, 500ms, in seconds."""
    units = {"ms": 1e-3, "s": 1.0, "sec": 1.0, "min": 60.0, "m": 60.0, "h": 3600.0, "": 1.0}
    total = 0.0
    for number, unit in re.findall(r"(\d+(?:\.\d+)?)\s*([a-z]*)", value):
        total += float(number) * units[unit]
    return total


# ---------------------------------------------------------------------------
# the units' content


@pytest.mark.parametrize("name", UNITS)
def test_unit_has_the_required_directives(name: str) -> None:
    unit = parse_unit(SYSTEMD_DIR / name)
    svc = "Service"
    assert one(unit, svc, "Type") == "notify"
    assert one(unit, svc, "NotifyAccess") == "main"
    assert seconds(one(unit, svc, "WatchdogSec")) > 0
    assert one(unit, svc, "Restart") == "on-failure"
    assert seconds(one(unit, svc, "RestartSec")) > 0
    exec_start = one(unit, svc, "ExecStart")
    assert exec_start.startswith(INSTALLED_BINARY + " run ")
    assert "--config /etc/imudiag/imudiag.yaml" in exec_start
    assert re.fullmatch(r"/(usr/)?bin/kill -HUP \$MAINPID", one(unit, svc, "ExecReload"))
    # hardening
    assert one(unit, svc, "DynamicUser") == "yes"
    groups = one(unit, svc, "SupplementaryGroups").split()
    assert "dialout" in groups and "plugdev" in groups
    assert one(unit, svc, "ProtectSystem") == "strict"
    assert one(unit, svc, "ProtectHome") == "yes"
    assert one(unit, svc, "NoNewPrivileges") == "yes"
    assert one(unit, svc, "DevicePolicy") == "closed"
    allowed = [v.split()[0] for v in values(unit, svc, "DeviceAllow")]
    for node in ("char-ttyACM", "char-hidraw", "char-usb_device"):
        assert node in allowed, f"DeviceAllow= lacks {node}"
    assert all(v.split()[1] in ("r", "rw", "rwm") for v in values(unit, svc, "DeviceAllow"))
    # PrivateDevices= would hide the real IMU node while leaving ptys
    all_keys = {k for section in unit.values() for k, _ in section}
    assert "PrivateDevices" not in all_keys
    assert one(unit, "Install", "WantedBy") == "multi-user.target"


def test_fixed_unit_reads_the_udev_symlink() -> None:
    unit = parse_unit(SYSTEMD_DIR / "imudiag.service")
    assert "--source serial:///dev/imu0" in one(unit, "Service", "ExecStart")
    assert "/dev/imu0" in [v.split()[0] for v in values(unit, "Service", "DeviceAllow")]


def test_template_takes_the_device_from_the_instance() -> None:
    unit = parse_unit(SYSTEMD_DIR / "imudiag@.service")
    assert "--source serial:///dev/%I" in one(unit, "Service", "ExecStart")
    assert "/dev/%I" in [v.split()[0] for v in values(unit, "Service", "DeviceAllow")]
    assert one(unit, "Unit", "After") == "dev-%i.device"
    assert not values(unit, "Unit", "BindsTo")  # survives unplugging: the daemon reconnects
    assert one(unit, "Install", "DefaultInstance") == "imu0"


@pytest.mark.parametrize("name", UNITS)
def test_watchdog_outlasts_the_daemon_timeouts(name: str) -> None:
    """A reconnect back-off or the no_data timeout must not alone starve the watchdog."""
    unit = parse_unit(SYSTEMD_DIR / name)
    watchdog_s = seconds(one(unit, "Service", "WatchdogSec"))
    config = default_config()
    assert config.reconnect_max_s < watchdog_s / 2
    assert config.no_data_timeout_s < watchdog_s / 2


# ---------------------------------------------------------------------------
# systemd-analyze


def _installable_copy(tmp_path: Path) -> Path:
    """The units with ExecStart pointing at this environment's imudiag console script.

    ``systemd-analyze verify`` checks that the ExecStart binary exists; the
    units name the install location /usr/local/bin/imudiag, absent here.
    """
    script = Path(sys.executable).with_name("imudiag")
    if not script.exists():
        found = shutil.which("imudiag")
        if found is None:
            pytest.skip("the imudiag console script is not installed")
        script = Path(found)
    out = tmp_path / "units"
    out.mkdir()
    for name in UNITS:
        text = (SYSTEMD_DIR / name).read_text(encoding="utf-8")
        assert text.count(INSTALLED_BINARY) == 1
        (out / name).write_text(text.replace(INSTALLED_BINARY, str(script)), encoding="utf-8")
    return out


def _analyze(*args: str) -> subprocess.CompletedProcess[str]:
    assert SYSTEMD_ANALYZE is not None
    return subprocess.run(
        [SYSTEMD_ANALYZE, *args], capture_output=True, text=True, timeout=60, check=False
    )


@needs_analyze
@pytest.mark.parametrize("unit", ["imudiag.service", "imudiag@imu0.service"])
def test_systemd_analyze_verify_is_clean(tmp_path: Path, unit: str) -> None:
    units = _installable_copy(tmp_path)
    proc = _analyze("verify", "--man=no", str(units / unit))
    # verify exits 0 even after "Unknown key" warnings: require silence as well
    assert proc.returncode == 0 and proc.stderr == "" and proc.stdout == "", proc.stderr


@needs_analyze
@pytest.mark.skipif(os.path.exists(INSTALLED_BINARY), reason=f"{INSTALLED_BINARY} is installed")
def test_systemd_analyze_only_misses_the_uninstalled_binary() -> None:
    """The units as shipped: the one complaint is the binary not installed in this environment."""
    for name in ("imudiag.service", "imudiag@imu0.service"):
        path = SYSTEMD_DIR / name
        proc = _analyze("verify", "--man=no", str(path))
        complaints = [line for line in proc.stderr.splitlines() if line.strip()]
        assert complaints == [
            f"{name}: Command {INSTALLED_BINARY} is not executable: No such file or directory"
        ], proc.stderr


@needs_analyze
@pytest.mark.parametrize("name", UNITS)
def test_systemd_analyze_security_exposure_is_low(tmp_path: Path, name: str) -> None:
    units = _installable_copy(tmp_path)
    target = units / (name if "@." not in name else "imudiag@imu0.service")
    if "@." in name:
        target.symlink_to(units / name)
    proc = _analyze("security", "--offline=yes", "--man=no", "--no-pager", str(target))
    if "Unknown command verb" in proc.stderr or "unrecognized option" in proc.stderr:
        pytest.skip(f"this systemd-analyze has no offline security check: {proc.stderr.strip()}")
    match = re.search(r"Overall exposure level for \S+: (\d+\.\d+)", proc.stdout)
    assert match, proc.stdout + proc.stderr
    exposure = float(match.group(1))
    assert exposure <= 2.5, proc.stdout  # 0 = fully sandboxed, 10 = unprotected


# ---------------------------------------------------------------------------
# udev rules

RULES = SYSTEMD_DIR / "99-imudiag.rules"
_TOKEN = re.compile(r'\s*([A-Z_]+(?:\{[^}]+\})?)\s*(==|!=|\+=|-=|:=|=)\s*"([^"]*)"\s*(?:,|$)')
_MATCH_KEYS = re.compile(r"^(ACTION|SUBSYSTEM|KERNEL|DRIVER|ATTRS?\{[^}]+\}|ENV\{[^}]+\}|TAG)$")
_ASSIGN_KEYS = re.compile(
    r"^(SYMLINK|GROUP|MODE|OWNER|TAG|ENV\{[^}]+\}|GOTO|LABEL|RUN\{[^}]+\}|RUN)$"
)


def parse_rules(path: Path) -> list[list[tuple[str, str, str]]]:
    """Rules as lists of (key, operator, value); every token must be well formed."""
    rules = []
    for number, raw in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        assert not line.endswith("\\"), f"line {number}: keep each rule on one line"
        tokens, pos = [], 0
        while pos < len(line):
            m = _TOKEN.match(line, pos)
            assert m, f"{path.name}:{number}: cannot parse at {line[pos:]!r}"
            key, op, value = m.groups()
            if op in ("==", "!="):
                assert _MATCH_KEYS.match(key), f"line {number}: {key} is not a match key"
            else:
                assert _ASSIGN_KEYS.match(key), f"line {number}: {key} cannot be assigned"
            tokens.append((key, op, value))
            pos = m.end()
        rules.append(tokens)
    return rules


def _rule_for(subsystem: str) -> list[tuple[str, str, str]]:
    found = [r for r in parse_rules(RULES) if ("SUBSYSTEM", "==", subsystem) in r]
    assert len(found) == 1, f"expected one rule for SUBSYSTEM=={subsystem}"
    return found[0]


def test_rules_parse_and_labels_match() -> None:
    rules = parse_rules(RULES)
    gotos = {v for r in rules for k, op, v in r if k == "GOTO"}
    labels = {v for r in rules for k, op, v in r if k == "LABEL"}
    assert gotos and gotos <= labels


@pytest.mark.parametrize("subsystem", ["tty", "hidraw", "usb"])
def test_rule_matches_vendor_product_and_serial(subsystem: str) -> None:
    rule = _rule_for(subsystem)
    matches = {k: v for k, op, v in rule if op == "=="}
    assert re.fullmatch(r"[0-9a-f]{4}", matches["ATTRS{idVendor}"])
    assert re.fullmatch(r"[0-9a-f]{4}", matches["ATTRS{idProduct}"])
    assert matches["ATTRS{serial}"]  # never by the bridge's IDs alone
    # the documented placeholder: pid.codes test VID/PID and the simulated board's serial
    assert (matches["ATTRS{idVendor}"], matches["ATTRS{idProduct}"]) == ("1209", "0001")
    assigns = {k: v for k, op, v in rule if op in ("=", "+=", ":=")}
    assert assigns["GROUP"] in ("dialout", "plugdev")
    assert re.fullmatch(r"0[0-7]{3}", assigns["MODE"]) and assigns["MODE"][-1] == "0"
    assert ("TAG", "+=", "systemd") in rule


def test_tty_rule_names_the_device_and_starts_the_instance() -> None:
    rule = _rule_for("tty")
    assigns = {k: v for k, op, v in rule if op in ("=", "+=")}
    assert assigns["SYMLINK"] == "imu0"
    assert assigns["GROUP"] == "dialout"  # the unit's SupplementaryGroups
    wants = assigns["ENV{SYSTEMD_WANTS}"]
    assert wants == f"imudiag@{assigns['SYMLINK']}.service"  # instance = /dev name = %I
    template = wants.split("@")[0] + "@.service"
    assert (SYSTEMD_DIR / template).is_file()


def test_rule_serial_is_the_simulated_boards() -> None:
    """The placeholder serial is the one the bundled certificate was made for."""
    from imudiag.certificate import load_default

    serial = str(load_default().device["serial"])
    for subsystem in ("tty", "hidraw", "usb"):
        assert {k: v for k, _, v in _rule_for(subsystem)}["ATTRS{serial}"] == serial


@pytest.mark.skipif(UDEVADM is None, reason="udevadm not installed (systemd >= 254 has verify)")
def test_udevadm_verify(tmp_path: Path) -> None:
    assert UDEVADM is not None
    proc = subprocess.run(
        [UDEVADM, "verify", str(RULES)], capture_output=True, text=True, timeout=60, check=False
    )
    if "Unknown command" in proc.stderr or "unknown command" in proc.stderr.lower():
        pytest.skip(f"this udevadm has no verify: {proc.stderr.strip()}")
    assert proc.returncode == 0, proc.stdout + proc.stderr


# ---------------------------------------------------------------------------
# journald-friendly logging (imudiag.service.logging_setup), in a real process

_LOGGING_CHILD = """
import logging, sys
from imudiag.service.logging_setup import setup_logging
setup_logging(sys.argv[1])
log = logging.getLogger("imudiag.daemon")
log.debug("debug line")
log.info("info line")
log.warning("IMU gone: reconnecting")
try:
    1 / 0
except ZeroDivisionError:
    log.exception("loop failed")
log.critical("giving up")
logging.getLogger("pyserial.like").error("a library error")
logging.getLogger("pyserial.like").info("a library detail")
print("stdout stays clean")
"""


def _run_logging_child(tmp_path: Path, level: str, journal: bool) -> tuple[str, str]:
    err_path = tmp_path / "stderr.txt"
    env = {k: v for k, v in os.environ.items() if k != "JOURNAL_STREAM"}
    with err_path.open("w") as err:
        if journal:
            st = os.fstat(err.fileno())
            env["JOURNAL_STREAM"] = f"{st.st_dev}:{st.st_ino}"
        else:
            env["JOURNAL_STREAM"] = "1:2"  # someone else's stream: not ours
        proc = subprocess.run(
            [sys.executable, "-c", _LOGGING_CHILD, level],
            stderr=err,
            stdout=subprocess.PIPE,
            text=True,
            env=env,
            timeout=30,
            check=True,
        )
    return proc.stdout, err_path.read_text()


def test_journal_stream_gets_priority_prefixes(tmp_path: Path) -> None:
    out, err = _run_logging_child(tmp_path, "debug", journal=True)
    assert out == "stdout stays clean\n"
    lines = err.splitlines()
    assert lines[0] == "<7>imudiag.daemon: debug line"
    assert lines[1] == "<6>imudiag.daemon: info line"
    assert lines[2] == "<4>imudiag.daemon: IMU gone: reconnecting"
    assert lines[3] == "<3>imudiag.daemon: loop failed"
    assert lines[-2] == "<2>imudiag.daemon: giving up"
    traceback = lines[4:-2]
    assert traceback and all(x.startswith("<3>") for x in traceback)  # every line keeps it
    assert any("ZeroDivisionError" in x for x in traceback)
    # other libraries' records go the same way, from WARNING up
    assert lines[-1] == "<3>pyserial.like: a library error"
    assert "a library detail" not in err
    assert not re.search(r"\d{4}-\d\d-\d\d", err)  # the journal stamps entries itself


def test_terminal_gets_timestamps_and_level_filter(tmp_path: Path) -> None:
    _, err = _run_logging_child(tmp_path, "warning", journal=False)
    lines = [x for x in err.splitlines() if re.match(r"\d{4}-\d\d-\d\d ", x)]
    assert [x.split(" ", 3)[2] for x in lines] == ["WARNING", "ERROR", "CRITICAL", "ERROR"]
    assert "<4>" not in err and "debug line" not in err and "info line" not in err

"""One exception family (imudiag.errors) mapped to exit codes in one place; every command loads."""

from __future__ import annotations

import importlib
import subprocess
import sys

import pytest

from imudiag import cli, errors
from imudiag.errors import (
    BadInput,
    BenchError,
    CertificateError,
    DeviceError,
    ImudiagError,
    SinkError,
    SourceError,
    exit_code,
)

#: Every error class imudiag raises on purpose, by module: all in the family.
ROOTS = {
    "imudiag.certificate": ("CertificateError", CertificateError),
    "imudiag.logs": ("LogError", BadInput),
    "imudiag.service.config": ("ConfigError", BadInput),
    "imudiag.service.nmea": ("NmeaError", BadInput),
    "imudiag.bench.scenario": ("ScenarioError", BadInput),
    "imudiag.bench.feeder": ("FeederError", BenchError),
    "imudiag.drivers.base": ("SourceError", SourceError),
    "imudiag.yamlio": ("YamlError", BadInput),
}


@pytest.mark.parametrize("module", sorted(ROOTS))
def test_error_classes_are_in_the_family(module: str) -> None:
    name, parent = ROOTS[module]
    cls = getattr(importlib.import_module(module), name)
    assert issubclass(cls, parent) and issubclass(cls, ImudiagError)


def test_status_link_error_is_a_sink_error() -> None:
    from imudiag.service.nmea import StatusLinkError

    assert issubclass(StatusLinkError, SinkError) and issubclass(StatusLinkError, OSError)


def test_exit_codes_in_one_place() -> None:
    assert exit_code(BadInput("x")) == 2
    assert exit_code(CertificateError("x")) == 2
    assert exit_code(SourceError("x")) == 2
    assert exit_code(DeviceError("x")) == 2
    assert exit_code(BenchError("x")) == 1
    assert exit_code(SinkError("x")) == 1
    assert exit_code(RuntimeError("x")) == 1
    # old except clauses still catch the family members
    assert isinstance(BadInput("x"), ValueError) and isinstance(SourceError("x"), OSError)
    assert isinstance(BenchError("x"), RuntimeError)
    assert cli.EXIT_BAD_INPUT is errors.EXIT_BAD_INPUT


def test_every_command_is_registered() -> None:
    parser = cli.build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    assert sorted(sub.choices) == sorted(n.replace("_", "-") for n in cli.COMMANDS)


def test_a_command_that_fails_to_import_is_an_error(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(cli, "COMMANDS", (*cli.COMMANDS, "no_such_command"))
    with pytest.raises(ModuleNotFoundError, match="no_such_command"):
        cli.build_parser()


def test_source_error_from_the_command_line_exits_2() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "imudiag", "run", "--source", "sim://?nonsense=1"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.count("\n") == 1 and "nonsense" in proc.stderr

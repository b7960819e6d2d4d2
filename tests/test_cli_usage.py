"""Usage errors name the command that refused them (the one-line error of every command,
exit 2): an option a subcommand does not take is reported by that subcommand's parser,
pointing at its own --help, as a missing or bad option already was. Before, the top
parser reported it: ``imudiag: error: unrecognized arguments: --out z (see imudiag
--help)``, which names neither the command nor the help that lists its options."""

from __future__ import annotations

import pytest

from imudiag.cli import main


@pytest.mark.parametrize(
    ("argv", "prog", "unknown"),
    [
        (["model-check", "x.csv", "--certificate", "c", "--out", "z"], "model-check", "--out z"),
        (["diagnose", "x.csv", "--bogus"], "diagnose", "--bogus"),
        (["fleet", "x", "--out", "d", "--bogus", "1"], "fleet", "--bogus 1"),
        (["--bogus"], "", "--bogus"),
    ],
)
def test_an_unknown_option_is_named_by_its_command(argv, prog, unknown, capsys) -> None:
    with pytest.raises(SystemExit) as stop:
        main(argv)
    assert stop.value.code == 2
    prog = f"imudiag {prog}".strip()
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"{prog}: error: unrecognized arguments: {unknown} (see {prog} --help)"]

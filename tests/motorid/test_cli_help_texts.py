"""Every flag of every motorid command explains itself, with its unit; clipped excitations are reported."""
import argparse
import re

import pytest

from motorid.cli import main

#: Words that give a value's unit, or say it has none.
UNIT = re.compile(r"\[[^\]]+\]|\b(s|ms|rad|rad/s|Hz|baud|duty|samples?|counts|counts/rev|1/s|"
                  r"fraction|probability|dimensionless|seconds|degrees|deg)\b|rad/s\^2")


def _flags(commands):
    for path, parser in commands.items():
        for action in parser._actions:
            if action.option_strings and not isinstance(action, (argparse._HelpAction, argparse._VersionAction)):
                yield " ".join(("motorid", *path)), action


def test_every_flag_has_help(motorid_commands):
    missing = [f"{cmd} {a.option_strings[-1]}" for cmd, a in _flags(motorid_commands)
               if not a.help or a.help == argparse.SUPPRESS]
    assert missing == []
    assert len(list(_flags(motorid_commands))) > 100        # the walk reached the sub-commands and bench parsers


def test_every_numeric_flag_with_a_physical_value_names_its_unit(motorid_commands):
    """A float flag always carries a quantity; so does a flag whose name says time, rate, noise or size."""
    quantity = re.compile(r"period|duration|timeout|noise|delay|rate|baud|amplitude|phase|speed|friction|bias|"
                          r"dead.zone|limit|counts|watchdog|samples|jitter|ms$")
    missing, checked = [], 0
    for cmd, a in _flags(motorid_commands):
        numeric = a.nargs != 0 and (a.type is float or quantity.search(a.dest))
        checked += bool(numeric)
        if numeric and not UNIT.search(a.help):
            missing.append(f"{cmd} {a.option_strings[-1]}: {a.help}")
    assert missing == []
    assert checked > 40
    assert not UNIT.search("sine amplitude (default 200)") and UNIT.search("sine amplitude in duty (default 200)")


@pytest.mark.parametrize("flag, value, wanted", [("--sine", "10,300", 300), ("--constant", "260", 260),
                                                 ("--chirp", "5,50,400", 400), ("--prbs", "300,-300", 300)])
def test_an_excitation_beyond_the_duty_limit_is_reported_on_stderr(tmp_path, capsys, flag, value, wanted):
    assert main(["simulate", "--a", "25", "--b", "3", flag, value, "--duration", "0.5",
                 "--out", str(tmp_path / "r.csv")]) == 0
    err = capsys.readouterr().err
    assert f"motorid: {flag} {value} asks for duty up to {wanted}; clipped to the duty limit ±255" in err


def test_an_excitation_within_the_limit_says_nothing(tmp_path, capsys):
    assert main(["simulate", "--a", "25", "--b", "3", "--sine", "10,255", "--duration", "0.5",
                 "--out", str(tmp_path / "r.csv")]) == 0
    assert "clipped" not in capsys.readouterr().err

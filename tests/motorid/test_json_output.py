"""``--json`` means stdout is one JSON document, for every command that offers the flag."""
from __future__ import annotations

import argparse
import json

import pytest

from motorid.cli import build_parser, main


def _commands_with_json() -> set[str]:
    """Every sub-command (and sub-sub-command) whose parser offers ``--json``."""
    found = set()

    def walk(parser: argparse.ArgumentParser, prefix: str) -> None:
        for action in parser._actions:
            if "--json" in action.option_strings:
                found.add(prefix)
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    walk(sub, f"{prefix} {name}".strip())
    walk(build_parser(), "")
    return found


@pytest.fixture(scope="module")
def run_csv(tmp_path_factory):
    path = tmp_path_factory.mktemp("json") / "run.csv"
    assert main(["simulate", "--a", "25", "--b", "3", "--duration", "2", "--sine", "10,200",
                 "--out", str(path)]) == 0
    return path


#: One command line per command that has --json ({run}: a recording, {out}: a folder for outputs).
COMMAND_LINES = {
    "identify": ["identify", "{run}", "--json", "--save", "{out}/model.json"],
    "frequency": ["frequency", "{run}", "--json"],
    "live": ["live", "--port", "fake://?a=25&b=3&speed=0", "--duration", "1", "--quiet", "--json",
             "--out", "{out}/live.csv"],
}


def test_every_command_with_json_is_covered():
    assert _commands_with_json() == set(COMMAND_LINES)


@pytest.mark.parametrize("name", sorted(COMMAND_LINES))
def test_json_stdout_is_exactly_one_document(name, run_csv, tmp_path, capsys):
    capsys.readouterr()
    argv = [a.format(run=run_csv, out=tmp_path) for a in COMMAND_LINES[name]]
    assert main(argv) == 0
    captured = capsys.readouterr()
    doc = json.loads(captured.out)           # the whole of stdout, not its last line
    assert isinstance(doc, dict) and doc
    assert captured.err.strip()              # the human text went to stderr, not nowhere

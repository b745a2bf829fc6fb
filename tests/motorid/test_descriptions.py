"""Every ``motorid`` command and sub-command says what it does in its ``--help``."""
from __future__ import annotations


def test_every_command_and_subcommand_has_a_description(motorid_commands):
    missing = [" ".join(("motorid", *path)) for path, parser in motorid_commands.items()
               if not (parser.description or "").strip()]
    assert not missing, f"no description in --help: {missing}"

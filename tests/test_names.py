"""The names table of ``docs/develop.md`` agrees with the code.

Every bench knob (``motorsim.rig.bench_knobs()``) has a row with its name, flag and unit;
the flags of those rows exist in ``motorid simulate``; every flag of the table is used by
some command and no command uses a retired one; the ``fake://`` and ``avr-sim://`` URL keys
are knob names or keys the guide lists as device-only.
"""
from __future__ import annotations

import dataclasses
import re
from pathlib import Path
from typing import NamedTuple

import pytest

from motorsim.plant import Motor
from motorsim.rig import bench_knobs
from motorsim.sensors import Encoder

ROOT = Path(__file__).resolve().parent.parent
GUIDE = ROOT / "docs" / "develop.md"

#: flags replaced by the table's names; no command may offer them again
RETIRED_FLAGS = {
    "--out-dir": "--out",
    "--noise": "--angle-noise",
    "--cpr": "--counts-per-rev",
    "--ppr": "--counts-per-rev",
    "--offset": "--count-offset",
    "--delay": "--input-delay",
    "--runs": "--repetitions",
    "--periods": "--sample-periods",
}


class Row(NamedTuple):
    """One row of a markdown table: its cells by header, and the first code span of each."""

    cells: dict[str, str]

    def code(self, column: str) -> str | None:
        match = re.search(r"`([^`]+)`", self.cells.get(column, ""))
        return match.group(1) if match else None


def guide_table(heading: str) -> list[Row]:
    """The first table under the ``## heading`` of the developer guide."""
    text = GUIDE.read_text(encoding="utf-8")
    match = re.search(rf"^## {re.escape(heading)}\n(.*?)(?=^## |\Z)", text, re.MULTILINE | re.DOTALL)
    assert match, f"docs/develop.md has no section '## {heading}'"
    lines = [line.strip() for line in match.group(1).splitlines() if line.strip().startswith("|")]
    assert len(lines) > 2, f"docs/develop.md: no table under '## {heading}'"

    def split(line):
        return [cell.strip() for cell in line.strip("|").split("|")]
    header = split(lines[0])
    return [Row(dict(zip(header, split(line)))) for line in lines[2:]]


def names_rows() -> dict[str, Row]:
    """Rows of the names table by name (the first code span of the ``name`` column)."""
    rows = {}
    for row in guide_table("Names and units"):
        name = row.code("name")
        assert name and name not in rows, f"docs/develop.md: names table row without a name or twice: {row.cells}"
        rows[name] = row
    return rows


def device_only_keys() -> dict[str, set[str]]:
    """URL keys the guide lists as device-only, by scheme."""
    keys: dict[str, set[str]] = {}
    for row in guide_table("Device URL keys"):
        key = row.code("key")
        assert key, f"docs/develop.md: device URL keys row without a key: {row.cells}"
        for scheme in re.findall(r"`(\w[\w-]*)://`", row.cells["schemes"]):
            keys.setdefault(scheme, set()).add(key)
    return keys


def url_keys(scheme: str) -> set[str]:
    """The query keys a port URL of ``scheme`` accepts."""
    from hardware import ports
    if hasattr(ports, "url_keys"):
        return set(ports.url_keys(scheme))
    if scheme == "fake":                # before hardware.ports.url_keys: the keys the parser names
        from hardware.fake_device import parse_fake_url
        with pytest.raises(ValueError, match="known: ") as info:
            parse_fake_url("fake://?no_such_key=1")
        return set(re.findall(r"'(\w+)'", str(info.value).partition("known: ")[2]))
    from hardware.sim.launcher import HarnessOptions
    return {f.name for f in dataclasses.fields(HarnessOptions)}


def unit_text(unit: str) -> str:
    """A unit as the table writes it (``^2`` as ``²``, dimensionless as ``—``)."""
    return unit.replace("^2", "²") if unit else "—"


KNOBS = bench_knobs()
KNOB_NAMES = {k.name for k in KNOBS}


@pytest.mark.parametrize("knob", KNOBS, ids=lambda k: k.name)
def test_every_bench_knob_has_a_row_with_its_name_flag_and_unit(knob):
    rows = names_rows()
    assert knob.name in rows, f"docs/develop.md: names table has no row for the bench knob {knob.name!r}"
    row = rows[knob.name]
    assert row.code("CLI flag") == knob.flag, f"{knob.name}: table flag {row.code('CLI flag')!r}, knob {knob.flag!r}"
    assert row.cells["unit"].startswith(unit_text(knob.unit)), \
        f"{knob.name}: table unit {row.cells['unit']!r}, knob unit {knob.unit!r}"


def test_the_flags_of_bench_knobs_exist_in_simulate(motorid_commands):
    simulate = motorid_commands[("simulate",)]
    flags = {opt for action in simulate._actions for opt in action.option_strings}
    missing = [row.code("CLI flag") for name, row in names_rows().items()
               if name in KNOB_NAMES and row.code("CLI flag") not in flags]
    assert not missing, f"motorid simulate lacks the bench-knob flags {missing}"


def flags_in_use(commands) -> dict[str, list[str]]:
    """Every option string of every command, with the commands that offer it."""
    used: dict[str, list[str]] = {}
    for path, parser in commands.items():
        for action in parser._actions:
            for opt in action.option_strings:
                used.setdefault(opt, []).append(" ".join(("motorid",) + path))
    return used


def test_every_flag_of_the_table_is_offered_by_some_command(motorid_commands):
    table_flags = {flag for row in names_rows().values()
                   for flag in re.findall(r"`(--[\w-]+)`", row.cells["CLI flag"])}
    unused = sorted(table_flags - set(flags_in_use(motorid_commands)))
    assert not unused, f"flags of the names table that no command offers: {unused}"


def test_no_command_offers_a_retired_flag(motorid_commands):
    used = flags_in_use(motorid_commands)
    retired = {flag: (RETIRED_FLAGS[flag], used[flag]) for flag in sorted(set(used) & set(RETIRED_FLAGS))}
    assert not retired, "retired flags still offered (flag: (its name now, commands)): " + repr(retired)


def test_fake_url_keys_are_the_device_knobs_and_the_device_only_keys():
    import identify
    from motorsim.plant import further_parameters
    keys = url_keys("fake")
    device_knobs = {k.name for k in KNOBS if k.owner in (Motor, Encoder)}
    assert not device_knobs - keys, f"fake:// lacks the motor and encoder knobs {sorted(device_knobs - keys)}"
    # a registered structure's own parameters are keys under their names, from the registry (no row each)
    keys -= set(further_parameters(identify.structures()))
    assert keys - KNOB_NAMES == device_only_keys()["fake"], (
        f"fake:// keys that are not knob names {sorted(keys - KNOB_NAMES)}; "
        f"docs/develop.md lists {sorted(device_only_keys()['fake'])}")


def test_avr_sim_url_keys_are_knob_names_or_listed_device_only_keys():
    keys = url_keys("avr-sim")
    assert keys - KNOB_NAMES == device_only_keys()["avr-sim"], (
        f"avr-sim:// keys that are not knob names {sorted(keys - KNOB_NAMES)}; "
        f"docs/develop.md lists {sorted(device_only_keys()['avr-sim'])}")

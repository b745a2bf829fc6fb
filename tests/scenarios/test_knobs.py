"""Every bench knob, under its one name, everywhere a user meets it.

Nothing here lists knobs: each test runs over :func:`motorsim.rig.bench_knobs`, so a knob
added to Motor, Encoder, SimRig or Experiment is checked as a scenario TOML key (and grid
axis), a ``Setting`` field, a sweep CSV column, a ``motorid simulate`` flag and, where the
simulated bench records it, in the recording.
"""
import dataclasses

import pytest

from motorid.cli import build_parser, main
from motorsim.plant import Motor
from motorsim.reading import read_recording
from motorsim.rig import bench_knobs
from scenarios.scenario import SETTING_KEYS, Setting, scenario_from_dict
from scenarios.sweep import CSV_COLUMNS, run_point, setting_column

KNOBS = bench_knobs()
IDS = [k.name for k in KNOBS]
#: Defaults a scenario gives the knobs the bench classes require.
SCENARIO_DEFAULTS = {f.name: f.default for f in dataclasses.fields(Setting)}


def other_value(knob):
    """A valid value of ``knob`` different from the scenario's default (derived from its kind)."""
    default = SCENARIO_DEFAULTS[knob.name]
    if knob.kind is bool:
        return not default
    if knob.kind is int:
        return default - 1 if default > 0 else default + 1
    return default / 2 if default else 0.1


def section(knob):
    return "motor" if knob.owner is Motor else "bench"


def short_run(knob, value):
    """Scenario settings of a short run with ``knob = value``."""
    bench = {"duration": 0.5}
    data = {"repetitions": 1, "methods": ["zoh-ls"], "seed": 1, "bench": bench, "motor": {}}
    data[section(knob)][knob.name] = value
    return data


def test_knob_names_are_unique_and_documented():
    assert len(set(IDS)) == len(IDS)
    assert all(k.help and k.kind in (int, float, bool) for k in KNOBS)


@pytest.mark.parametrize("knob", KNOBS, ids=IDS)
def test_a_knob_is_a_setting_field_and_a_scenario_key(knob):
    assert knob.name in {f.name for f in dataclasses.fields(Setting)}
    assert knob.name in SETTING_KEYS[section(knob)]
    value = other_value(knob)
    point = next(scenario_from_dict(short_run(knob, value)).points())
    assert getattr(point.setting, knob.name) == value


@pytest.mark.parametrize("knob", KNOBS, ids=IDS)
def test_a_knob_is_a_grid_axis_and_a_sweep_csv_column(knob):
    value = other_value(knob)
    data = short_run(knob, value)
    data["grid"] = {f"{section(knob)}.{knob.name}": [SCENARIO_DEFAULTS[knob.name], value]}
    points = list(scenario_from_dict(data).points())
    column = setting_column(knob.name)
    assert column in CSV_COLUMNS
    rows = [run_point(p, ["zoh-ls"], 1, 1).rows()[0] for p in points]
    assert [r[column] for r in rows] == [SCENARIO_DEFAULTS[knob.name], value]


def simulate_argv(knob, value, out):
    """``motorid simulate`` of a short run with ``knob = value`` (the flag given last wins)."""
    flag = [knob.flag] if knob.kind is bool else [knob.flag, str(value)]
    return ["simulate", "--out", str(out), "--a", "25", "--b", "3", "--duration", "0.5", "--seed", "1", *flag]


@pytest.mark.parametrize("knob", KNOBS, ids=IDS)
def test_a_knob_is_a_simulate_flag_with_its_unit(knob, tmp_path, capsys):
    value = other_value(knob)
    args = build_parser().parse_args(simulate_argv(knob, value, tmp_path / "r.csv"))
    assert getattr(args, knob.name) == value
    with pytest.raises(SystemExit):
        main(["simulate", "--help"])
    help_text = " ".join(capsys.readouterr().out.split())
    assert f"{knob.flag} " in help_text and f"[{knob.unit}]" in help_text if knob.unit else knob.flag in help_text


@pytest.mark.parametrize("knob", KNOBS, ids=IDS)
def test_a_knob_reaches_the_recording_of_a_simulated_run(knob, tmp_path):
    value = other_value(knob)
    assert main(simulate_argv(knob, value, tmp_path / "r.csv")) == 0
    rec = read_recording(tmp_path / "r.csv")
    found = [rec.metadata[key] for key in (knob.name, f"true_{knob.name}") if key in rec.metadata]
    if hasattr(rec, knob.name):
        found.append(str(getattr(rec, knob.name)))
    assert found, f"the simulated bench does not record {knob.name}"
    assert all(knob.parse(text) == pytest.approx(value) for text in found)

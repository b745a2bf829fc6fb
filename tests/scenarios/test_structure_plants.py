"""Every registered structure the simulator carries is a scenario's plant and a ``fake://`` device's, by its name
and its parameters' names, from the structure registry (no structure is named in the code that reads them).

Compared exactly: the plant a scenario or a URL builds is the structure's own plant for the same values (frozen
dataclasses, equal field by field); a sweep over a two-mass plant's shaft frequency runs that plant (its
recording equal, sample for sample, to the simulated bench's with the same generator)."""
from __future__ import annotations

import math
import urllib.parse

import numpy as np
import pytest

import identify
from hardware.fake_device import parse_fake_url, url_keys
from scenarios.scenario import PLANT_PARAMETERS, SETTING_KEYS, ScenarioError, scenario_from_dict
from scenarios.sweep import CSV_COLUMNS, run_point

SIMULATED = [s for s in identify.structures().values() if s.simulated]


def values_of(structure) -> dict[str, float]:
    """Valid values, none at its neutral 0 (each further parameter larger than the one before: a static friction
    above the friction)."""
    return {"a": 20.0, "b": 2.5, **{p.name: 0.5 + 0.3 * k for k, p in enumerate(structure.parameters[2:])}}


def test_every_further_parameter_of_a_simulated_structure_is_a_scenario_and_url_key():
    expected = {p.name for s in SIMULATED for p in s.parameters} - {"a", "b", "friction", "bias", "dead_zone",
                                                                    "static_friction", "electrical_time_constant"}
    assert expected and expected <= set(PLANT_PARAMETERS)
    assert {"structure", *PLANT_PARAMETERS} <= set(SETTING_KEYS["motor"]) & set(url_keys())
    assert {"structure", *PLANT_PARAMETERS} <= set(CSV_COLUMNS)


@pytest.mark.parametrize("structure", SIMULATED, ids=lambda s: s.name)
def test_a_scenario_runs_the_structure_s_own_plant(structure):
    values = values_of(structure)
    setting = scenario_from_dict({"motor": {"structure": structure.name, "input_delay": 2, **values},
                                  "bench": {"duration": 0.2}}).point(0).setting
    assert setting.motor() == structure.plant(values, 2)


@pytest.mark.parametrize("structure", SIMULATED, ids=lambda s: s.name)
def test_a_fake_url_runs_the_structure_s_own_plant(structure):
    values = values_of(structure)
    query = urllib.parse.urlencode({"structure": structure.name, "input_delay": 1, "speed": 0, **values})
    assert parse_fake_url(f"fake://?{query}").motor == structure.plant(values, 1)


def test_without_a_structure_the_motor_is_the_knobs_motor_as_before():
    from motorsim import Motor
    setting = scenario_from_dict({"motor": {"friction": 0.3}}).point(0).setting
    assert setting.structure == "" and all(math.isnan(getattr(setting, n)) for n in PLANT_PARAMETERS)
    assert setting.motor() == Motor(25.0, 3.0, friction=0.3)
    assert parse_fake_url("fake://?friction=0.3&speed=0").motor == Motor(25.0, 3.0, friction=0.3)


@pytest.mark.parametrize("motor, words", [
    ({"structure": "two-mass", "inertia_ratio": 1.5, "shaft_frequency": 150.0, "friction": 0.5},
     "friction is not a parameter of the two-mass structure"),
    ({"shaft_frequency": 150.0}, "shaft_frequency needs a structure that has it"),
    ({"structure": "two-mass", "inertia_ratio": 1.5}, "needs a value for 'shaft_frequency'"),
    ({"structure": "asymmetric-gain"}, "asymmetric-gain"),
    ({"structure": "no-such"}, "structure must be one of"),
])
def test_a_plant_that_cannot_be_built_is_refused_naming_the_key(motor, words):
    with pytest.raises(ScenarioError, match=words):
        scenario_from_dict({"motor": motor})
    with pytest.raises(ValueError, match=words):
        parse_fake_url("fake://?" + urllib.parse.urlencode(motor))


def test_a_sweep_over_the_shaft_frequency_runs_the_two_mass_plant():
    from motorsim.rig import SimRig
    from scenarios.sweep import repetition_seed, runs_batched
    truth = {"a": 25.0, "b": 3.0, "inertia_ratio": 1.5, "shaft_damping": 0.1}
    scenario = scenario_from_dict({
        "methods": ["oe"], "repetitions": 1,
        "motor": {"structure": "two-mass", **truth}, "bench": {"sample_period": 0.001, "duration": 0.3},
        "excitation": {"spec": "multisine:3,60,0;110,40,1"}, "grid": {"motor.shaft_frequency": [100.0, 150.0]}})
    for point in scenario.points():
        setting = point.setting
        plant = identify.structures()["two-mass"].plant({**truth, "shaft_frequency": setting.shaft_frequency})
        assert not runs_batched(setting)            # the batch engine runs the first-order motor alone
        rng = np.random.default_rng(repetition_seed(0, point.index, 0))
        ours = setting.sim_rig(rng).run(setting.experiment())
        rng = np.random.default_rng(repetition_seed(0, point.index, 0))
        theirs = SimRig(plant, setting.encoder(), rng=rng).run(setting.experiment())
        assert np.array_equal(ours.counts, theirs.counts)
        row = run_point(point, ["oe"], 1, 0).rows()[0]
        assert row["structure"] == "two-mass" and row["shaft_frequency"] == setting.shaft_frequency


def test_motorid_live_runs_a_structure_named_on_the_url_in_a_fresh_process(tmp_path):
    # the bench learns the structures from identify when it is imported: a fresh process, as a user runs it
    import subprocess
    import sys
    url = "fake://?structure=two-mass&inertia_ratio=1.5&shaft_frequency=60&shaft_damping=0.1&speed=0"
    code = ("import sys\nfrom motorid.cli import main\n"
            f"sys.exit(main(['live', '--port', {url!r}, '--duration', '0.5', '--out', 'run.csv', '--method', 'oe']))")
    done = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    from motorsim.reading import read_recording
    assert len(read_recording(tmp_path / "run.csv")) == 100

"""Scenario definitions: built-ins, TOML files and the errors that name the key."""
import math

import pytest

from scenarios.scenario import ScenarioError, builtin_scenarios, load_scenario, scenario_from_dict

BASE = {"motor": {"a": 25.0, "b": 3.0}, "bench": {"duration": 1.0}, "excitation": {"frequency": 10.0}}


def test_builtins_are_the_four_the_issue_names_and_all_load():
    assert set(builtin_scenarios()) == {"article", "frequency-noise", "resolution", "reality"}
    for name in builtin_scenarios():
        scenario = load_scenario(name)
        assert scenario.name == name
        assert scenario.n_points == math.prod(len(v) for _, v in scenario.grid)
        assert len(list(scenario.points())) == scenario.n_points


def test_article_grid_is_the_four_sines_of_the_article():
    s = load_scenario("article")
    freqs = sorted({p.setting.frequency for p in s.points()})
    assert freqs == [10.0, 20.0, 30.0, 40.0]
    p0 = next(s.points()).setting
    assert (p0.a, p0.b, p0.sample_period, p0.counts_per_rev, p0.duration) == (25.0, 3.0, 0.005, 16667, 10.0)
    assert p0.excitation_object().amplitudes == (200,)


def test_reality_grid_sweeps_every_imperfection():
    axes = set(load_scenario("reality").axes)
    assert axes == {"motor.friction", "motor.dead_zone", "motor.input_delay", "bench.jitter", "bench.drop_rate"}


def test_grid_points_are_row_major_and_override_the_base(tmp_path):
    data = dict(BASE, grid={"excitation.frequency": [5.0, 7.0], "bench.angle_noise": [0.0, 1e-3, 2e-3]})
    s = scenario_from_dict(data)
    pts = list(s.points())
    assert [p.index for p in pts] == list(range(6))
    assert [(p.setting.frequency, p.setting.angle_noise) for p in pts] == [
        (5.0, 0.0), (5.0, 1e-3), (5.0, 2e-3), (7.0, 0.0), (7.0, 1e-3), (7.0, 2e-3)]
    assert s.total_samples() == 6 * 200 * s.repetitions



def test_a_point_by_index_is_the_walked_one_and_the_longest_run_needs_only_the_timing_axes():
    from motorsim.checks import ParameterError
    data = dict(BASE, grid={"bench.duration": [0.5, 2.0, 1.0], "excitation.frequency": [5.0, 7.0],
                            "bench.sample_period": [0.01, 0.002], "bench.angle_noise": [0.0, 1e-3]})
    s = scenario_from_dict(data)
    walked = list(s.points())
    assert [s.point(i) for i in range(s.n_points)] == walked
    assert s.max_samples() == max(p.setting.n_samples for p in walked) == 1000
    with pytest.raises(ParameterError, match="index must be"):
        s.point(s.n_points)

def test_load_from_a_file_and_spec_excitations(tmp_path):
    path = tmp_path / "mine.toml"
    path.write_text('repetitions = 3\nmethods = ["zoh-ls"]\n[bench]\nduration = 2.0\n'
                    '[grid]\n"excitation.spec" = ["prbs:200,-200,8", "chirp:1,50,150"]\n', encoding="utf-8")
    s = load_scenario(path)
    assert s.name == "mine" and s.methods == ("zoh-ls",) and s.repetitions == 3
    assert [p.setting.excitation_object().kind for p in s.points()] == ["prbs", "chirp"]


def test_an_odd_multisine_scenario_runs_its_realisations(tmp_path):
    path = tmp_path / "odd.toml"
    path.write_text('methods = ["oe"]\n[bench]\nduration = 5.12\n'
                    '[grid]\n"excitation.spec" = ["odd-multisine:256,31,20,1", "odd-multisine:256,31,20,2"]\n',
                    encoding="utf-8")
    points = list(load_scenario(path).points())
    assert [p.setting.excitation_object().describe() for p in points] == [
        "odd-multisine:256,31,20,1,3", "odd-multisine:256,31,20,2,3"]
    exp = points[0].setting.experiment()
    assert exp.n_samples == 1024 and (exp.duty()[:256] == exp.duty()[256:512]).all()


@pytest.mark.parametrize("data, match", [
    (dict(BASE, colour="red"), "unknown key 'colour'"),
    (dict(BASE, motor={"a": 25.0, "c": 1.0}), "unknown key motor.c"),
    (dict(BASE, grid={"bench.speed": [1, 2]}), "grid axis 'bench.speed'"),
    (dict(BASE, grid={"bench.angle_noise": []}), "non-empty list"),
    (dict(BASE, bench={"sample_period": -0.005}), "sample_period must be > 0"),
    (dict(BASE, grid={"motor.a": [25.0, -1.0]}), "a must be > 0"),
    (dict(BASE, methods=["nope"]), "methods must name estimators"),
    (dict(BASE, repetitions=0), "repetitions must be an integer >= 1"),
    (dict(BASE, excitation={"spec": "sine:10", "frequency": 3.0}), "either spec or sine fields"),
    (dict(BASE, grid={"excitation.frequency": [10.0, 1000.0]}), "Nyquist"),
], ids=["top-key", "motor-key", "grid-axis", "empty-axis", "sample-period", "grid-value", "method",
        "repetitions", "spec-and-sine", "nyquist"])
def test_bad_definitions_name_the_key_and_the_rule(data, match):
    with pytest.raises(ScenarioError, match=match):
        scenario_from_dict(data)


def test_unknown_scenario_name_lists_the_builtins(tmp_path):
    with pytest.raises(ScenarioError, match="built-in name"):
        load_scenario("no-such-scenario")
    bad = tmp_path / "bad.toml"
    bad.write_text("repetitions = = 3", encoding="utf-8")
    with pytest.raises(ScenarioError, match="not valid TOML"):
        load_scenario(bad)


def test_with_repetitions_and_methods_validate():
    import identify
    s = load_scenario("article")
    assert s.with_methods("all").methods == tuple(identify.available_methods(open_loop=True, first_order=True))
    assert s.with_methods(["oe"]).methods == ("oe",)
    with pytest.raises(ScenarioError, match="methods must"):
        s.with_methods([])
    assert s.with_repetitions(7).repetitions == 7
    with pytest.raises(ScenarioError, match="repetitions"):
        s.with_repetitions(0)

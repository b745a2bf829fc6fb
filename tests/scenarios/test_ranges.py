"""A scenario's keys and a fake:// URL's keys are held to the ranges motorid simulate holds its flags to
(motorsim/ranges.py): the same rule, the value named as the user wrote it."""
from __future__ import annotations

import pytest

from hardware.fake_device import parse_fake_url
from motorsim.checks import ParameterError
from motorsim.ranges import MAX_SPEED, check_bench_values
from scenarios.scenario import ScenarioError, scenario_from_dict


@pytest.mark.parametrize("data, message", [
    ({"motor": {"a": 4.3e9}, "bench": {"sample_period": 0.005}},
     r"x\.toml: motor\.a times bench\.sample_period must be within 1e-09\.\.\.700 .* got a = 4300000000\.0"),
    ({"grid": {"motor.b": [3.0, 1e9]}}, r"motor\.b must keep the top speed of the run.* got b = 1000000000\.0"),
    ({"motor": {"bias": 1e9}}, r"motor\.bias must keep the speed .* got bias = 1000000000\.0"),
    ({"motor": {"friction": 1e9}}, r"motor\.friction must be at most a x 100000 rad/s .* got 1000000000\.0"),
    ({"motor": {"electrical_time_constant": 1e-12}},
     r"motor\.electrical_time_constant must be 0 \(none\) or keep bench\.sample_period / it .* got 1e-12 s"),
    ({"bench": {"angle_noise": 10.0}}, r"bench\.angle_noise must be at most 6\.28319 rad .* got 10\.0"),
    ({"bench": {"initial_speed": -2e5}}, r"bench\.initial_speed must be within \+-100000 rad/s .* got -200000\.0"),
    ({"bench": {"sample_period": 1e-7}}, r"bench\.sample_period must be in 1e-06\.\.\.4294\.97 s .* got 1e-07"),
    ({"bench": {"counts_per_rev": 12, "duration": 0.01}, "motor": {"b": 1e-6}},
     r"motor\.b must move the encoder at least one count"),
])
def test_a_scenario_key_out_of_the_bench_range_is_refused_by_its_name(data, message):
    with pytest.raises(ScenarioError, match=message):
        scenario_from_dict(data, source="x.toml")


def test_a_scenario_within_the_ranges_loads_and_names_the_point_that_is_not():
    ok = scenario_from_dict({"grid": {"bench.sample_period": [0.001, 0.005], "motor.a": [2.0, 120.0]}})
    assert ok.n_points == 4
    with pytest.raises(ScenarioError, match=r"in the setting .*motor\.a = 200000\.0"):
        scenario_from_dict({"grid": {"bench.sample_period": [0.001, 0.005], "motor.a": [2.0, 2e5]}})


@pytest.mark.parametrize("query, message", [
    ("b=1e9", r"fake:// url key 'b' must keep the top speed .* got b = 1000000000\.0"),
    ("a=2&bias=1e6", r"fake:// url key 'bias' must keep the speed .* got bias = 1000000\.0"),
    ("friction=1e12", r"fake:// url key 'friction' must be at most a x 100000 rad/s .* got 1000000000000\.0"),
    ("static_friction=1e12", r"fake:// url key 'static_friction' must be at most a x 100000"),
    ("angle_noise=7", r"fake:// url key 'angle_noise' must be at most 6\.28319 rad .* got 7\.0"),
    ("dead_zone=300", r"fake:// url key 'dead_zone' must be at most 255 duty .* got 300\.0"),
])
def test_a_fake_url_key_out_of_the_bench_range_is_refused_by_its_name(query, message):
    with pytest.raises(ParameterError, match=message):
        parse_fake_url(f"fake://?{query}")


def test_a_fake_url_within_the_ranges_builds_its_device():
    device = parse_fake_url("fake://?a=120&b=30&friction=50&angle_noise=0.001&dead_zone=20&speed=0")
    assert device.motor.a == 120.0 and device.motor.friction == 50.0


def test_without_a_run_length_the_steady_speed_is_the_rule():
    # b x 255 / a is the speed the drive holds; at the range's edge it is allowed, just past it refused
    a = 25.0
    check_bench_values({"a": a, "b": MAX_SPEED * a / 255})
    with pytest.raises(ParameterError, match="b must keep the top speed"):
        check_bench_values({"a": a, "b": MAX_SPEED * a / 255 * (1 + 1e-9)})

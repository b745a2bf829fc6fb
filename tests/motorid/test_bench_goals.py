"""The speed gate (``motorid bench --check``) on made-up figures: a missed goal fails it, no clock involved."""
import importlib
import io
import math

import pytest

from motorid.bench import goals
from motorid.bench.goals import GATED, Goal, report, run_check
from motorid.cli import main

AT_MOST = Goal("a time against its baseline", 3.0)
AT_LEAST = Goal("a speed-up", 100.0, at_most=False)


@pytest.mark.parametrize(("goal", "figure", "met"), [
    (AT_MOST, 2.9, True), (AT_MOST, 3.0, True), (AT_MOST, 3.1, False), (AT_MOST, math.nan, False),
    (AT_LEAST, 101.0, True), (AT_LEAST, 99.9, False), (AT_LEAST, math.inf, False)],
    ids=["below", "at", "above", "nan", "faster", "slower", "inf"])
def test_a_goal_is_met_on_its_side_of_the_limit_only(goal, figure, met):
    assert goal.met(figure) is met
    assert goal.line(figure).endswith("met" if met else "MISSED")


def test_report_prints_every_figure_and_fails_on_one_miss():
    out = io.StringIO()
    assert report([(AT_MOST, 1.0), (AT_LEAST, 150.0)], out) == 0
    assert report([(AT_MOST, 1.0), (AT_LEAST, 50.0)], out) == 1
    lines = out.getvalue().splitlines()
    assert len(lines) == 4 and lines[-1].startswith("a speed-up") and "goal >= 100 x: MISSED" in lines[-1]


def _fake(figures_of):
    """A measure function that returns made-up figures for each gated module's declared goals."""
    def measure(module):
        return [(goal, figures_of(goal)) for goal in importlib.import_module(module).GOALS]
    return measure


def test_the_gate_passes_when_every_goal_is_met_and_fails_on_one_miss():
    def good(goal):
        return goal.limit * (0.5 if goal.at_most else 2.0)
    out = io.StringIO()
    assert run_check(stream=out, measure=_fake(good)) == 0
    assert "all goals met" in out.getvalue()
    victim = GATED["selection"]
    missed = importlib.import_module(victim).GOALS[0]

    def one_bad(goal):
        return goal.limit * 1.5 if goal is missed else good(goal)
    out = io.StringIO()
    assert run_check(stream=out, measure=_fake(one_bad)) == 1
    assert sum("MISSED" in line for line in out.getvalue().splitlines()) == 2    # the goal and the summary


def test_a_declared_goal_the_benchmark_did_not_measure_fails_the_gate():
    out = io.StringIO()
    assert run_check(["simulate"], stream=out, measure=lambda module: []) == 1
    assert "nan" in out.getvalue() and "MISSED" in out.getvalue()


def test_every_gated_benchmark_declares_its_goals_once():
    names = []
    for module in GATED.values():
        mod = importlib.import_module(module)
        assert mod.GOALS and callable(mod.goal_figures)
        names += [g.name for g in mod.GOALS]
    assert len(names) == len(set(names))


def test_motorid_bench_check_exits_nonzero_on_a_missed_goal(monkeypatch, capsys):
    monkeypatch.setattr(goals, "_measure", _fake(lambda goal: math.nan))
    assert main(["bench", "--check", "frequency"]) == 1
    assert "MISSED" in capsys.readouterr().out
    monkeypatch.setattr(goals, "_measure", _fake(lambda goal: goal.limit))
    assert main(["bench", "--check", "frequency"]) == 0


def test_unknown_names_are_refused():
    with pytest.raises(ValueError, match="names must be among"):
        run_check(["parse"], stream=io.StringIO(), measure=lambda module: [])


OPEN = Goal("a goal not reached yet", 3.0, held=8.0)


@pytest.mark.parametrize(("figure", "met", "fails"), [(2.5, True, False), (5.0, False, False), (8.5, False, True),
                                                      (math.nan, False, True)], ids=["met", "open", "worse", "nan"])
def test_an_open_goal_says_missed_but_fails_the_gate_only_beyond_what_it_holds(figure, met, fails):
    assert OPEN.met(figure) is met and OPEN.fails(figure) is fails
    line = OPEN.line(figure)
    assert line.endswith("met") if met else ("MISSED (open; the gate fails above 8 x)" in line)
    assert report([(OPEN, figure)], io.StringIO()) == int(fails)
    assert AT_MOST.fails(figure) is not AT_MOST.met(figure)         # a goal without `held`: missed is failed


def test_the_gate_says_how_many_goals_are_open():
    out = io.StringIO()
    def measure(module):
        return [(OPEN, 5.0)] + [(goal, goal.limit) for goal in importlib.import_module(module).GOALS]
    assert run_check(["frequency"], stream=out, measure=measure) == 0
    assert "every goal held, 1 of them open" in out.getvalue()

"""Long work shows progress on a terminal, stays quiet in pipes, and a sweep says its run time first."""
import math

import pytest

from motorsim import Motor, SimRig
from scenarios.cli import main
from scenarios.demo import article_experiments, run_article
from scenarios.scenario import scenario_from_dict
from scenarios.sweep_time import estimate_sweep_time


def test_demo_counts_its_runs_and_fits_on_a_terminal(capsys):
    exps = article_experiments((10, 20), duration=0.5)
    run_article(SimRig(Motor(25.0, 3.0)), exps, ["zoh-ls", "oe"], progress=True)
    err = capsys.readouterr().err
    assert "demo [" in err and "6/6 steps" in err            # 2 runs + 2 x 2 fits


def test_demo_is_quiet_in_a_pipe(capsys):
    run_article(SimRig(Motor(25.0, 3.0)), article_experiments((10,), duration=0.5), ["zoh-ls"])
    assert capsys.readouterr().err == ""                     # pytest's stderr is not a terminal


def test_sweep_time_estimate_is_points_times_repetitions_times_one_run_and_fit():
    scenario = scenario_from_dict({"name": "t", "repetitions": 7, "methods": ["zoh-ls", "oe"],
                                   "bench": {"duration": 0.5}, "grid": {"excitation.frequency": [10, 20, 30]}})
    est = estimate_sweep_time(scenario, workers=2)
    assert set(est.fits) == {"zoh-ls", "oe"} and est.workers == 2
    assert est.seconds == pytest.approx(3 * 7 * (est.run + sum(est.fits.values())) / 2, rel=1e-12)
    assert all(math.isfinite(t) and t > 0 for t in est.fits.values())
    assert "3 points x 2 methods x 7 repetitions, estimated" in est.describe(scenario)


def test_sweep_announces_its_run_time_unless_quiet(tmp_path, capsys):
    args = ["sweep", "article", "--repetitions", "1", "--methods", "zoh-ls", "--workers", "1", "--no-plots"]
    assert main([*args, "--out", str(tmp_path / "a")]) == 0
    assert "sweep article: 8 points x 1 methods x 1 repetitions, estimated" in capsys.readouterr().err
    assert main([*args, "--out", str(tmp_path / "b"), "--quiet"]) == 0
    assert "estimated" not in capsys.readouterr().err

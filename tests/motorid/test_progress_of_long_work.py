"""Long work shows progress on a terminal, stays quiet in pipes, and a sweep says its run time first."""
import io
import re
import sys

import pytest

from motorid.cli import main
from motorid.commands.demo import article_experiments, run_article
from motorid.progress import Ticker
from motorsim import Motor, SimRig
from motorsim.writing import write_recording
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


def test_sweep_time_estimate_probes_each_method_on_points_spread_over_the_grid(monkeypatch):
    from scenarios import sweep_time
    scenario = scenario_from_dict({"name": "t", "repetitions": 7, "methods": ["zoh-ls", "oe"],
                                   "bench": {"duration": 0.5, "angle_noise": 1e-4},
                                   "grid": {"excitation.frequency": [10, 15, 20, 25, 30, 35]}})
    probed = []
    from scenarios import sweep
    run_point = sweep.run_point

    def spy(point, methods, repetitions, seed, **kw):
        probed.append((point.index, tuple(methods), repetitions))
        return run_point(point, methods, repetitions, seed, **kw)
    monkeypatch.setattr(sweep, "run_point", spy)
    monkeypatch.setattr(sweep_time, "effective_workers", lambda workers: 2.0)
    est = estimate_sweep_time(scenario, workers=2)
    assert {i for i, _, _ in probed} == {0, 2, 3, 5}                 # the first, the last, evenly between
    assert {m for _, m, _ in probed} == {("zoh-ls",), ("oe",)}
    assert {r for _, _, r in probed} == {1, 2}            # batched: what a second repetition adds is timed
    assert set(est.fits) == {"zoh-ls", "oe"} and est.workers == 2 and est.points_probed == 4
    assert sweep_time.WORKER_STARTUP < est.seconds < sweep_time.WORKER_STARTUP + 6 * 7 * sum(est.fits.values())
    assert "6 points x 2 methods x 7 repetitions, estimated" in est.describe(scenario)


def test_sweep_announces_its_run_time_unless_quiet(tmp_path, capsys):
    args = ["sweep", "article", "--repetitions", "1", "--methods", "zoh-ls", "--workers", "1", "--no-plots"]
    assert main([*args, "--out", str(tmp_path / "a")]) == 0
    assert "sweep article: 8 points x 1 methods x 1 repetitions, estimated" in capsys.readouterr().err
    assert main([*args, "--out", str(tmp_path / "b"), "--quiet"]) == 0
    assert "estimated" not in capsys.readouterr().err


class _Terminal(io.StringIO):
    def isatty(self):
        return True


def test_ticker_draws_on_a_terminal_and_wipes_its_line_before_standard_output(capsys):
    term = _Terminal()
    with Ticker("identify: oe-friction fit", stream=term, delay=0, interval=60) as ticker:
        assert re.fullmatch(r"\r\033\[Kidentify: oe-friction fit, \d+ s", term.getvalue())
        ticker.set_note("section 1 of 5: sines")
        print("a table row")
        assert term.getvalue().endswith("\r\033[K")          # wiped before the row was printed
        ticker.draw()
        assert re.search(r"identify: oe-friction fit, \d+ s  section 1 of 5: sines$", term.getvalue())
    assert term.getvalue().endswith("\r\033[K") and type(sys.stdout).__name__ != "_ClearingStdout"
    assert capsys.readouterr().out == "a table row\n"


def test_ticker_is_silent_in_a_pipe_and_leaves_standard_output_alone():
    pipe = io.StringIO()
    before = sys.stdout
    with Ticker("bench accuracy", stream=pipe, delay=0):
        assert sys.stdout is before
    assert pipe.getvalue() == ""


def test_identify_in_a_pipe_shows_no_ticker(tmp_path, capsys):
    rec = SimRig(Motor(25.0, 3.0)).run(article_experiments((10,), duration=0.5)[0])
    write_recording(rec, tmp_path / "r.csv")
    assert main(["identify", str(tmp_path / "r.csv"), "--method", "oe"]) == 0
    assert "identify: oe fit" not in capsys.readouterr().err


def _grid_toml(frequencies: int, noises: int) -> str:
    return "\n".join([
        'name = "big"', 'description = "a large grid"', "seed = 1", "repetitions = 2", 'methods = ["zoh-ls"]',
        "[bench]", "duration = 1.0", "[grid]",
        '"excitation.frequency" = [' + ", ".join(f"{5 + 0.5 * i:g}" for i in range(frequencies)) + "]",
        '"bench.angle_noise" = [' + ", ".join(f"{1e-6 * i:g}" for i in range(noises)) + "]", ""])


@pytest.mark.slow            # the one walk that validates 99 000 points takes seconds
def test_a_99_000_point_sweep_says_its_time_first_after_one_walk_of_the_grid(tmp_path, capsys, monkeypatch):
    """The estimate is the first line, before any point runs; loading, the memory check and the probe
    walk the grid once between them (each walk of 99 000 points costs seconds)."""
    import scenarios.scenario as scenario_module
    from motorid.commands import sweep as sweep_command
    built = [0]
    setting = scenario_module._setting

    def counting(values):
        built[0] += 1
        return setting(values)
    monkeypatch.setattr(scenario_module, "_setting", counting)
    at_work: list[int] = []

    def work(*args, **kwargs):
        at_work.append(built[0])
        raise KeyboardInterrupt          # Ctrl-C as the work starts: none of the 99 000 points runs
    monkeypatch.setattr(sweep_command, "run_scenario", work)
    path = tmp_path / "big.toml"
    path.write_text(_grid_toml(99, 1000))
    assert main(["sweep", str(path), "--workers", "1", "--no-plots", "--out", str(tmp_path / "out")]) == 130
    err = capsys.readouterr().err
    assert err.startswith("sweep big: 99000 points x 1 methods x 2 repetitions, estimated"), err[:300]
    assert "motorid: interrupted (Ctrl-C)" in err
    assert at_work and at_work[0] <= 99_000 + 10, at_work    # one walk to validate, then the probed points

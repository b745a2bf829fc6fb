"""Sweeps: the batch path equals the per-run path, the CSV does not depend on the workers,
failures are counted, estimators are found by name."""
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import identify.methods
from identify import fit
from identify.checks.uncertainty import cramer_rao_bound
from motorid.cli import main
from motorid.commands.sweep import format_sweep_table
from scenarios.scenario import load_scenario, scenario_from_dict
from scenarios.sweep import (
    CSV_COLUMNS,
    MethodOutcome,
    read_sweep_csv,
    repetition_seed,
    run_point,
    run_scenario,
)

# Small but complete: batchable points (noise) and non-batchable ones (jitter); the two batched
# estimators and oe (batched too; the slower estimators add time, not cases;
# test_estimators_are_found_by_name sweeps every available one).
SMALL = """
name = "small"
seed = 7
repetitions = 4
methods = ["euler-ls", "zoh-ls", "oe"]
[motor]
a = 25.0
b = 3.0
[bench]
sample_period = 0.005
counts_per_rev = 4096
duration = 1.0
[excitation]
amplitude = 200
[grid]
"excitation.frequency" = [10.0, 30.0]
"bench.angle_noise" = [0.0, 5e-4]
"bench.jitter" = [0.0, 0.05]
"""


@pytest.fixture
def small(tmp_path):
    path = tmp_path / "small.toml"
    path.write_text(SMALL, encoding="utf-8")
    return load_scenario(path)


def _point(scenario, **want):
    for p in scenario.points():
        if all(getattr(p.setting, k) == v for k, v in want.items()):
            return p
    raise LookupError(want)


def test_seeds_are_spawned_from_the_root_seed():
    # SeedSequence(seed).spawn(n)[i].spawn(R)[r] is what the docs promise
    root = np.random.SeedSequence(123).spawn(5)[3].spawn(4)[2]
    ours = repetition_seed(123, 3, 2)
    assert np.array_equal(root.generate_state(4), ours.generate_state(4))


def test_batch_path_equals_simrig_plus_identify_fit_on_the_same_seeds(small):
    # The batch engine against the path users take: SimRig.run + identify.fit, repetition by
    # repetition with the same generators.  Noise makes every repetition different; the
    # estimates agree to 1e-9 relative (same counts; rounding-level differences in the fit).
    point = _point(small, angle_noise=5e-4, jitter=0.0, frequency=30.0)
    fast = run_point(point, small.methods, small.repetitions, small.seed)
    slow = run_point(point, small.methods, small.repetitions, small.seed, batch=False)
    assert fast.batched and not slow.batched
    for f, s in zip(fast.outcomes, slow.outcomes):
        np.testing.assert_allclose(f.a, s.a, rtol=1e-9)
        np.testing.assert_allclose(f.b, s.b, rtol=1e-9)
    # and the slow path is literally identify.fit on SimRig.run
    rec = point.setting.sim_rig(np.random.default_rng(repetition_seed(small.seed, point.index, 2))).run(
        point.setting.experiment())
    assert fit(rec, method="zoh-ls").a == slow.outcomes[1].a[2]
    assert len(set(fast.outcomes[0].a)) == small.repetitions  # the repetitions really differ


def test_a_repetition_does_not_depend_on_how_many_there_are(small):
    point = _point(small, angle_noise=5e-4, jitter=0.05, frequency=10.0)
    three = run_point(point, ["zoh-ls"], 3, small.seed)
    five = run_point(point, ["zoh-ls"], 5, small.seed)
    np.testing.assert_array_equal(three.outcomes[0].a, five.outcomes[0].a[:3])


def test_csv_rows_carry_the_monte_carlo_statistics_and_the_crb(small, tmp_path):
    summary = run_scenario(small, tmp_path / "out", workers=1)
    rows = read_sweep_csv(summary.csv_path)
    assert len(rows) == small.n_points * len(small.methods) == summary.n_rows
    with open(summary.csv_path, encoding="utf-8") as f:
        assert f.readline().strip().split(",") == list(CSV_COLUMNS)
    point = _point(small, angle_noise=5e-4, jitter=0.0, frequency=30.0)
    result = run_point(point, small.methods, small.repetitions, small.seed)
    for outcome in result.outcomes:
        row = next(r for r in rows if r["point"] == point.index and r["method"] == outcome.method)
        # the definitions: sample mean, bias in % of the truth, std with ddof 1, RMSE about the truth
        assert row["mean_a"] == pytest.approx(np.mean(outcome.a), rel=1e-12)
        assert row["bias_a_pct"] == pytest.approx(100 * (np.mean(outcome.a) / 25.0 - 1), rel=1e-9)
        assert row["std_b"] == pytest.approx(np.std(outcome.b, ddof=1), rel=1e-9)
        assert row["rmse_a"] == pytest.approx(math.sqrt(np.mean((outcome.a - 25.0) ** 2)), rel=1e-12)
        crb = cramer_rao_bound(25.0, 3.0, point.setting.experiment().duty(), 0.005, counts_per_rev=4096,
                               angle_noise=5e-4).stderr()
        assert row["crb_a"] == pytest.approx(crb["a"], rel=1e-12)
        assert row["successes"] == 4 and row["failures"] == 0
    # no CRB where it does not apply (jittered clock)
    jittered = [r for r in rows if r["jitter"] > 0]
    assert jittered and all(math.isnan(r["crb_a"]) for r in jittered)
    # noise-free repetitions are identical: zero spread, exactly
    assert all(r["std_a"] == 0.0 for r in rows if r["angle_noise"] == 0 and r["jitter"] == 0)
    meta = json.loads(summary.json_path.read_text(encoding="utf-8"))
    assert meta["points"] == small.n_points and meta["rows"] == len(rows)
    assert meta["grid_columns"] == {"excitation.frequency": "frequency", "bench.angle_noise": "angle_noise",
                                    "bench.jitter": "jitter"}


def test_failed_fits_are_counted_with_their_reason_not_dropped(tmp_path):
    data = {"repetitions": 3, "bench": {"duration": 1.0, "angle_noise": 1e-4},
            "grid": {"excitation.spec": ["sine:10,200", "constant:0"]}}
    summary = run_scenario(scenario_from_dict(data), tmp_path, workers=1)
    rows = read_sweep_csv(summary.csv_path)
    dead = [r for r in rows if r["excitation"] == "constant:0"]
    assert len(dead) == len(identify.available_methods(open_loop=True, first_order=True))
    for r in dead:
        assert r["successes"] == 0 and r["failures"] == 3
        assert "not persistently exciting" in r["failure_reasons"] and "(3)" in r["failure_reasons"]
        assert math.isnan(r["mean_a"])
    assert summary.failures == {m: 3 for m in identify.available_methods(open_loop=True, first_order=True)}


def test_estimators_are_found_by_name(monkeypatch, tmp_path):
    # A new entry in identify's method table (and its options, none) is swept without any change to the sweep;
    # it has no batched implementation, so it goes through identify.fit on the same counts.
    def shifted(recordings):
        import dataclasses
        est = identify.fit_zoh_ls(recordings)
        return dataclasses.replace(est, method="shifted", a=est.a + 1.0)
    monkeypatch.setitem(identify.methods.ESTIMATORS, "shifted", identify.methods.Estimator("shifted", shifted))
    data = {"repetitions": 3, "seed": 1, "bench": {"duration": 1.0, "angle_noise": 2e-4}}
    summary = run_scenario(scenario_from_dict(data), tmp_path, workers=1)
    rows = {r["method"]: r for r in read_sweep_csv(summary.csv_path)}
    assert set(rows) == set(identify.available_methods(open_loop=True, first_order=True))
    # the same data as the batched zoh-ls, shifted by exactly 1 (to rounding of the two fits)
    assert rows["shifted"]["mean_a"] == pytest.approx(rows["zoh-ls"]["mean_a"] + 1.0, rel=1e-9)
    assert rows["shifted"]["std_a"] == pytest.approx(rows["zoh-ls"]["std_a"], rel=1e-6)


def test_same_csv_from_one_worker_two_processes_and_dask(small, tmp_path):
    one = run_scenario(small, tmp_path / "w1", workers=1).csv_path.read_bytes()
    two = run_scenario(small, tmp_path / "w2", workers=2).csv_path.read_bytes()
    assert one == two
    distributed = pytest.importorskip("dask.distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster, distributed.Client(cluster) as client:
        dask_csv = run_scenario(small, tmp_path / "dask", executor=client.get_executor()).csv_path.read_bytes()
    assert one == dask_csv


def test_cli_sweep_lists_runs_and_plots(small, tmp_path, capsys):
    assert main(["sweep", "--list"]) == 0
    listed = capsys.readouterr().out
    for name in ("article", "frequency-noise", "resolution", "reality"):
        assert name in listed
    toml = tmp_path / "small.toml"
    toml.write_text(SMALL, encoding="utf-8")
    out = tmp_path / "cli"
    assert main(["sweep", str(toml), "--out", str(out), "--workers", "1", "--repetitions", "2",
                 "--methods", "zoh-ls,oe"]) == 0
    text = capsys.readouterr().out
    assert "8 points x 2 methods x 2 repetitions" in text
    rows = read_sweep_csv(out / "sweep.csv")
    assert {r["repetitions"] for r in rows} == {2.0}
    assert [r["method"] for r in rows[:2]] == ["zoh-ls", "oe"]
    for png in ("bias_vs_frequency.png", "heatmap_bias_a.png", "heatmap_bias_b.png"):
        assert (out / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_cli_sweep_errors_are_messages(tmp_path, capsys):
    assert main(["sweep", "nope", "--out", str(tmp_path)]) == 2
    assert "built-in name" in capsys.readouterr().err
    assert main(["sweep", "article", "--workers", "0", "--out", str(tmp_path)]) == 2
    assert "--workers must be >= 1" in capsys.readouterr().err
    assert main(["sweep"]) == 2
    assert "sweep needs a scenario" in capsys.readouterr().err
    assert main(["sweep", "article", "--methods", "zoh-ls,nope", "--out", str(tmp_path)]) == 2
    assert "methods must name estimators" in capsys.readouterr().err


def test_at_most_a_window_of_points_is_in_flight_and_results_come_in_grid_order():
    # Bounded memory: the sweep never submits more than `window` points ahead of the one it writes.
    import concurrent.futures

    from scenarios.executors import results_in_order

    class Recorder(concurrent.futures.Executor):
        def __init__(self):
            self.pending = self.most = 0
            self.order = []

        def submit(self, fn, *args):
            fut = concurrent.futures.Future()
            self.pending += 1
            self.most = max(self.most, self.pending)
            self.order.append(args[0])
            fut.set_result(args[0])
            original = fut.result

            def result(timeout=None):
                self.pending -= 1
                return original(timeout)
            fut.result = result
            return fut

    ex = Recorder()
    jobs = [(i, (), 1, 0) for i in range(20)]
    got = list(results_in_order(ex, lambda i, *_: i, jobs, window=3))
    assert got == list(range(20)) and ex.order == list(range(20))
    assert ex.most == 3


def test_run_point_checks_its_arguments(small):
    point = next(small.points())
    with pytest.raises(ValueError, match="repetitions must be >= 1"):
        run_point(point, ["zoh-ls"], 0, 1)
    with pytest.raises(ValueError, match="methods must be a non-empty list"):
        run_point(point, ["nope"], 2, 1)
    with pytest.raises(TypeError, match="point must be a GridPoint"):
        run_point(point.setting, ["zoh-ls"], 2, 1)
    with pytest.raises(ValueError, match="workers must be >= 1"):
        run_scenario(small, "unused", workers=0)


def test_workers_are_clamped_to_the_cores_and_forked_warm():
    from scenarios.executors import WORKER_PRELOAD, available_cores, usable_workers
    cores = available_cores()
    assert usable_workers(None) == cores
    assert usable_workers(1) == 1
    assert usable_workers(10 * cores) == cores
    assert "scenarios.sweep" in WORKER_PRELOAD
    # In a fresh single-threaded process (earlier tests may leave threads in this one): on
    # Linux the warm parent itself is forked, having imported what a worker needs.
    code = ("import sys; from scenarios.executors import WORKER_PRELOAD, worker_context; "
            "print(worker_context().get_start_method(), all(m in sys.modules for m in WORKER_PRELOAD))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=Path(__file__).resolve().parents[2]).stdout.split()
    assert out == ["fork" if sys.platform.startswith("linux") else "forkserver", "True"]


def test_workers_are_not_forked_from_a_threaded_parent():
    # Another Python thread could hold a lock the forked child would inherit locked.
    import threading

    from scenarios.executors import worker_context
    stop = threading.Event()
    thread = threading.Thread(target=stop.wait)
    thread.start()
    try:
        assert worker_context().get_start_method() in ("forkserver", "spawn")
    finally:
        stop.set()
        thread.join()


@pytest.mark.parametrize("frequency, angle_noise", [(10.0, 0.0), (10.0, 1e-3), (120.0, 3e-4)],
                         ids=["noise-free", "noisy", "no-regression-start"])
def test_batched_oe_equals_identify_fit_per_repetition(frequency, angle_noise):
    # oe fitted on all repetitions at once against identify.fit on SimRig.run, repetition by
    # repetition: the same minimum (1e-9 relative: different starts and paths, rounding apart),
    # so the sweep's table prints the same digits.  At 120 rad/s zoh-ls gives no start.
    scenario = load_scenario("frequency-noise")
    point = _point(scenario, frequency=frequency, angle_noise=angle_noise)
    fast = run_point(point, ["oe"], 20, scenario.seed)
    slow = run_point(point, ["oe"], 20, scenario.seed, batch=False)
    assert fast.batched and not slow.batched
    (f,), (s,) = fast.outcomes, slow.outcomes
    assert f.n_failed == s.n_failed == 0
    np.testing.assert_allclose(f.a, s.a, rtol=1e-9)
    np.testing.assert_allclose(f.b, s.b, rtol=1e-9)
    assert format_sweep_table(scenario, fast.rows()) == format_sweep_table(scenario, slow.rows())


def test_failure_reasons_group_by_the_message_with_its_numbers_masked():
    # each repetition's message carries its own figure; grouped verbatim, every group had one member
    failures = ("singular: cond 3.1e+08 after 12 steps", "singular: cond 2.7e+08 after 9 steps", "",
                "recording is too short: 1 regression rows", "singular: cond -4e+07 after 3 steps")
    outcome = MethodOutcome("oe", np.zeros(5), np.zeros(5), failures)
    assert outcome.failure_summary() == ("singular: cond 3.1e+08 after 12 steps (3) | "
                                         "recording is too short: 1 regression rows (1)")


def test_a_sweep_whose_motor_has_an_electrical_lag_runs_it_on_either_path():
    # The batch engine simulates the first-order motor only: a lag it cannot run must send the point
    # down the per-run path, not be dropped (zoh-ls read a = 25.54 batched against 19.56 per run on
    # this setting).  Noise-free, so both paths see the same counts: equal to 1e-9 relative.
    scenario = scenario_from_dict({
        "name": "lag", "seed": 3, "repetitions": 2, "methods": ["euler-ls", "zoh-ls", "oe"],
        "motor": {"a": 25.0, "b": 3.0, "electrical_time_constant": 0.01},
        "bench": {"sample_period": 0.001, "counts_per_rev": 4096, "duration": 2.0},
        "excitation": {"frequency": 10.0, "amplitude": 200}})
    point = scenario.point(0)
    fast = run_point(point, scenario.methods, 2, scenario.seed)
    slow = run_point(point, scenario.methods, 2, scenario.seed, batch=False)
    assert not fast.batched
    for f, s in zip(fast.outcomes, slow.outcomes):
        assert f.n_failed == s.n_failed == 0
        np.testing.assert_allclose(f.a, s.a, rtol=1e-9)
        np.testing.assert_allclose(f.b, s.b, rtol=1e-9)
    # and the first-order Cramer-Rao bound is not quoted for a plant that is not first-order
    assert fast.crb is None

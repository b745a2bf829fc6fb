"""``motorid control design`` from a saved second-order model: tau_e printed, the full model's margins, the
first-order part's beside them, a design unstable on the full model refused."""
import numpy as np
import pytest

from identify import Estimate
from motorid.cli import main
from motorsim.control import DesignLimitWarning, PlantModel, design_controller

A, B, TAU = 25.0, 3.0, 0.004


def _save(tmp_path, tau=TAU, dt=0.001):
    extra = {"electrical_time_constant": tau, "bias": 0.0} if tau else {}
    names = ("a", "b", "electrical_time_constant", "bias") if tau else ("a", "b")
    est = Estimate("oe-electrical" if tau else "oe", A, B, 4000, dt, 1e-3, 99.0, np.diag([0.04, 1e-4, 1e-8, 1e-4][
        :len(names)]), names, extra, input_delay=1, counts_per_rev=16667)
    path = tmp_path / "m.json"
    path.write_text(est.to_json())
    return str(path)


@pytest.mark.filterwarnings("default::motorsim.control.DesignLimitWarning")
def test_design_from_a_second_order_model_prints_tau_e_and_the_full_models_margins(tmp_path, capsys):
    path = _save(tmp_path)
    # the default weight given: left to itself the design is slowed to the input limit (the reference asks more)
    assert main(["control", "design", "--model", path, "--controller", "lqr-position", "--repetitions", "10",
                 "--duty-weight", "1e-6"]) == 0
    out, err = capsys.readouterr()
    model = PlantModel(A, B, 0.001, 16667, input_delay=1, electrical_time_constant=TAU)
    with pytest.warns(DesignLimitWarning):
        lqr = design_controller("lqr-position", model)
    assert "input delay 1 (0.001 s), electrical time constant 0.004 s, dt = 0.001 s" in out
    assert f"margins at the point estimate: {lqr.margins().describe()}\n" in out
    assert f"the design's first-order part alone: {lqr.first_order_margins().describe()})" in out
    assert lqr.margins().phase_margin < lqr.first_order_margins().phase_margin - 10      # what was hidden
    assert "electrical time constant 0.004 s costs the lqr-position design" in err
    # the saved model's covariance has tau_e's row: the plants are drawn with it
    assert "plants (a, b, tau_e) drawn from a normal distribution" in out and "kept in every plant" not in out


def test_a_first_order_model_prints_no_electrical_line(tmp_path, capsys):
    assert main(["control", "design", "--model", _save(tmp_path, tau=0.0), "--controller", "pi"]) == 0
    assert "electrical" not in capsys.readouterr().out


def test_a_design_unstable_on_the_full_model_is_refused_with_both_verdicts(tmp_path, capsys):
    path = _save(tmp_path, dt=0.005)
    assert main(["control", "design", "--model", path, "--controller", "mpc", "--duty-weight", "1e-6"]) == 2
    err = capsys.readouterr().err
    assert "on the first-order part (phase margin" in err and "stable)" in err
    assert "gives an unstable loop on the full model with its electrical time constant 0.004 s: raise duty_weight" \
        in err


def test_design_and_closed_loop_simulation_from_flags_carry_tau_e(tmp_path, capsys):
    """``--electrical-time-constant`` is the design model's in ``control design``, the motor's (and so the
    model's) in ``simulate --controller``: the rig's measured tracking then matches the full model's prediction."""
    assert main(["control", "design", "--a", "25", "--b", "3", "--electrical-time-constant", "0.004",
                 "--sample-period", "0.001", "--input-delay", "1", "--controller", "pi"]) == 0
    out = capsys.readouterr().out
    pi = design_controller("pi", PlantModel(A, B, 0.001, 16667, input_delay=1, electrical_time_constant=TAU))
    assert "electrical time constant 0.004 s" in out and f"margins at the point estimate: {pi.margins().describe()}" \
        in out
    run = tmp_path / "run.csv"
    assert main(["simulate", "--a", "25", "--b", "3", "--electrical-time-constant", "0.004", "--sample-period",
                 "0.001", "--controller", "pi", "--reference", "sine:10,10", "--duration", "2", "--out", str(run)]) == 0
    text = capsys.readouterr().out
    measured, predicted = (float(x) for x in text.split("measured ")[1].split(" rad/s")[0].split(", predicted "))
    assert measured == pytest.approx(predicted, rel=0.10)     # the tolerance every controller is held to
    from motorsim import read_recording
    meta = read_recording(run).metadata
    assert meta["true_electrical_time_constant"] == meta["model_electrical_time_constant"] == "0.004"

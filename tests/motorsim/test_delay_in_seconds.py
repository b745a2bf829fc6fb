"""An input delay is a time: a model's delay is counted again at each sample period, or refused."""
import pytest

from identify import fit
from motorsim import Experiment, Motor, SimRig, Sine
from motorsim.checks import ParameterError
from motorsim.control import PISpeed, PlantModel
from motorsim.plant import delay_at


@pytest.mark.parametrize("delay, period, new, expected", [(4, 0.005, 0.001, 20), (20, 0.001, 0.005, 4),
                                                          (3, 0.001, 0.003, 1), (0, 0.005, 0.003, 0),
                                                          (2, 0.005, 0.005, 2)],
                         ids=["finer", "coarser", "float-rounding", "no-delay", "same"])
def test_delay_at_keeps_the_time(delay, period, new, expected):
    assert delay_at(delay, period, new) == expected
    assert expected * new == pytest.approx(delay * period, rel=1e-12)


@pytest.mark.parametrize("delay, period, new", [(1, 0.005, 0.002), (1, 0.005, 0.01), (4, 0.005, 0.003)],
                         ids=["2.5-samples", "half-a-sample", "6.67-samples"])
def test_delay_at_refuses_a_time_that_is_not_whole_samples(delay, period, new):
    with pytest.raises(ParameterError, match=rf"input_delay {delay} samples? at {period} s .* at {new} s, not a "
                                             "whole number"):
        delay_at(delay, period, new)


@pytest.fixture(scope="module")
def delayed_estimate():
    """oe on a run of a motor with 20 ms of delay at 5 ms: 4 samples."""
    rec = SimRig(Motor(25.0, 3.0, input_delay=4)).run(Experiment(Sine(10.0, 200), 0.005, 4.0))
    return fit(rec, method="oe", input_delay=4)


def test_a_controller_at_another_sample_period_is_designed_with_the_same_delay_in_seconds(delayed_estimate):
    at_1ms = PlantModel.from_source(delayed_estimate, 0.001, 16667)
    assert at_1ms.input_delay == 20
    direct = PlantModel(delayed_estimate.a, delayed_estimate.b, 0.001, 16667, input_delay=20)
    # the fast PI is unstable with the real 20 ms: counting 4 samples of 1 ms called it stable (31.5 deg)
    pi = PISpeed(at_1ms, time_constant=0.01, min_phase_margin=0.0)
    assert not pi.is_stable() and pi.margins() == PISpeed(direct, 0.01, min_phase_margin=0.0).margins()
    from_model = PlantModel.from_source(PlantModel.from_source(delayed_estimate, 0.005, 16667), 0.001)
    assert from_model == at_1ms
    with pytest.raises(ParameterError, match="input_delay 4 samples at 0.005 s .* 0.003 s, not a whole number"):
        PlantModel.from_source(delayed_estimate, 0.003, 16667)


def test_a_motor_has_no_sample_period_so_its_delay_is_in_the_samples_asked_for():
    assert PlantModel.from_source(Motor(25.0, 3.0, input_delay=2), 0.001, 16667).input_delay == 2

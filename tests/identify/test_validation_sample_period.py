"""Validation on a recording at another sample period: the estimate's input delay is a time."""
import pytest

from identify import fit, validate
from motorsim import Experiment, Motor, SimRig, Sine
from motorsim.checks import ParameterError


@pytest.fixture(scope="module")
def delayed_estimate():
    """oe on a run of a motor with 20 ms of delay at 5 ms: 4 samples."""
    rec = SimRig(Motor(25.0, 3.0, input_delay=4)).run(Experiment(Sine(10.0, 200), 0.005, 4.0))
    return fit(rec, method="oe", input_delay=4)


def test_validation_on_a_run_at_another_sample_period_counts_the_delay_in_its_samples(delayed_estimate):
    run_1ms = SimRig(Motor(25.0, 3.0, input_delay=20)).run(Experiment(Sine(10.0, 200), 0.001, 4.0))
    native = fit(run_1ms, method="oe", input_delay=20)
    # both models are the true motor to 1e-4 relative, so they explain the run alike (0.05 points: the
    # encoder's rounding); with 4 samples of 1 ms the right model scored 84 %
    assert validate(delayed_estimate, run_1ms).fit_percent == pytest.approx(validate(native, run_1ms).fit_percent,
                                                                           abs=0.05)
    run_3ms = SimRig(Motor(25.0, 3.0)).run(Experiment(Sine(10.0, 200), 0.003, 1.0))
    with pytest.raises(ParameterError, match=r"input_delay 4 samples at 0.005 s \(0.02 s\) is 6.66667 samples at "
                                             "0.003 s, not a whole number"):
        validate(delayed_estimate, run_3ms)

"""``motorid bench coverage``: each class makes the recording it names, the truth a = 25, b = 3."""
import numpy as np
import pytest

from motorid.bench.coverage import CLASSES, A, B, bench_coverage


@pytest.mark.parametrize("name", ["electrical lag 8 ms at 1 ms", "delay 20 samples at 1 ms"])
def test_the_lag_and_delay_classes_are_the_plants_they_name(name):
    rec = CLASSES[name](0)
    assert float(rec.metadata["true_a"]) == A and float(rec.metadata["true_b"]) == B
    assert rec.sample_period == 0.001
    if "lag" in name:
        assert float(rec.metadata["true_electrical_time_constant"]) == 0.008
    else:
        assert rec.metadata["true_input_delay"] == "20"


def test_the_differenced_speed_class_is_a_speed_on_the_count_grid():
    # 1000 counts at 2 ms: every speed is a whole number of counts per sample, 2 pi / 1000 / 0.002 rad/s
    rec = CLASSES["differenced speed, 1000 counts, 2 ms"](3)
    assert rec.counts is None and rec.sample_period == 0.002
    steps = rec.speed / (2 * np.pi / 1000 / 0.002)
    np.testing.assert_allclose(steps, np.round(steps), atol=1e-6)
    assert np.ptp(np.round(steps)) > 10


def test_the_position_loop_class_feeds_a_random_torque_back():
    rec = CLASSES["PD position loop, friction, torque"](0)
    assert rec.reference is not None and rec.metadata["controller"] == "position"
    assert rec.metadata["disturbance"] == "30.0" and float(rec.metadata["true_friction"]) == 60.0
    assert len(rec) == 15000
    # the seed sets the torque: two seeds, two different duty sequences
    assert not np.array_equal(rec.duty, CLASSES["PD position loop, friction, torque"](1).duty)


def test_the_speed_loop_class_feeds_a_random_torque_back():
    rec = CLASSES["PI speed loop, friction, torque"](0)
    assert rec.reference is not None and rec.metadata["controller"] == "pi"
    assert rec.metadata["disturbance"] == "30.0" and float(rec.metadata["true_friction"]) == 60.0
    assert not np.array_equal(rec.duty, CLASSES["PI speed loop, friction, torque"](1).duty)


@pytest.mark.parametrize("name, delay, tau, friction", [
    ("electrical lag 10 ms, delay 3, at 1 ms", "3", 0.01, 0.0),
    ("delay 15 samples, Coulomb friction", "15", 0.0, 60.0),
])
def test_the_combined_classes_are_the_plants_they_name(name, delay, tau, friction):
    rec = CLASSES[name](0)
    assert rec.metadata["true_input_delay"] == delay and float(rec.metadata.get("true_friction", 0.0)) == friction
    assert float(rec.metadata.get("true_electrical_time_constant", 0.0)) == tau


def test_an_unknown_class_or_no_seed_is_refused(capsys):
    with pytest.raises(SystemExit):
        bench_coverage(["--only", "no such class"])
    with pytest.raises(SystemExit):
        bench_coverage(["--seeds", "0"])
    assert "--seeds" in capsys.readouterr().err


def test_a_refused_recording_is_counted_not_raised(monkeypatch):
    import identify
    from identify.errors import NotIdentifiableError
    from motorid.bench import coverage

    def refuse(rec, *args, **kwargs):
        raise NotIdentifiableError("no stable first-order model fits")
    monkeypatch.setattr(identify, "fit", refuse)
    outcome = coverage.coverage_run("past: driver clips the duty", 0)
    assert outcome.refused and not (outcome.covered or outcome.clear)
    row, met = coverage._row("past: driver clips the duty", [outcome])
    assert "(1 refused)" in row and met          # no answer is never a clear wrong one

"""Static friction (stiction): ``oe-friction`` with ``static_friction`` fits the break-away level by a profile,
the ``stiction`` structure carries it, and the default chooses it only on evidence."""
import numpy as np
import pytest

import identify
from identify import fit
from motorsim import Motor, Multisine, Recording, Sine, simulate
from motorsim.checks import ParameterError

A, B, C = 25.0, 3.0, 60.0


def _recording(ratio, multisine, counts_per_rev, seed, friction=C):
    """6000 samples at 5 ms of the motor (a = 25, b = 3, friction 60 rad/s^2) under one sine of 5 rad/s,
    amplitude 200, or a three-line multisine, read by an encoder whose phase (where the shaft's zero falls
    within a count) the seed draws, as a rig's is wherever the shaft was at power-up, with 1e-4 counts of
    noise."""
    n, h = 6000, 0.005
    t = np.arange(n) * h
    excitation = Multisine((2.0, 7.0, 19.0), (90, 70, 50), (0, 1, 2)) if multisine else Sine(5.0, 200)
    u = excitation.duty(n, h).astype(float)
    motor = Motor(A, B, friction=friction, static_friction=ratio * friction if ratio else 0.0)
    angle = simulate(motor, u, t).angle
    rng = np.random.default_rng(seed)
    phase = rng.uniform()
    counts = np.floor(angle * counts_per_rev / (2 * np.pi) + phase + 1e-4 * rng.standard_normal(n)).astype(np.int64)
    return Recording(time=t, duty=u, sample_period=h, counts=counts, counts_per_rev=counts_per_rev)


def _covers(est, name, truth):
    low, high = est.confidence_interval()[name]
    return low <= truth <= high


def test_the_structure_is_registered_and_carries_the_level_to_the_simulator():
    found = identify.structures()["stiction"]
    assert found.param_names == ("a", "b", "friction", "static_friction", "bias")
    assert found.method == "oe-friction" and found.options == {"dead_zone": False, "static_friction": True}
    motor = found.plant({"a": A, "b": B, "friction": C, "static_friction": 1.6 * C, "bias": 0.5}, input_delay=1)
    assert (motor.friction, motor.static_friction, motor.bias, motor.input_delay) == (C, 1.6 * C, 0.5, 1)


@pytest.mark.parametrize("ratio", [1.6, 2.0], ids=["1.6x", "2x"])
def test_oe_friction_fits_the_static_level_and_its_bracket_holds_the_truth(ratio):
    # a sine on a 1000-count encoder: a and b to 0.1 % (measured: 0.05 % at most), the level's bracket (the
    # forces between which every level gives the same response) around the truth
    est = fit(_recording(ratio, False, 1000, 0), "oe-friction", input_delay=0, dead_zone=False, static_friction=True)
    assert est.structure == "stiction" and est.method == "oe-friction"
    assert est.a == pytest.approx(A, rel=1e-3) and est.b == pytest.approx(B, rel=1e-3)
    assert est.extra["friction"] == pytest.approx(C, rel=1e-2)
    assert est.extra["static_friction"] >= est.extra["friction"]
    assert _covers(est, "static_friction", ratio * C)
    low, high = est.confidence_interval()["static_friction"]
    assert high - low < 0.1 * ratio * C                              # one or two of the sine's force steps
    assert est.motor().static_friction == est.extra["static_friction"]


def test_a_narrow_well_in_the_static_level_s_cost_is_found():
    # static friction 100 rad/s^2 (5/3 of the sliding level) under the sine, 6 s from SimRig (1e-4 rad of
    # noise, fixed seed): the cost over the levels has a narrow well, two levels wide, that the scans' evenly
    # spread levels stepped over, and the search stopped at 86 (a = 24.84 [24.835, 24.848], b 0.5 % low,
    # intervals without the truth); its later rounds now try every level near their own
    from motorsim import Encoder, Experiment, SimRig
    rig = SimRig(Motor(A, B, friction=C, static_friction=100.0), Encoder(1000, angle_noise=1e-4),
                 rng=np.random.default_rng(0))
    rec = rig.run(Experiment(Sine(5.0, 200), 0.005, 6.0))
    est = fit(rec, "oe-friction", input_delay=0, dead_zone=False, static_friction=True)
    assert est.a == pytest.approx(A, rel=1e-3) and est.b == pytest.approx(B, rel=1e-3)
    assert _covers(est, "a", A) and _covers(est, "b", B) and _covers(est, "static_friction", 100.0)


def test_without_stiction_the_level_stays_at_the_friction():
    est = fit(_recording(0.0, True, 1000, 0), "oe-friction", input_delay=0, dead_zone=False, static_friction=True)
    low, _ = est.confidence_interval()["static_friction"]
    assert low == pytest.approx(est.extra["friction"], rel=1e-12)      # the friction level is within the noise
    assert est.a == pytest.approx(A, rel=2e-3) and est.b == pytest.approx(B, rel=2e-3)


def test_static_friction_with_a_dead_zone_is_refused_by_name():
    with pytest.raises(ParameterError, match="static_friction=True fits no dead zone"):
        fit(_recording(1.6, False, 1000, 0), "oe-friction", static_friction=True)


def test_the_default_chooses_stiction_where_it_is_and_keeps_friction_where_it_is_not():
    sticky = fit(_recording(2.0, False, 1000, 0))
    assert sticky.structure == "stiction" and sticky.input_delay == 0
    assert sticky.a == pytest.approx(A, rel=1e-2) and sticky.b == pytest.approx(B, rel=1e-2)
    plain = fit(_recording(0.0, True, 1000, 0))
    assert plain.structure == "friction"
    judged = [c for c in plain.selection.candidates if c.structure == "stiction"]
    assert judged and plain.selection.chosen.structure == "friction"


def _judged(est, truth_a, truth_b):
    """Within 1 %, or inside covering intervals narrower than +-25 %; and never clear with an interval that misses.

    The intervals are the 99.9 % ones: a 95 % interval misses one run in twenty by design, and the 24 runs here
    would then miss about two (measured: one, ``a`` 2.0 standard errors off by 0.011 %); at 99.9 % all 24 must hold.
    """
    ci = est.confidence_interval(0.999)
    covered = ci["a"][0] <= truth_a <= ci["a"][1] and ci["b"][0] <= truth_b <= ci["b"][1]
    narrow = max((ci["a"][1] - ci["a"][0]) / 2 / truth_a, (ci["b"][1] - ci["b"][0]) / 2 / truth_b) < 0.25
    close = abs(est.a / truth_a - 1) <= 0.01 and abs(est.b / truth_b - 1) <= 0.01
    return (close or (covered and narrow)), (covered or not est.selection.clear)


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("counts_per_rev", [1000, 360])
@pytest.mark.parametrize("multisine", [False, True], ids=["sine", "multisine"])
@pytest.mark.parametrize("ratio", [1.6, 2.0], ids=["1.6x", "2x"])
def test_the_default_on_stiction(ratio, multisine, counts_per_rev, seed):
    est = fit(_recording(ratio, multisine, counts_per_rev, seed))
    accurate, honest = _judged(est, A, B)
    assert accurate, (est.structure, est.input_delay, est.a, est.b, est.confidence_interval())
    assert honest, (est.structure, est.a, est.b, est.confidence_interval())

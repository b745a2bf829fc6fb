"""Excitations: defining properties of each waveform, and the integer arithmetic's accuracy."""
import math

import numpy as np
import pytest

from motorsim.excitation import (
    PRBS,
    Chirp,
    Constant,
    Multisine,
    Sine,
    Step,
    parse_excitation,
    phase_increment,
    sine_q15,
    sine_table,
)

# The interpolated Q15 table is within 4.8e-5 of sin (measured over the whole phase circle
# below); the firmware divides by 32768 (a shift), not 32767, which adds a gain error of
# 1/32768 = 3.1e-5: together within 7.7e-5 of full scale (measured, 8e-5 used below).
# The u32 phase step is exact to 2**-33 cycle per sample, i.e. 1.5e-9 rad/sample drift.
TABLE_ERROR = 4.8e-5
SINE_ERROR = 8e-5


def _phase_drift(n):
    return n * 2 * np.pi * 2.0**-33 + 2 * np.pi * 2.0**-33  # step rounding over n samples + phase0 rounding


def test_sine_table_matches_its_definition():
    t = sine_table()
    assert t.dtype == np.int16 and len(t) == 1024
    np.testing.assert_array_equal(t, np.rint(32767 * np.sin(2 * np.pi * np.arange(1024) / 1024)))


def test_interpolated_sine_accuracy_over_the_whole_circle():
    phase = np.arange(0, 2**32, 4099, dtype=np.int64)
    err = sine_q15(phase) / 32767 - np.sin(2 * np.pi * phase / 2**32)
    assert np.abs(err).max() < TABLE_ERROR


@pytest.mark.parametrize("freq, amp, phase", [(10, 200, 0.0), (40, 200, 1.1), (3.3, 255, -2.0), (600, 100, 0.5)],
                         ids=["10", "40", "slow", "near-nyquist"])
def test_sine_is_the_articles_rounded_sine(freq, amp, phase):
    dt, n = 0.005, 4000
    duty = Sine(freq, amp, phase).duty(n, dt)
    exact = amp * np.sin(freq * np.arange(n) * dt + phase)
    assert duty.dtype == np.int64
    assert np.abs(duty - exact).max() <= 0.5 + amp * (SINE_ERROR + _phase_drift(n))
    assert np.mean(duty != np.rint(exact)) < 0.01


def test_sine_frequency_is_realised_to_one_part_in_2_to_32_per_sample():
    inc = phase_increment(10.0, 0.005)
    realised = inc * 2 * math.pi / 2**32 / 0.005
    assert abs(realised - 10.0) <= 0.5 * 2 * math.pi / 2**32 / 0.005


def test_duty_is_clamped():
    duty = Sine(10, 1000).duty(1000, 0.005, duty_limit=255)
    assert duty.max() == 255 and duty.min() == -255
    assert Constant(-300).duty(5, 0.01, duty_limit=100).tolist() == [-100] * 5


def test_multisine_is_the_sum_of_its_sines_within_rounding():
    ms = Multisine((5.0, 17.0, 41.0), (60, 50, 40), (0.0, 1.0, 2.0), offset=10)
    dt, n = 0.002, 3000
    t = np.arange(n) * dt
    exact = 10 + 60 * np.sin(5 * t) + 50 * np.sin(17 * t + 1) + 40 * np.sin(41 * t + 2)
    assert np.abs(ms.duty(n, dt) - exact).max() <= 0.5 + 150 * (SINE_ERROR + _phase_drift(n))


@pytest.mark.parametrize("order", range(2, 17))
def test_prbs_is_maximal_length(order):
    bits = PRBS(order=order).bits((1 << order) - 1)
    period = (1 << order) - 1
    assert bits.sum() == 1 << (order - 1)  # a maximal-length sequence has 2^(n-1) ones per period
    # autocorrelation of the +-1 sequence is -1 at every nonzero lag (a defining property)
    s = 2.0 * bits - 1
    for lag in (1, 2, period // 3):
        assert np.dot(s, np.roll(s, lag)) == -1


def test_prbs_levels_and_hold():
    duty = PRBS(high=90, low=-40, order=5, hold=4).duty(40, 0.01)
    assert set(duty.tolist()) == {90, -40}
    assert np.all(duty.reshape(10, 4) == duty.reshape(10, 4)[:, :1])


def test_step_switches_at_the_nearest_sample():
    duty = Step(after=120, at_time=0.033, before=-5).duty(10, 0.01)
    assert duty.tolist() == [-5, -5, -5, 120, 120, 120, 120, 120, 120, 120]


def test_chirp_sweeps_its_frequency_band():
    dt, n = 0.001, 20000
    c = Chirp(2.0, 60.0, 200)
    duty = c.duty(n, dt)
    # instantaneous frequency from the phase of the analytic signal rises from f0 to f1
    from scipy.signal import hilbert
    inst = np.diff(np.unwrap(np.angle(hilbert(duty.astype(float))))) / dt
    assert abs(np.median(inst[1000:2000]) - (2.0 + 58.0 * 1500 / n)) < 1.0
    assert abs(np.median(inst[-2000:-1000]) - (2.0 + 58.0 * (n - 1500) / n)) < 1.0


@pytest.mark.parametrize("spec", ["sine:10.0,200,0.3", "multisine:5.0,60,0.0;17.0,50,1.0@10", "chirp:1.0,50.0,200",
                                  "prbs:200,-200,7,2,5", "step:120,0.5,-5", "constant:42"])
def test_describe_and_parse_round_trip(spec):
    ex = parse_excitation(spec)
    assert parse_excitation(ex.describe()) == ex
    np.testing.assert_array_equal(parse_excitation(ex.describe()).duty(500, 0.005), ex.duty(500, 0.005))


@pytest.mark.parametrize("build, match", [
    (lambda: Sine(10, 200.5), "amplitudes must be an integer"),
    (lambda: Sine(-1.0), "frequencies must be > 0"),
    (lambda: Sine(10, 2000), r"amplitudes must be in -1023\.\.\.1023"),
    (lambda: Sine(700).duty(10, 0.005), "below the Nyquist frequency"),
    (lambda: Multisine((1, 2, 3, 4, 5), (10,)), "1...4 components"),
    (lambda: PRBS(order=20), r"order must be in 2\.\.\.16"),
    (lambda: PRBS(order=4, seed=16), r"seed must be in 1\.\.\.15"),
    (lambda: Sine(10).duty(10, 0.0), "sample_period must be > 0"),
    (lambda: parse_excitation("sine"), "must look like KIND:ARGS"),
    (lambda: parse_excitation("square:1"), "excitation kind must be one of"),
    (lambda: parse_excitation("sine:ten"), "comma-separated numbers"),
], ids=["amp-float", "freq-neg", "amp-big", "nyquist", "components", "order", "seed", "dt", "nokind", "kind", "nan"])
def test_bad_excitations_are_refused_with_the_rule(build, match):
    with pytest.raises((ValueError, TypeError), match=match):
        build()


def test_an_empty_offset_is_refused_in_excitations_and_references_alike():
    # one parser splits KIND:ARGS[@OFFSET] for both; "@" with nothing after it is a typo, never no offset
    from motorsim.control import parse_reference
    with pytest.raises(ValueError, match=r"excitation 'sine:10,200@': @ takes one OFFSET, got none"):
        parse_excitation("sine:10,200@")
    with pytest.raises(ValueError, match=r"reference 'sine:10,20@': @ takes one OFFSET, got none"):
        parse_reference("sine:10,20@")
    with pytest.raises(ValueError, match="excitation 'sine:10@x': expected comma-separated numbers"):
        parse_excitation("sine:10@x")

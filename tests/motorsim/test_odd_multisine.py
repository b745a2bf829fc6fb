"""The odd random-phase multisine: defining properties (odd lines only, exact period, left-out lines)."""
import numpy as np
import pytest

from motorsim.excitation import MAX_ODD_LINES, Multisine, OddMultisine, multisine_duty, parse_excitation


@pytest.mark.parametrize("seed", [0, 1, 12345], ids=["schroeder", "seed1", "seed12345"])
def test_duty_repeats_every_period_and_holds_only_the_excited_odd_lines(seed):
    ex = OddMultisine(period=512, max_harmonic=41, amplitude=30, seed=seed)
    d = ex.duty(3 * 512, 0.005)
    assert np.array_equal(d[:512], d[512:1024]) and np.array_equal(d[:512], d[1024:])
    spectrum = np.abs(np.fft.rfft(d[:512]))
    excited = np.array(ex.excited_harmonics())
    # each excited line carries amplitude * period / 2 to within the duty's rounding
    np.testing.assert_allclose(spectrum[excited], 30 * 512 / 2, rtol=0.02)
    others = np.setdiff1d(np.arange(0, 257), excited)   # even lines and left-out odd ones
    assert spectrum[others].max() < 0.01 * spectrum[excited].min()   # the duty's rounding only


def test_left_out_lines_are_one_per_group_and_the_same_for_every_seed():
    lines = {OddMultisine(1024, 63, 20, seed).detection_harmonics() for seed in (0, 1, 2, 999)}
    assert len(lines) == 1
    left_out = lines.pop()
    groups = [list(range(3, 64, 2))[i:i + 3] for i in range(0, 31, 3)]
    for g in groups:
        assert sum(h in left_out for h in g) == (1 if len(g) == 3 else 0)
    assert 1 in OddMultisine(1024, 63, 20).excited_harmonics()
    assert OddMultisine(1024, 63, 20, group=0).detection_harmonics() == ()


def test_seeds_are_different_phases_of_the_same_amplitude_spectrum():
    a, b = OddMultisine(256, 31, 20, 1), OddMultisine(256, 31, 20, 2)
    assert a.excited_harmonics() == b.excited_harmonics()
    assert a.phase_words() != b.phase_words()


def test_duty_is_the_multisine_arithmetic_of_its_components():
    ex = OddMultisine(256, 31, 20, 3, offset=5)
    comps = ex.components()
    assert all(inc == h << 24 for (_, _, inc), h in zip(comps, ex.excited_harmonics()))
    np.testing.assert_array_equal(ex.duty(300, 0.01), np.clip(multisine_duty(comps, 5, 300), -255, 255))
    assert not isinstance(ex, Multisine)   # not a four-component wave a device could be sent as MULTISINE


def test_schroeder_phases_keep_the_crest_factor_low():
    d = OddMultisine(1024, 63, 10, seed=0, group=0).duty(1024, 0.005)
    rms = np.sqrt(np.mean(d.astype(float) ** 2))
    assert np.abs(d).max() / rms < 2.0


def test_spec_round_trip_and_line_frequencies():
    ex = parse_excitation("odd-multisine:1024,63,20,5@3")
    assert ex == OddMultisine(1024, 63, 20, 5, 3, offset=3)
    assert parse_excitation(ex.describe()) == ex
    np.testing.assert_allclose(ex.line_frequencies(0.005, [1]), [2 * np.pi / (1024 * 0.005)], rtol=1e-15)


@pytest.mark.parametrize("kwargs, match", [
    ({"period": 1000}, "period must be a power of two"),
    ({"max_harmonic": 30}, "max_harmonic must be odd"),
    ({"max_harmonic": 2 * MAX_ODD_LINES + 1}, "max_harmonic must be at most"),
    ({"amplitude": 0}, "amplitude"),
    ({"group": 1}, "group must be 0"),
    ({"seed": 70000}, "seed"),
], ids=["period", "even-harmonic", "too-many-lines", "amplitude", "group", "seed"])
def test_bad_arguments_name_the_parameter(kwargs, match):
    with pytest.raises(ValueError, match=match):
        OddMultisine(**{"period": 1024, "max_harmonic": 63, "amplitude": 20, **kwargs})


def test_parse_refuses_a_wrong_number_of_fields():
    with pytest.raises(ValueError, match="odd-multisine takes PERIOD,MAX_HARMONIC,AMP"):
        parse_excitation("odd-multisine:1024,63")

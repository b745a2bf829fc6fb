"""The time column must agree with the declared sample period (jitter and drops allowed)."""
import numpy as np
import pytest

from motorsim import Experiment, Motor, Recording, RecordingFormatError, SimRig, Sine, read_recording, write_recording
from motorsim.recording import TIME_BASE_TOLERANCE


def _rec(scale=1.0, sample_period=0.005, jitter=0.0, drop_rate=0.0):
    rec = SimRig(Motor(25.0, 3.0), jitter=jitter, drop_rate=drop_rate, rng=np.random.default_rng(3)).run(
        Experiment(Sine(20.0), sample_period, 1.0))
    return Recording(time=rec.time * scale, duty=rec.duty, sample_period=sample_period, counts=rec.counts,
                     seq=rec.seq, counts_per_rev=rec.counts_per_rev)


def test_time_in_milliseconds_is_refused_with_both_figures(tmp_path):
    path = tmp_path / "ms.csv"
    rec = _rec()
    text = write_recording(rec, path).read_text(encoding="utf-8").splitlines()
    header = text.index("seq,time_s,duty,counts")
    rows = [r.split(",") for r in text[header + 1:]]
    path.write_text("\n".join(text[:header + 1] + [",".join([r[0], repr(float(r[1]) * 1000), *r[2:]])
                                                    for r in rows]) + "\n", encoding="utf-8")
    with pytest.raises(RecordingFormatError, match=r"ms\.csv: .*5 s per sample.*sample_period is 0\.005 s.*1000"):
        read_recording(path)


@pytest.mark.parametrize("scale", [10.0, 0.1, 1 + 1.5 * TIME_BASE_TOLERANCE, 1 - 1.5 * TIME_BASE_TOLERANCE])
def test_building_a_recording_with_a_wrong_time_base_is_refused(scale):
    with pytest.raises(ValueError, match="time and sample_period disagree"):
        _rec(scale)


def test_jitter_and_dropped_samples_are_within_the_tolerance():
    rec = _rec(jitter=0.95, drop_rate=0.5)
    assert rec.has_gaps and len(rec) > 50
    assert np.ptp(np.diff(rec.time)[np.diff(rec.seq) == 1]) > 0.5 * 0.005   # intervals really vary

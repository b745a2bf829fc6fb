"""Recording format v1: round trip, metadata rules, and every bad-file case."""
import dataclasses
import os

import numpy as np
import pytest

from motorsim import Experiment, Motor, Recording, RecordingFormatError, SimRig, Sine, read_recording, write_recording
from motorsim.sensors import Encoder


def _sim(**kw):
    rig = SimRig(Motor(25.0, 3.0), Encoder(16667, count_offset=-123, angle_noise=1e-4), jitter=0.1, drop_rate=0.05,
                 rng=np.random.default_rng(7), **kw)
    return rig.run(Experiment(Sine(20.0), 0.005, 1.0))


def test_round_trip_is_bit_exact(tmp_path):
    rec = _sim(record_speed=True)
    back = read_recording(write_recording(rec, tmp_path / "r.csv"))
    for name in ("time", "duty", "counts", "speed", "seq"):
        np.testing.assert_array_equal(getattr(back, name), getattr(rec, name), err_msg=name)
    assert back.sample_period == rec.sample_period and back.counts_per_rev == 16667
    assert dict(back.metadata) == dict(rec.metadata)
    assert back.has_gaps


def test_file_layout_matches_the_spec(tmp_path):
    rec = Recording(time=[0.0, 0.005], duty=[0, 12], sample_period=0.005, counts=[0, 3], counts_per_rev=16667)
    lines = write_recording(rec, tmp_path / "r.csv").read_text(encoding="utf-8").splitlines()
    assert lines == ["# motorid recording v1", "# sample_period: 0.005", "# counts_per_rev: 16667",
                     "seq,time_s,duty,counts", "0,0.0,0,0", "1,0.005,12,3"]


def test_reading_accepts_aliases_any_column_order_and_keeps_unknown_keys(tmp_path):
    p = tmp_path / "r.csv"
    p.write_text("# motorid recording v1\n# dt: 0.01\n# ppr: 400\n# operator: Ryo\n"
                 "counts,duty,time_s\n5,1.5,0.0\n9,-2.25,0.01\n12,0,0.02\n", encoding="utf-8")
    rec = read_recording(p)
    assert rec.sample_period == 0.01 and rec.counts_per_rev == 400
    assert rec.metadata["operator"] == "Ryo"
    assert rec.duty.tolist() == [1.5, -2.25, 0.0] and rec.seq.tolist() == [0, 1, 2]
    np.testing.assert_allclose(rec.measured_speed()[1:], np.array([4, 3]) * 2 * np.pi / 400 / 0.01)


def test_speed_only_recording_without_sample_period_uses_the_median_interval(tmp_path):
    p = tmp_path / "r.csv"
    p.write_text("time_s,duty,speed_rad_s\n0,1,0\n0.02,1,1\n0.04,1,2\n", encoding="utf-8")
    rec = read_recording(p)
    assert rec.sample_period == pytest.approx(0.02) and rec.speed.tolist() == [0, 1, 2]


def test_gaps_split_segments_and_break_differences():
    rec = Recording(time=[0, 1, 2, 4, 5], duty=[0] * 5, sample_period=1.0, angle=[0, 1, 3, 7, 8], seq=[0, 1, 2, 4, 5])
    assert [s.seq.tolist() for s in rec.segments()] == [[0, 1, 2], [4, 5]]
    np.testing.assert_array_equal(rec.measured_speed(), [np.nan, 1, 2, np.nan, 1])


def test_the_differenced_speed_is_kept_and_every_caller_gets_its_own_copy():
    rec = Recording(time=[0, 1, 2, 4, 5], duty=[0] * 5, sample_period=1.0, angle=[0, 1, 3, 7, 8], seq=[0, 1, 2, 4, 5])
    first = rec.measured_speed()
    first[1:3] = 99.0                     # a caller's own array: changing it changes nothing kept
    second = rec.measured_speed()
    np.testing.assert_array_equal(second, [np.nan, 1, 2, np.nan, 1])
    assert second is not first and second.flags.writeable
    # a recording made from it (another angle) differences its own
    other = dataclasses.replace(rec, angle=np.array([0, 2, 6, 14, 16.0]))
    np.testing.assert_array_equal(other.measured_speed(), [np.nan, 2, 4, np.nan, 2])


BAD = {
    "missing-time": ("seq,duty,counts\n0,0,0\n", "line 3: missing required column 'time_s'"),
    "missing-duty": ("time_s,counts\n0,0\n", "missing required column 'duty'"),
    "no-measurement": ("time_s,duty\n0,0\n", "at least one of the columns counts, angle_rad, speed_rad_s"),
    "non-numeric": ("time_s,duty,angle_rad\n0,0,0\n0.1,abc,0\n", "line 5: column 'duty' must be a number, got 'abc'"),
    "nan": ("time_s,duty,angle_rad\n0,0,0\n0.1,1,nan\n", "line 5: column 'angle_rad' must be finite"),
    "time-not-increasing": ("time_s,duty,angle_rad\n0,0,0\n0.1,1,0\n0.1,1,0\n",
                            "line 6: time_s must be strictly increasing, got 0.1 after 0.1"),
    "counts-without-cpr": ("time_s,duty,counts\n0,0,0\n0.1,0,1\n", "needs the metadata line '# counts_per_rev: N'"),
    "counts-not-integer": ("# counts_per_rev: 100\ntime_s,duty,counts\n0,0,0\n0.1,0,1.5\n",
                           "line 4: column 'counts' must be an integer, got '1.5'"),
    "short-row": ("time_s,duty,angle_rad\n0,0,0\n0.1,0\n", "line 5: expected 3 values, got 2"),
    "seq-backwards": ("time_s,duty,angle_rad,seq\n0,0,0,5\n0.1,0,0,4\n", "seq must be strictly increasing"),
    "bad-cpr": ("# counts_per_rev: -4\ntime_s,duty,counts\n0,0,0\n",
                "counts_per_rev must be a positive integer, got '-4'"),
    "bad-dt": ("# sample_period: zero\ntime_s,duty,angle_rad\n0,0,0\n",
               "sample_period must be a number > 0 s, got 'zero'"),
    "version": ("# motorid recording v2\ntime_s,duty,angle_rad\n0,0,0\n", "unsupported format 'motorid recording v2'"),
    "no-rows": ("time_s,duty,angle_rad\n", "no data rows"),
    "empty": ("", "no header row"),
    "duplicate-column": ("time_s,duty,duty,angle_rad\n0,0,0,0\n", "duplicate column names"),
}


@pytest.mark.parametrize("name", list(BAD), ids=list(BAD))
def test_bad_files_name_the_file_line_and_rule(tmp_path, name):
    text, message = BAD[name]
    p = tmp_path / f"{name}.csv"
    p.write_text(("# motorid recording v1\n# sample_period: 0.1\n" if not text.startswith("#") else "") + text
                 if name not in ("empty",) else text, encoding="utf-8")
    with pytest.raises(RecordingFormatError, match=str(p).replace("\\", "\\\\")) as info:
        read_recording(p)
    assert message in str(info.value)


def test_unreadable_and_non_utf8_files(tmp_path, monkeypatch):
    with pytest.raises(RecordingFormatError, match="missing.csv: cannot read: No such file"):
        read_recording(tmp_path / "missing.csv")
    with pytest.raises(RecordingFormatError, match="not a regular file .a directory"):
        read_recording(tmp_path)
    readable = write_recording(Recording(time=[0.0, 1.0], duty=[0, 1], sample_period=1.0, angle=[0.0, 1.0]),
                               tmp_path / "denied.csv")

    real_open = os.open

    def denied(path, *args, **kwargs):
        if os.fspath(path) == str(readable):
            raise PermissionError(13, "Permission denied", str(readable))
        return real_open(path, *args, **kwargs)
    monkeypatch.setattr(os, "open", denied)   # root reads any file: a refusal has to be simulated
    with pytest.raises(RecordingFormatError, match="denied.csv: cannot read: Permission denied"):
        read_recording(readable)
    monkeypatch.undo()
    p = tmp_path / "latin1.csv"
    p.write_bytes(b"time_s,duty,angle_rad\n0,0,\xe9\n")
    with pytest.raises(RecordingFormatError, match="not UTF-8"):
        read_recording(p)


@pytest.mark.parametrize("kwargs, match", [
    (dict(time=[0, 1], duty=[0, 0], sample_period=1.0), "at least one of counts, angle, speed"),
    (dict(time=[0, 1], duty=[0, 0], sample_period=1.0, counts=[0, 1]), "counts_per_rev must be a positive integer"),
    (dict(time=[0, 1], duty=[0], sample_period=1.0, angle=[0, 1]), "duty must have the same length as time"),
    (dict(time=[0, 1], duty=[0, 0], sample_period=-1.0, angle=[0, 1]), "sample_period must be > 0"),
    (dict(time=[1, 0], duty=[0, 0], sample_period=1.0, angle=[0, 1]), "time must be strictly increasing"),
    (dict(time=[0, 1], duty=[0, np.inf], sample_period=1.0, angle=[0, 1]), "duty must be finite"),
    (dict(time=[0, 1], duty=[0, 0], sample_period=1.0, counts=[0, 1.5], counts_per_rev=4), "counts must hold integers"),
], ids=["nothing", "cpr", "length", "dt", "time", "inf", "counts"])
def test_recording_validates_arrays(kwargs, match):
    with pytest.raises((ValueError, TypeError), match=match):
        Recording(**kwargs)


def test_recording_arrays_are_read_only():
    rec = Recording(time=[0.0, 1.0], duty=[0, 1], sample_period=1.0, angle=[0.0, 1.0])
    with pytest.raises(ValueError):
        rec.duty[0] = 5


def test_failed_write_leaves_no_file_behind(tmp_path):
    rec = Recording(time=[0.0, 1.0], duty=[0, 1], sample_period=1.0, angle=[0.0, 1.0], metadata={"a:b": "key"})
    with pytest.raises(ValueError, match="without ':'"):
        write_recording(rec, tmp_path / "r.csv")
    assert list(tmp_path.iterdir()) == []


def test_a_write_failing_after_the_temporary_file_exists_keeps_the_old_file(tmp_path, monkeypatch):
    import motorsim.writing as writing
    path = write_recording(Recording(time=[0.0, 1.0], duty=[0, 1], sample_period=1.0, angle=[0.0, 1.0]),
                           tmp_path / "r.csv")
    old = path.read_bytes()
    seen = []

    def failing_replace(src, dst):
        seen.append(src)
        assert (tmp_path / src).exists()        # the temporary file was written
        raise OSError(28, "No space left on device")
    monkeypatch.setattr(writing.os, "replace", failing_replace)
    with pytest.raises(OSError, match="No space left"):
        write_recording(Recording(time=[0.0, 2.0], duty=[0, 1], sample_period=2.0, angle=[0.0, 1.0]), path)
    assert seen and path.read_bytes() == old and sorted(tmp_path.iterdir()) == [path]


@pytest.mark.parametrize("name, new_module", [("read_recording", "motorsim.reading"),
                                              ("write_recording", "motorsim.writing"),
                                              ("RecordingWriter", "motorsim.writing")],
                         ids=["read_recording", "write_recording", "RecordingWriter"])
def test_moved_names_still_import_from_recording_with_a_warning(name, new_module):
    import importlib

    import motorsim.recording as recording
    with pytest.warns(DeprecationWarning, match=new_module):
        old = getattr(recording, name)
    assert old is getattr(importlib.import_module(new_module), name)


@pytest.mark.parametrize("offset", [0, 2 ** 62])
def test_measured_angle_of_rows_is_the_whole_columns_rows(offset):
    # rows converted alone give the same numbers as the whole column's rows, counts offset by 2**62
    # included (measured from the whole column's median, found once)
    counts = np.cumsum(np.random.default_rng(3).integers(-5, 9, size=1001)) + offset
    rec = Recording(time=np.arange(1001) * 0.01, duty=np.zeros(1001), sample_period=0.01, counts=counts,
                    counts_per_rev=400)
    whole = rec.measured_angle()
    for rows in (slice(0, 10), slice(300, 777), slice(990, None)):
        np.testing.assert_array_equal(rec.measured_angle(rows), whole[rows])
    assert np.all(np.abs(whole) < 1e4)                 # measured from the median: no bit lost

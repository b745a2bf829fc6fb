"""motorsim.RecordingWriter: incremental, always-readable, atomically finished recordings."""
from __future__ import annotations

import numpy as np
import pytest

from motorsim import Experiment, Motor, SimRig, Sine, read_recording
from motorsim.files import OutputFileError
from motorsim.writing import RecordingWriter


def _rec():
    return SimRig(Motor(25.0, 3.0)).run(Experiment(Sine(10.0), 0.005, 1.0))


def _write(writer, rec, stop=None):
    for s, t, u, c in list(zip(rec.seq, rec.time, rec.duty, rec.counts))[:stop]:
        writer.append(s, t, u, c)


def test_complete_file_reads_back_bit_for_bit(tmp_path):
    rec = _rec()
    w = RecordingWriter(tmp_path / "run.csv", rec.sample_period, rec.counts_per_rev, metadata={"source": "test"})
    _write(w, rec)
    path = w.close(True, metadata={"device_samples_sent": "200"})
    back = read_recording(path)
    for name in ("seq", "time", "duty", "counts"):
        assert np.array_equal(getattr(back, name), getattr(rec, name))
    assert back.metadata["complete"] == "true" and "incomplete_reason" not in back.metadata
    assert back.metadata["source"] == "test" and back.metadata["device_samples_sent"] == "200"
    assert not (tmp_path / "run.csv.partial").exists()


def test_partial_file_is_readable_while_recording_and_marked_incomplete(tmp_path):
    rec = _rec()
    w = RecordingWriter(tmp_path / "run.csv", rec.sample_period, rec.counts_per_rev, flush_interval=0.0)
    _write(w, rec, 120)
    partial = read_recording(tmp_path / "run.csv.partial")
    assert np.array_equal(partial.counts, rec.counts[:120]) and partial.metadata["complete"] == "false"
    assert not (tmp_path / "run.csv").exists()
    w.close(True)


def test_an_exception_or_ctrl_c_leaves_a_valid_incomplete_recording(tmp_path):
    rec = _rec()
    for exc, reason in ((RuntimeError("port vanished"), "RuntimeError: port vanished"),
                        (KeyboardInterrupt(), "interrupted (Ctrl-C)")):
        path = tmp_path / f"{type(exc).__name__}.csv"
        with pytest.raises(type(exc)):
            with RecordingWriter(path, rec.sample_period, rec.counts_per_rev) as w:
                _write(w, rec, 77)
                raise exc
        back = read_recording(path)
        assert len(back) == 77 and back.metadata["complete"] == "false"
        assert back.metadata["incomplete_reason"] == reason


def test_no_rows_writes_nothing(tmp_path):
    w = RecordingWriter(tmp_path / "run.csv", 0.005, 1000)
    assert w.close(False, "never started") is None and list(tmp_path.iterdir()) == []


def test_writer_rejects_rows_out_of_order_and_bad_settings(tmp_path):
    w = RecordingWriter(tmp_path / "run.csv", 0.005, 1000)
    w.append(3, 0.015, 0, 0)
    with pytest.raises(ValueError, match="strictly increasing"):
        w.append(3, 0.02, 0, 0)
    w.close(False, "abandoned")
    with pytest.raises(ValueError, match="counts_per_rev"):
        RecordingWriter(tmp_path / "x.csv", 0.005, 0)
    with pytest.raises(ValueError, match="sample_period"):
        RecordingWriter(tmp_path / "x.csv", -1.0, 10)
    with pytest.raises(OutputFileError, match="missing does not exist"):
        RecordingWriter(tmp_path / "missing" / "x.csv", 0.005, 10)

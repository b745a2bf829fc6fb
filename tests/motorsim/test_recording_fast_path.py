"""The fast reader (pyarrow) and the careful line-by-line parser give the same recording, bit for bit."""
import numpy as np
import pytest

import motorsim.reading as reading
from motorsim import Encoder, Experiment, Motor, RecordingFormatError, SimRig, Sine, read_recording, write_recording


@pytest.fixture(autouse=True)
def _fast_path_for_small_files(monkeypatch):
    # the fast path is taken only from FAST_PATH_MIN_BYTES on; these small files must take it too
    monkeypatch.setattr(reading, "FAST_PATH_MIN_BYTES", 0)


def test_a_small_file_is_read_without_importing_pyarrow(written, monkeypatch):
    monkeypatch.setattr(reading, "FAST_PATH_MIN_BYTES", 1 << 30)
    calls = []
    monkeypatch.setattr(reading, "_read_columns_fast", lambda *a: calls.append(1))
    rec, path = written
    back = read_recording(path)
    assert not calls
    np.testing.assert_array_equal(back.counts, rec.counts)


def _careful(monkeypatch):
    monkeypatch.setattr(reading, "_read_columns_fast", lambda *args: None)


@pytest.fixture
def written(tmp_path):
    rig = SimRig(Motor(25.0, 3.0), Encoder(count_offset=-(1 << 40), angle_noise=1e-3), jitter=0.3, drop_rate=0.05,
                 record_speed=True, rng=np.random.default_rng(4))
    rec = rig.run(Experiment(Sine(20.0), 0.005, 2.0))
    return rec, write_recording(rec, tmp_path / "r.csv")


def test_the_fast_path_is_taken_and_reads_back_bit_for_bit(written, monkeypatch):
    rec, path = written
    calls = []
    fast = reading._read_columns_fast
    monkeypatch.setattr(reading, "_read_columns_fast", lambda *a: calls.append(1) or fast(*a))
    back = read_recording(path)
    assert calls and back.counts is not None and back.counts.dtype == np.int64
    for name in ("time", "duty", "counts", "speed", "seq"):
        np.testing.assert_array_equal(getattr(back, name), getattr(rec, name), err_msg=name)
    assert dict(back.metadata) == dict(rec.metadata) and back.sample_period == rec.sample_period


def test_the_careful_parser_reads_the_same_recording(written, monkeypatch):
    rec, path = written
    fast = read_recording(path)
    _careful(monkeypatch)
    careful = read_recording(path)
    for name in ("time", "duty", "counts", "speed", "seq"):
        np.testing.assert_array_equal(getattr(fast, name), getattr(careful, name), err_msg=name)


@pytest.mark.parametrize("bad_row, match", [
    ("5,0.5,abc,7", r"line 19: column 'duty' must be a number"),
    ("5,0.5,1,7.5", r"line 19: column 'counts' must be an integer"),
    ("5,nan,1,7", r"line 19: column 'time_s' must be finite"),
    ("5,0.5,1", r"line 19: expected 4 values, got 3"),
    ("5,0.5,1,7,8", r"line 19: expected 4 values, got 5"),
], ids=["text", "fraction", "nan", "short", "long"])
def test_a_bad_row_still_gets_its_line_when_the_fast_path_fails(tmp_path, bad_row, match):
    lines = [reading.FORMAT_HEADER, "# sample_period: 0.1", "# counts_per_rev: 400", "seq,time_s,duty,counts"]
    rows = [f"{k},{k * 0.1!r},1,{k}" for k in range(30)]
    rows[14] = bad_row
    path = tmp_path / "bad.csv"
    path.write_text("\n".join(lines + rows) + "\n", encoding="utf-8")
    with pytest.raises(RecordingFormatError, match=match):
        read_recording(path)


def test_blank_lines_keep_the_line_numbers_of_an_implausible_row(tmp_path):
    lines = [reading.FORMAT_HEADER, "# sample_period: 0.1", "# counts_per_rev: 400", "seq,time_s,duty,counts"]
    rows = [f"{k},{k * 0.1!r},1,{k * 3}" for k in range(40)]
    rows[20] = f"20,2.0,1,{1 << 40}"
    path = tmp_path / "blank.csv"
    path.write_text("\n".join(lines + rows[:10] + ["", ""] + rows[10:]) + "\n", encoding="utf-8")
    with pytest.raises(RecordingFormatError, match=r"line 27: implausible sample \(seq 20\)"):
        read_recording(path)


@pytest.mark.parametrize("block_bytes", [64, 97, 4096])
def test_rows_cut_across_blocks_read_back_bit_for_bit(written, monkeypatch, block_bytes):
    # Rows are 30-60 bytes: 64 and 97 cut almost every block inside a row, whose start is carried over.
    rec, path = written
    monkeypatch.setattr(reading, "_FAST_BLOCK_BYTES", block_bytes)
    returned = []
    fast = reading._read_columns_fast
    monkeypatch.setattr(reading, "_read_columns_fast", lambda *a: returned.append(fast(*a)) or returned[-1])
    back = read_recording(path)
    assert returned and returned[0] is not None
    for name in ("time", "duty", "counts", "speed", "seq"):
        np.testing.assert_array_equal(getattr(back, name), getattr(rec, name), err_msg=name)


def test_a_row_longer_than_a_block_is_left_to_the_careful_parser(written, monkeypatch):
    rec, path = written
    monkeypatch.setattr(reading, "_FAST_BLOCK_BYTES", 16)
    returned = []
    fast = reading._read_columns_fast
    monkeypatch.setattr(reading, "_read_columns_fast", lambda *a: returned.append(fast(*a)) or returned[-1])
    back = read_recording(path)
    assert returned == [None]
    np.testing.assert_array_equal(back.counts, rec.counts)


def _rows_file(tmp_path, rows, name="rows.csv"):
    lines = [reading.FORMAT_HEADER, "# sample_period: 0.1", "# counts_per_rev: 400", "seq,time_s,duty,counts"]
    path = tmp_path / name
    path.write_text("\n".join(lines + rows) + "\n", encoding="utf-8")
    return path


def _fast_calls(monkeypatch):
    returned = []
    fast = reading._read_columns_fast
    monkeypatch.setattr(reading, "_read_columns_fast", lambda *a: returned.append(fast(*a)) or returned[-1])
    return returned


def test_a_nul_byte_past_the_head_is_named_by_its_line(tmp_path, monkeypatch):
    # only the head is searched for NUL bytes before parsing; the fast reader refuses one as a cell that is no number
    monkeypatch.setattr(reading, "_HEAD_BYTES", 256)
    rows = [f"{k},{k * 0.1!r},1,{k}" for k in range(200)]
    rows[150] = "150,15.0,1,\0" + "150"
    path = _rows_file(tmp_path, rows)
    returned = _fast_calls(monkeypatch)
    with pytest.raises(RecordingFormatError, match=r"rows\.csv, line 155: contains a NUL byte"):
        read_recording(path)
    assert returned == [None]


def test_rows_shorter_than_the_first_blocks_grow_the_columns(tmp_path, monkeypatch):
    # the columns are sized from the first block's bytes per row: later, shorter rows outgrow them
    monkeypatch.setattr(reading, "_FAST_BLOCK_BYTES", 4096)
    padded = "0" * 40 + "1"
    rows = [f"{k},{k * 0.1!r},{padded if k < 300 else 1},{k}" for k in range(3000)]
    path = _rows_file(tmp_path, rows)
    returned = _fast_calls(monkeypatch)
    fast = read_recording(path)
    assert returned[0] is not None
    _careful(monkeypatch)
    careful = read_recording(path)
    for name in ("time", "duty", "counts", "seq"):
        np.testing.assert_array_equal(getattr(fast, name), getattr(careful, name), err_msg=name)
    assert len(fast) == 3000


def test_blank_lines_are_read_by_the_fast_path(tmp_path, monkeypatch):
    rows = [f"{k},{k * 0.1!r},1,{k * 3}" for k in range(40)]
    path = _rows_file(tmp_path, rows[:10] + ["", "", "\r"] + rows[10:])
    returned = _fast_calls(monkeypatch)
    rec = read_recording(path)
    assert returned[0] is not None
    np.testing.assert_array_equal(rec.counts, np.arange(40) * 3)


@pytest.mark.parametrize("ending", ["\r", "\r\n"])
def test_carriage_returns_keep_the_line_numbers_of_an_implausible_row(tmp_path, ending):
    # a lone carriage return ends a line as a newline does; the line named is the careful parser's
    rows = [f"{k},{k * 0.1!r},1,{k * 3}" for k in range(40)]
    rows[20] = f"20,2.0,1,{1 << 40}"
    lines = [reading.FORMAT_HEADER, "# sample_period: 0.1", "# counts_per_rev: 400", "seq,time_s,duty,counts"]
    path = tmp_path / "cr.csv"
    path.write_bytes(("\n".join(lines + rows[:10]) + "\n" + ending.join(rows[10:]) + "\n").encode())
    with pytest.raises(RecordingFormatError, match=r"line 25: implausible sample \(seq 20\)"):
        read_recording(path)


def test_an_implausible_row_is_named_without_the_careful_parser(tmp_path, monkeypatch):
    rows = [f"{k},{k * 0.1!r},1,{k * 3}" for k in range(40)]
    rows[20] = f"20,2.0,1,{1 << 40}"
    path = _rows_file(tmp_path, rows)
    monkeypatch.setattr(reading, "_parse", lambda *a, **k: pytest.fail("the careful parser was asked"))
    with pytest.raises(RecordingFormatError, match=r"rows\.csv, line 25: implausible sample \(seq 20\)"):
        read_recording(path)


def test_a_plain_file_is_read_once(written, monkeypatch):
    # the head, then the rows block by block: no pass over the file before the parse
    rec, path = written
    passes = []
    blocks = reading._blocks
    monkeypatch.setattr(reading, "_blocks", lambda *a: passes.append(a) or blocks(*a))
    opened = []
    read_head = reading._read_head
    monkeypatch.setattr(reading, "_read_head", lambda p: opened.append(p) or read_head(p))
    back = read_recording(path)
    assert len(passes) == 1 and len(opened) == 1
    assert passes[0][2] == path.stat().st_size
    np.testing.assert_array_equal(back.counts, rec.counts)

"""Files that lie: each gets its own message naming the file and line, never a traceback or a wrong number."""
import numpy as np
import pytest

from motorsim import Recording, RecordingFormatError, read_recording, write_recording

GOOD = Recording(time=np.arange(40) * 0.005, duty=np.full(40, 100), sample_period=0.005,
                 counts=np.arange(40) * 3, counts_per_rev=16667)


def _text(tmp_path):
    return write_recording(GOOD, tmp_path / "good.csv").read_text(encoding="utf-8")


def _refused(tmp_path, data, match):
    path = tmp_path / "bad.csv"
    path.write_bytes(data if isinstance(data, bytes) else data.encode("utf-8"))
    with pytest.raises(RecordingFormatError, match=match):
        read_recording(path)


def test_a_torn_last_line_is_named_as_torn(tmp_path):
    text = _text(tmp_path)
    n_lines = text.count("\n")
    _refused(tmp_path, text[:-4], rf"bad\.csv, line {n_lines}: the last line is torn")


def test_a_last_line_with_its_newline_but_too_few_values_is_not_called_torn(tmp_path):
    text = _text(tmp_path)
    _refused(tmp_path, text + "40,0.2\n", r"line \d+: expected 4 values, got 2")


@pytest.mark.parametrize("cell, match", [("9" * 25, "must fit a 64-bit integer"),
                                         ("-9223372036854775809", "must fit a 64-bit integer"),
                                         ("1_000_000", r"must be a plain number \(no '_' digit separators\)")])
def test_counts_beyond_int64_and_digit_separators_are_refused(tmp_path, cell, match):
    lines = _text(tmp_path).splitlines()
    lines[10] = ",".join([*lines[10].split(",")[:3], cell])
    _refused(tmp_path, "\n".join(lines) + "\n", r"bad\.csv, line 11: column 'counts' " + match)


def test_the_largest_int64_count_is_kept(tmp_path):
    lines = _text(tmp_path).splitlines()
    header = lines.index("seq,time_s,duty,counts")
    rows = [f"{k},{k * 0.005!r},0,{(1 << 63) - 1}" for k in range(5)]
    path = tmp_path / "big.csv"
    path.write_text("\n".join(lines[:header + 1] + rows) + "\n", encoding="utf-8")
    assert read_recording(path).counts[0] == (1 << 63) - 1


def test_a_byte_order_mark_gets_its_own_message(tmp_path):
    _refused(tmp_path, b"\xef\xbb\xbf" + _text(tmp_path).encode(), r"line 1: starts with a UTF-8 byte-order mark")


def test_a_nul_byte_gets_its_own_message_with_its_line(tmp_path):
    text = _text(tmp_path)
    at = text.index("\n5,") + 2
    _refused(tmp_path, text[:at] + "\0" + text[at:], rf"line {text[:at].count(chr(10)) + 1}: contains a NUL byte")


def test_a_field_over_the_csv_limit_is_a_format_error(tmp_path):
    _refused(tmp_path, _text(tmp_path) + "1," + "9" * 200_000 + ",0,0\n", r"line \d+: not a CSV row: field larger")


@pytest.mark.parametrize("device", ["/dev/zero", "/dev/urandom", "/dev/null"])
def test_devices_are_refused_before_reading(device):
    with pytest.raises(RecordingFormatError, match="not a regular file"):
        read_recording(device)


def test_a_directory_is_refused(tmp_path):
    with pytest.raises(RecordingFormatError, match="not a regular file .a directory"):
        read_recording(tmp_path)


def test_a_file_over_the_size_limit_is_refused_without_reading_it(tmp_path, monkeypatch):
    import motorsim.reading as reading
    path = write_recording(GOOD, tmp_path / "r.csv")
    monkeypatch.setattr(reading, "MAX_RECORDING_BYTES", path.stat().st_size - 1)
    with pytest.raises(RecordingFormatError, match=f"{path.stat().st_size} bytes is over"):
        read_recording(path)

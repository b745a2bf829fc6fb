"""Foreign data in: columns, units, timing rule, text tables and MATLAB files (motorsim/columns.py)."""
import math

import numpy as np
import pytest

from motorsim.columns import ColumnSpec, ImportFormatError, import_recording, read_table
from motorsim.recording import Recording

recording_from_columns = Recording.from_columns


def test_units_convert_to_si_and_input_unit_is_kept():
    t_ms = np.arange(5) * 20.0
    rec = Recording.from_columns(time=t_ms, duty=[1, 1, 2, 2, 2], speed=[0, 60, 60, 120, 120], time_unit="ms",
                                 speed_unit="rpm", input_unit="%")
    assert rec.sample_period == 0.02
    np.testing.assert_allclose(rec.time, t_ms / 1000, rtol=1e-15)
    np.testing.assert_allclose(rec.speed, np.array([0, 60, 60, 120, 120]) * 2 * math.pi / 60, rtol=1e-15)
    assert rec.input_unit == "%" and rec.duty.tolist() == [1, 1, 2, 2, 2]


@pytest.mark.parametrize("unit,scale", [("rad", 1.0), ("deg", math.pi / 180), ("rev", 2 * math.pi)])
def test_angle_units(unit, scale):
    rec = recording_from_columns(time=[0, 1, 2], duty=[0, 0, 0], angle=[0, 1, 3], angle_unit=unit, time_unit="us")
    np.testing.assert_allclose(rec.angle, np.array([0, 1, 3]) * scale, rtol=1e-15)
    assert rec.sample_period == 1e-6


def test_angle_in_counts_becomes_counts():
    rec = recording_from_columns(time=[0, 0.01, 0.02], duty=[1, 1, 1], angle=[0, 10, 30], angle_unit="counts",
                                 counts_per_rev=100)
    assert rec.counts.tolist() == [0, 10, 30] and rec.angle is None
    np.testing.assert_allclose(rec.measured_speed()[1:], [2 * math.pi * 0.1 / 0.01, 2 * math.pi * 0.2 / 0.01])


def test_gaps_of_whole_periods_become_seq_gaps():
    rec = recording_from_columns(time=[0, 0.01, 0.02, 0.05, 0.06], duty=[0] * 5, speed=[0] * 5)
    assert rec.seq.tolist() == [0, 1, 2, 5, 6] and rec.has_gaps and "time_uniform" not in rec.metadata


def test_non_uniform_clock_is_kept_and_said():
    t = [0, 0.01, 0.017, 0.03, 0.04]
    with pytest.warns(UserWarning, match="not uniform"):
        rec = recording_from_columns(time=t, duty=[0] * 5, speed=[0] * 5)
    assert rec.time.tolist() == t and rec.metadata["time_uniform"] == "false"
    assert rec.seq.tolist() == [0, 1, 2, 3, 4]


def test_pandas_series_are_accepted():
    pd = pytest.importorskip("pandas")
    df = pd.DataFrame({"t": [0.0, 0.5, 1.0], "u": [1.0, 2.0, 3.0], "y": [0.0, 1.0, 2.0]})
    rec = Recording.from_columns(time=df["t"], duty=df["u"], speed=df["y"])
    assert rec.sample_period == 0.5 and rec.speed.tolist() == [0.0, 1.0, 2.0]


@pytest.mark.parametrize("kwargs,match", [
    ({"time": [0, 0.1, 0.1], "speed": [0, 0, 0]}, "strictly increasing.*sample 2"),
    ({"time": [0, 0.1, 0.2], "speed": [0, 0, 0], "speed_unit": "m/s"}, "speed_unit must be one of"),
    ({"time": [0, 0.1, 0.2]}, "at least one of speed, angle, counts"),
    ({"time": [0, 0.1, 0.2], "speed": [0, 0, 0], "sample_period": 0.2}, "sample_period must agree"),
    ({"time": [0.0], "speed": [0]}, "at least 2 samples"),
], ids=["time", "unit", "no-output", "period", "short"])
def test_refusals_name_the_rule(kwargs, match):
    duty = [0] * len(kwargs["time"])
    with pytest.raises(ValueError, match=match):
        recording_from_columns(duty=duty, **kwargs)


def test_column_spec():
    assert ColumnSpec.parse("time", "t") == ColumnSpec("time", "t", None)     # the file may state it
    assert ColumnSpec.parse("time", "2:µs") == ColumnSpec("time", 2, "µs")
    assert ColumnSpec.parse("speed", "w [x]:rev/s").column == "w [x]"
    with pytest.raises(ValueError, match="unit of the speed column must be one of"):
        ColumnSpec.parse("speed", "y:deg")


@pytest.mark.parametrize("text,sep", [
    ("t,u,y\n0,1,2\n0.1,1,3\n", ","), ("t\tu\ty\n0\t1\t2\n0.1\t1\t3\n", "\t"),
    ("# lab run\n% more\nt  u   y\n\n0  1  2\n0.1 1 3\n", " "), ("t;u;y\n0;1;2\n0.1;1;3\n", ";"),
    ('"t","u","y"\n0,1,2\n0.1,1,3\n', ","),
], ids=["csv", "tsv", "whitespace-comments", "semicolon", "quoted"])
def test_text_tables_with_header(tmp_path, text, sep):
    path = tmp_path / "lab.txt"
    path.write_text(text)
    table = read_table(path)
    assert table.names == ("t", "u", "y") and table.has_header
    np.testing.assert_array_equal(table.column(ColumnSpec("speed", "y", "rad/s")), [2, 3])


def test_text_table_without_header_by_index(tmp_path):
    path = tmp_path / "raw.dat"
    path.write_text("0 100 0\n5 100 12\n10 100 30\n")
    rec = import_recording(path, time="0:ms", input="1:duty", counts="2", counts_per_rev=1000)
    assert rec.sample_period == 0.005 and rec.counts.tolist() == [0, 12, 30] and rec.counts_per_rev == 1000


@pytest.mark.parametrize("text,kwargs,match", [
    ("t,u,y\n0,1,2\n0.1,1\n", {}, r"raw.csv, line 3: 2 cells where the header has 3"),
    ("t,u,y\n0,1,2\n0.1,1,abc\n", {}, r"raw.csv, line 3: column 'y' must hold a finite number, got 'abc'"),
    ("t,u,y\n0,1,2\n0.1,1,3\n", {"speed": "w"}, r"raw.csv: no column named 'w' for the speed \(columns: t, u, y"),
    ("t,u,y\n0,1,2\n0.1,1,3\n", {"speed": "5"}, r"column index 5 for the speed is out of range"),
    ("t,u,y\n0,1,2\n0,1,3\n", {}, r"raw.csv, line 3, column 't' \(time\): time must be strictly increasing"),
    ("t,u,y\n0,1,2\n0.1,1,3.5\n", {"speed": None, "counts": "y"}, r"need the encoder resolution"),
    ("t,u,y\n0,1,2\n0.1,1,3.5\n", {"speed": None, "counts": "y", "counts_per_rev": 10},
     r"raw.csv, line 3, column 'y' \(counts\): counts must be integers, got 3.5"),
    ("t,u,y\n", {}, r"raw.csv: a header but no data rows"),
], ids=["cells", "number", "name", "index", "time", "cpr", "counts", "empty"])
def test_file_refusals_name_file_line_column_and_rule(tmp_path, text, kwargs, match):
    path = tmp_path / "raw.csv"
    path.write_text(text)
    with pytest.raises(ImportFormatError, match=match):
        import_recording(path, **{"time": "t:s", "input": "u:duty", "speed": "y:rad/s", **kwargs})


def test_matlab_v5_vectors_and_matrix(tmp_path):
    from scipy import io
    t = np.arange(4) * 0.01
    io.savemat(tmp_path / "run.mat", {"t": t[:, None], "u": np.ones(4), "y": np.arange(4.0)})
    rec = import_recording(tmp_path / "run.mat", time="t:s", input="u:V", speed="y:rev/s")
    np.testing.assert_allclose(rec.speed, np.arange(4.0) * 2 * math.pi, rtol=1e-15)
    io.savemat(tmp_path / "matrix.mat", {"data": np.column_stack([t * 1000, np.ones(4), np.arange(4.0)])})
    rec = import_recording(tmp_path / "matrix.mat", time="0:ms", input="1:V", speed="2:deg/s")
    assert rec.sample_period == 0.01


def _fake_v73(path):
    """A MATLAB v7.3 file: HDF5 with MATLAB's 512-byte header (scipy refuses it as v7.3)."""
    header = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Mon Jan  1 00:00:00 2024 HDF5 schema 1.00 ."
    header = header.ljust(116) + b"\x00" * 8 + b"\x00\x02" + b"IM"
    path.write_bytes(header.ljust(512, b"\x00") + b"\x89HDF\r\n\x1a\n")


def test_matlab_v73_without_h5py_says_what_it_needs(tmp_path, monkeypatch):
    import sys
    monkeypatch.setitem(sys.modules, "h5py", None)     # as if h5py were not installed
    _fake_v73(tmp_path / "big.mat")
    with pytest.raises(ImportFormatError, match=r"big.mat: a MATLAB v7.3 \(HDF5\) file: reading it needs h5py"):
        read_table(tmp_path / "big.mat")


def test_matlab_v73_with_h5py(tmp_path):
    h5py = pytest.importorskip("h5py")
    path = tmp_path / "v73.mat"
    with h5py.File(path, "w", userblock_size=512) as f:
        f["t"] = (np.arange(3) * 0.1)[None, :]             # MATLAB's column vector, as HDF5 stores it
        f["u"] = np.ones((1, 3))
        f["y"] = np.arange(3.0)[None, :]
    with open(path, "r+b") as fh:
        fh.write(b"MATLAB 7.3 MAT-file".ljust(124) + b"\x00\x02IM")
    rec = import_recording(path, time="t:s", input="u:duty", speed="y:rad/s")
    assert rec.sample_period == 0.1 and rec.speed.tolist() == [0.0, 1.0, 2.0]


@pytest.mark.parametrize("quantity,name,unit", [
    ("time", "time_ms", "ms"), ("time", "t_us", "us"), ("speed", "speed_rpm", "rpm"), ("speed", "w_degs", "deg/s"),
    ("input", "u_pct", "%"), ("input", "u_V", "V"), ("angle", "theta_deg", "deg"), ("speed", "w [rad/s]", "rad/s"),
], ids=lambda x: str(x))
def test_a_unit_the_header_states_is_the_columns_unit(tmp_path, quantity, name, unit):
    from motorsim.columns import unit_in_name
    assert unit_in_name(quantity, name) == unit
    columns = {"time": "t", "input": "u", "speed": "y", quantity: name}
    if quantity == "angle":
        del columns["speed"]
    path = tmp_path / "lab.csv"
    path.write_text(f"{','.join(columns.values())}\n0,1,0\n1,1,1\n2,1,2\n")
    flags = {q: (c if c == name else f"{c}:{'duty' if q == 'input' else 's' if q == 'time' else 'rad/s'}")
             for q, c in columns.items() if c}
    with pytest.warns(UserWarning, match="the unit its header states"):
        rec = import_recording(path, **flags)
    assert (rec.input_unit if quantity == "input" else rec.speed_unit) == {
        "input": unit, "speed": unit, "time": "rad/s", "angle": {"deg": "deg/s"}.get(unit)}[quantity]


@pytest.mark.parametrize("quantity", ["speed", "input"])
def test_a_speed_or_input_column_without_a_unit_is_refused_with_the_units(tmp_path, quantity):
    # an rpm column read as rad/s without a word put b 9.55 times off; no default is safe
    path = tmp_path / "lab.csv"
    path.write_text("t,u,y\n0,1,0\n1,1,1\n2,1,2\n")
    flags = {"time": "t", "input": "u:V", "speed": "y:rpm", quantity: {"speed": "y", "input": "u"}[quantity]}
    units = "rad/s, deg/s, rpm, rev/s" if quantity == "speed" else "duty, V, %"
    with pytest.raises(ImportFormatError, match=f"the {quantity} column .* has no unit and the file does not "
                                                f"state one: give --{quantity} .*:UNIT with UNIT one of {units}"):
        import_recording(path, **flags)


def test_every_column_problem_is_said_in_one_message(tmp_path):
    path = tmp_path / "lab.csv"
    path.write_text("t,pwm,rpm\n0,10,0\n1,10,1\n2,10,2\n")
    with pytest.raises(ImportFormatError) as info:
        import_recording(path, time="t", input="pwm", speed="speed", angle="theta:furlong")
    text = str(info.value)
    assert text.startswith(f"{path}: 4 problems with the columns: (1) ")
    assert "the unit of the angle column must be one of" in text            # (1) a unit that is none
    assert "the input column 'pwm' has no unit" in text                     # (2) nothing states it
    assert "no column named 'speed' for the speed" in text                  # (3) a name not in the file
    assert "the time column 't' has no unit" in text and "in doubt" in text  # (4) intervals of 1: s, ms, us?


def test_a_speed_in_rpm_is_kept_as_the_recordings_speed_unit(tmp_path):
    path = tmp_path / "lab.csv"
    path.write_text("t,pwm,rpm\n0,50,0\n10,50,1500\n20,50,3000\n")
    rec = import_recording(path, time="t:ms", input="pwm:%", speed="rpm:rpm")
    assert rec.speed_unit == "rpm" and rec.input_unit == "%"
    np.testing.assert_allclose(rec.speed, [0, 50 * math.pi, 100 * math.pi], rtol=1e-15)   # stored in rad/s


def _crashing_mat_bytes() -> bytes:
    """A MATLAB v5 file with one byte changed (offset 177, a variable's tag) on which scipy's compiled
    reader crashes the interpreter (a bus error or segmentation fault in scipy 1.17)."""
    import io as bytes_io

    from scipy import io
    buffer = bytes_io.BytesIO()
    t = np.arange(200) * 0.005
    io.savemat(buffer, {"t": t, "u": np.round(100 * np.sin(10 * t)), "y": np.sin(t)})
    raw = bytearray(buffer.getvalue())
    raw[177] = 101
    return bytes(raw)


def test_a_mat_file_that_crashes_scipys_reader_is_refused_not_fatal(tmp_path):
    import subprocess
    import sys
    path = tmp_path / "bad.mat"
    path.write_bytes(_crashing_mat_bytes())
    # reference: the same file read by scipy in this interpreter ends it by a signal
    probe = subprocess.run([sys.executable, "-c", "import io, sys, scipy.io; "
                            "scipy.io.loadmat(io.BytesIO(open(sys.argv[1], 'rb').read()))", str(path)],
                           capture_output=True, timeout=120)
    if probe.returncode >= 0:
        pytest.skip(f"this scipy reads the file without crashing (exit {probe.returncode})")
    # the crash reads memory past the data, so it is not certain on every read: refused either way
    with pytest.raises(ImportFormatError, match=r"bad\.mat: a damaged (MATLAB \.mat file: scipy's reader crashed "
                                                r"on it \(signal \d+\)|or truncated MATLAB \.mat file)"):
        read_table(path)


def test_a_mat_files_reader_error_and_hdf5_come_back_from_the_child(tmp_path, monkeypatch):
    truncated = tmp_path / "cut.mat"
    good = _crashing_mat_bytes()[:177] + b"\x00" * 3
    truncated.write_bytes(good)
    with pytest.raises(ImportFormatError, match="damaged or truncated MATLAB .mat file scipy cannot read"):
        read_table(truncated)
    pytest.importorskip("h5py")
    v73 = tmp_path / "v73.mat"
    v73.write_bytes(b"MATLAB 7.3 MAT-file".ljust(116, b" ") + b"\x00" * 8 + b"\x00\x02IM" + b"\x00" * 512)
    with pytest.raises(ImportFormatError, match=r"v73.mat: a damaged MATLAB v7.3 \(HDF5\) file h5py cannot read"):
        read_table(v73)


@pytest.mark.parametrize("fault, said", [("crash", r"crashed on it \(signal 11\)"),
                                         ("hang", r"crashed on it \(no answer in 0.5 s\)")])
def test_a_reader_that_dies_or_hangs_in_its_child_is_refused(tmp_path, monkeypatch, fault, said):
    # deterministic: scipy's reader replaced by one that dies by SIGSEGV or never answers (the child
    # is forked, so it runs the replacement); the real crash above depends on memory contents
    import os
    import signal
    import time

    from scipy import io

    from motorsim import mat_files
    if "fork" not in __import__("multiprocessing").get_all_start_methods():
        pytest.skip("needs fork to hand the child a replaced reader")

    def broken(*args, **kwargs):
        if fault == "crash":
            os.kill(os.getpid(), signal.SIGSEGV)
        time.sleep(60)
    monkeypatch.setattr(io, "loadmat", broken)
    monkeypatch.setattr(mat_files, "MAT_READ_SECONDS", 0.5)
    path = tmp_path / "run.mat"
    path.write_bytes(_crashing_mat_bytes())
    with pytest.raises(ImportFormatError, match=said):
        read_table(path)

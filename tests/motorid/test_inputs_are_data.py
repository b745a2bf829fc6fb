"""Hostile inputs of the fourth round: what a file holds is data, never instructions to the terminal or the machine.

Each case ran as a user would run it (``motorid.cli.main`` or the ``motorid`` command); each failed before the
change it tests (text reaching the terminal raw, a traceback, a file of the machine read, memory without bound,
a wrong number with exit 0) and now ends in a right answer or one ``motorid: error:`` line naming the parameter,
the rule and the value.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from motorid.cli import main
from motorsim import Experiment, Motor, SimRig, Sine, write_recording

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def rec_path(tmp_path_factory):
    path = tmp_path_factory.mktemp("rec") / "r.csv"
    write_recording(SimRig(Motor(25.0, 3.0)).run(Experiment(Sine(10.0, 200), 0.005, 4.0)), path)
    return path


@pytest.fixture(scope="module")
def model_doc(rec_path, tmp_path_factory):
    path = tmp_path_factory.mktemp("model") / "m.json"
    assert main(["identify", str(rec_path), "--save", str(path)]) == 0
    return json.loads(path.read_text())


def _error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert err and err[-1].startswith("motorid: error:"), err
    return err[-1]


def _raw_controls(text: str) -> set[str]:
    return {c for c in text if (ord(c) < 32 and c not in "\n\t") or 0x7f <= ord(c) <= 0x9f
            or 0xd800 <= ord(c) <= 0xdfff}


# --- control characters from a file never reach the terminal raw ---------------------------------------

@pytest.mark.parametrize("where, text", [
    ("units.input", "\x1b]0;owned\x07\x1b[2Jduty"),          # retitles and clears a terminal
    ("units.input", "duty\nmotorid: error: forged"),         # forges a line
    ("units.speed", "rad/s\udc80"),                         # a lone surrogate: an encoding error when printed
    ("input_unit", "du\ud800ty"),
    ("notes", "fit \r overwritten"),
])
def test_a_model_whose_text_holds_control_characters_is_refused_in_one_printable_line(model_doc, tmp_path, where,
                                                                                    text, capsys):
    doc = json.loads(json.dumps(model_doc))
    if where.startswith("units."):
        doc["units"][where.split(".")[1]] = text
    elif where == "notes":
        doc["notes"] = [*doc.get("notes", []), text]
    else:
        doc[where] = text
    path = tmp_path / "m.json"
    path.write_text(json.dumps(doc))
    assert main(["control", "design", "--model", str(path), "--controller", "pi"]) == 2
    out, err = capsys.readouterr()
    line = err.strip().splitlines()[-1]
    assert line.startswith(f"motorid: error: --model {path}: not a saved model: an estimate's text must be printable")
    assert not _raw_controls(out + err) and "forged" not in out


def test_a_recordings_metadata_with_an_escape_sequence_is_printed_escaped(rec_path, tmp_path, capsys):
    text = rec_path.read_text().replace("# sample_period:", "# input_unit: \x1b[2J\x1b]0;owned\x07duty\n"
                                        "# sample_period:", 1)
    path = tmp_path / "esc.csv"
    path.write_text(text)
    main(["identify", str(path)])
    out, err = capsys.readouterr()
    assert "\\x1b[2J" in out + err                 # said, made visible
    assert not _raw_controls(out + err)            # before: the terminal was cleared and retitled


def test_a_column_name_with_an_escape_sequence_is_printed_escaped(tmp_path, capsys):
    path = tmp_path / "lab.csv"
    path.write_text("t,u\x1b[2J,y\n0,1,0\n0.01,1,0.1\n0.02,1,0.2\n")
    assert main(["import", str(path), "--time", "t", "--input", "nothing:duty", "--speed", "y:rad/s",
                 "--out", str(tmp_path / "o.csv")]) == 2
    line = _error(capsys)
    assert "u\\x1b[2J" in line and "\x1b" not in line


def test_a_warning_holding_a_newline_stays_one_line(capsys):
    import warnings

    from motorid.cli import _show_warning
    _show_warning(warnings.WarningMessage("one\nmotorid: error: forged", UserWarning, "f", 1).message,
                  UserWarning, "f", 1)
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("motorid: warning: one motorid: error: forged")


# --- a locale without UTF-8 -------------------------------------------------------------------------------

@pytest.mark.parametrize("argv", [["design", "--a", "25", "--b", "3", "--sample-period", "0.005",
                                   "--counts-per-rev", "1000", "--no-plots", "--out", "{tmp}/d"],
                                  ["control", "design", "--a", "25", "--b", "3", "--controller", "pi"]])
def test_commands_print_under_an_ascii_locale(argv, tmp_path):
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONIOENCODING", "PYTHONUTF8", "LANG", "LC_CTYPE")}
    env.update(LC_ALL="C", PYTHONUTF8="0", PYTHONPATH=str(ROOT))
    done = subprocess.run([sys.executable, "-m", "motorid", *[a.format(tmp=tmp_path) for a in argv]],
                          capture_output=True, env=env, timeout=600)
    # before: "internal error: UnicodeEncodeError: 'ascii' codec can't encode character '\xe9'", exit 1
    assert done.returncode == 0, done.stderr.decode("ascii", "replace")
    assert done.stdout.isascii() and done.stderr.isascii() and b"Error" not in done.stderr


# --- a .mat file: only the file named is read, in a memory the file can honestly fill ------------------------

_V73_HEADER = (b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Mon Jan  1 00:00:00 2024 HDF5 schema 1.00 ."
               .ljust(116) + b"\x00" * 8 + b"\x00\x02IM")


def _v73(path, fill):
    """A MATLAB v7.3 file (HDF5 behind MATLAB's 512-byte header) with t, u and what ``fill`` adds."""
    h5py = pytest.importorskip("h5py")
    import numpy as np
    with h5py.File(path, "w", userblock_size=512) as f:
        f["t"] = (np.arange(100) * 0.01)[None, :]
        f["u"] = np.ones((1, 100))
        fill(f, h5py, np)
    with open(path, "r+b") as f:
        f.write(_V73_HEADER)
    return path


def _import(path, out):
    return main(["import", str(path), "--time", "t", "--input", "u:duty", "--speed", "y:rad/s", "--out", str(out)])


def test_a_mat_variable_linked_to_another_file_is_refused_not_followed(tmp_path, capsys):
    import numpy as np
    h5py = pytest.importorskip("h5py")
    with h5py.File(tmp_path / "other.h5", "w") as g:
        g["data"] = (np.arange(100.0) * 7)[None, :]
    path = _v73(tmp_path / "link.mat", lambda f, h5py, np: f.__setitem__(
        "y", h5py.ExternalLink(str(tmp_path / "other.h5"), "/data")))
    # before: exit 0, the other file's values copied into the recording
    assert _import(path, tmp_path / "o.csv") == 2
    line = _error(capsys)
    assert "the variable 'y' is a link to another file" in line and "reads only the file it is given" in line
    assert not (tmp_path / "o.csv").exists()


def test_a_mat_variable_stored_in_another_file_is_refused_not_read(tmp_path, capsys):
    import numpy as np
    secret = tmp_path / "secret.bin"
    secret.write_bytes(np.arange(100, dtype="<f8").tobytes())
    path = _v73(tmp_path / "external.mat", lambda f, h5py, np: f.create_dataset(
        "y", shape=(100, 1), dtype="<f8", external=[(str(secret), 0, 800)]))
    assert _import(path, tmp_path / "o.csv") == 2              # before: exit 0, the secret file's bytes imported
    line = _error(capsys)
    assert "the variable 'y' keeps its values in another file" in line and "external storage" in line


def test_a_mat_virtual_dataset_over_another_file_is_refused(tmp_path, capsys):
    import numpy as np
    h5py = pytest.importorskip("h5py")
    with h5py.File(tmp_path / "other.h5", "w") as g:
        g["data"] = np.arange(100.0)

    def fill(f, h5py, np):
        layout = h5py.VirtualLayout(shape=(100,), dtype="<f8")
        layout[:] = h5py.VirtualSource(str(tmp_path / "other.h5"), "data", shape=(100,))
        f.create_virtual_dataset("y", layout)
    assert _import(_v73(tmp_path / "virtual.mat", fill), tmp_path / "o.csv") == 2
    assert "virtual dataset" in _error(capsys)


def test_a_v73_decompression_bomb_is_refused_by_its_claimed_size(tmp_path, capsys):
    # 4 kB of file claiming 2.4 GB of zeros (chunks never written: the fill value); before: 7 GB of memory
    path = _v73(tmp_path / "bomb.mat", lambda f, h5py, np: f.create_dataset(
        "y", shape=(1, 300_000_000), dtype="<f8", chunks=(1, 1 << 20), compression="gzip"))
    assert _import(path, tmp_path / "o.csv") == 2
    line = _error(capsys)
    assert "the variable 'y' claims 1x300000000 values of 8 bytes" in line and "decompression bomb" in line


def _v5_bomb(path, n_values, dims):
    """A v5 .mat file: t and u, then a compressed double variable y of ``dims`` holding ``n_values`` zeros."""
    import io
    import struct
    import zlib

    import numpy as np
    import scipy.io as sio

    def tag(kind, n):
        return struct.pack("<II", kind, n)
    body = (tag(6, 8) + struct.pack("<II", 6, 0) + tag(5, 8) + struct.pack("<ii", *dims)
            + struct.pack("<HH", 1, 1) + b"y\0\0\0" + tag(9, 8 * n_values))
    deflate = zlib.compressobj(6)
    parts = [deflate.compress(tag(14, len(body) + 8 * n_values) + body)]
    zeros = bytes(1 << 22)
    for start in range(0, 8 * n_values, len(zeros)):
        parts.append(deflate.compress(zeros[:min(len(zeros), 8 * n_values - start)]))
    packed = b"".join(parts) + deflate.flush()
    head = io.BytesIO()
    sio.savemat(head, {"t": np.arange(100) * 0.01, "u": np.ones(100)}, do_compression=True)
    path.write_bytes(head.getvalue() + tag(15, len(packed)) + packed)
    return path


@pytest.mark.parametrize("dims", [(1, 12_000_000), (1, 100)], ids=["claimed", "understated"])
def test_a_v5_decompression_bomb_is_refused_before_it_is_unpacked(tmp_path, dims, capsys):
    # 96 MB of zeros packed into about 100 kB: more than 32 x the file and the 64 MiB any file may unpack to
    path = _v5_bomb(tmp_path / "bomb.mat", 12_000_000, dims)
    assert path.stat().st_size < 200_000
    assert _import(path, tmp_path / "o.csv") == 2
    line = _error(capsys)
    assert "the variable 'y'" in line and "decompression bomb" in line and str(path) in line


def test_an_honest_compressed_mat_file_still_reads(tmp_path):
    import numpy as np
    import scipy.io as sio

    from motorsim import read_recording
    rng = np.random.default_rng(1)
    n = 200_000
    t = np.arange(n) * 1e-3
    sio.savemat(tmp_path / "run.mat", {"t": t, "u": np.where(t > 1, 100.0, 0.0),
                                       "y": np.round(100 * (1 - np.exp(-np.maximum(t - 1, 0))) + rng.normal(size=n))},
                do_compression=True)
    assert _import(tmp_path / "run.mat", tmp_path / "o.csv") == 0
    assert len(read_recording(tmp_path / "o.csv")) == n


# --- robot logs: damaged records, sparse files, FIFOs ------------------------------------------------------

def _wpilog(path, n=400):
    wpiutil = pytest.importorskip("wpiutil", reason="robotpy-wpiutil (the wpilib extra) is not installed")
    from wpiutil.log import DoubleLogEntry
    log = wpiutil.DataLogWriter(str(path))
    volts = DoubleLogEntry(log, "voltage-drive", "Volt", 1_000_000)
    speed = DoubleLogEntry(log, "velocity-drive", "Rotation per Second", 1_000_000)
    for k in range(n):
        volts.append(2.0 if k > 50 else 0.0, 1_000_000 + 5000 * k)
        speed.append(0.1 * k, 1_000_000 + 5000 * k)
    log.flush()
    log.stop()
    return path


def _records(data: bytes):
    """(offset, entry, payload size, header length) of each record of a .wpilog's bytes."""
    pos = 12 + int.from_bytes(data[8:12], "little")
    while pos < len(data):
        h = data[pos]
        n_entry, n_size, n_time = (h & 3) + 1, ((h >> 2) & 3) + 1, ((h >> 4) & 7) + 1
        entry = int.from_bytes(data[pos + 1:pos + 1 + n_entry], "little")
        size = int.from_bytes(data[pos + 1 + n_entry:pos + 1 + n_entry + n_size], "little")
        yield pos, entry, size, n_entry
        pos += 1 + n_entry + n_size + n_time + size


def _import_log(path, out):
    return main(["import", str(path), "--time", "time_s", "--input", "voltage-drive", "--speed", "velocity-drive",
                 "--out", str(out)])


def test_a_wpilog_record_shorter_than_its_type_is_refused_naming_the_byte(tmp_path, capsys):
    data = bytearray(_wpilog(tmp_path / "good.wpilog").read_bytes())
    pos, _, _, n_entry = [r for r in _records(bytes(data)) if r[1] != 0][300]
    data[pos + 1 + n_entry] = 4                                  # a double's record now says 4 bytes
    (tmp_path / "short.wpilog").write_bytes(bytes(data))
    # before: "internal error: TypeError: not a double", exit 1
    assert _import_log(tmp_path / "short.wpilog", tmp_path / "o.csv") == 2
    assert _error(capsys).endswith(f"byte {pos}: the record of 'voltage-drive' (double) holds 4 bytes, a double "
                                   "holds 8; a damaged log")


@pytest.mark.parametrize("cut", ["3 bytes short", "length past the end"])
def test_a_wpilog_cut_inside_its_last_record_keeps_the_rest_and_says_so(tmp_path, cut, capsys):
    from motorsim import read_recording
    data = bytearray(_wpilog(tmp_path / "good.wpilog").read_bytes())
    if cut == "3 bytes short":
        data = data[:-3]
    else:
        pos, _, _, n_entry = list(_records(bytes(data)))[-1]
        data[pos + 1 + n_entry] = 200
    (tmp_path / "cut.wpilog").write_bytes(bytes(data))
    assert _import_log(tmp_path / "cut.wpilog", tmp_path / "o.csv") == 0
    assert "the log ends inside a record" in capsys.readouterr().err     # before: 399 of 400 rows, unsaid
    assert len(read_recording(tmp_path / "o.csv")) == 399


def test_a_sparse_wpilog_is_refused_at_once(tmp_path, capsys):
    head = _wpilog(tmp_path / "good.wpilog").read_bytes()[:200]
    for size in (1_200_000_000, 200_000_000):          # over the size a log may have; a file of zeros under it
        path = tmp_path / f"sparse{size}.wpilog"
        with open(path, "wb") as f:
            f.write(head)
            f.truncate(size)                            # a hole: no disk used
        assert _import_log(path, tmp_path / "o.csv") == 2   # before: over a minute and a half, then SIGTERM
        line = _error(capsys)
        assert ("over the 268435456 bytes it may have" in line if size > 268435456
                else "a control record with no payload" in line)


@pytest.mark.parametrize("name", ["x.wpilog", "x.mcap", "x.db3", "x.mat", "x.csv"])
def test_a_fifo_given_as_a_file_is_refused_not_waited_on(tmp_path, name, capsys):
    path = tmp_path / name
    os.mkfifo(path)
    if name.endswith(".csv"):
        argv = ["identify", str(path)]
    else:
        argv = ["import", str(path), "--time", "t", "--input", "u:duty", "--speed", "y:rad/s",
                "--out", str(tmp_path / "o.csv")]
    assert main(argv) == 2
    assert "FIFO" in _error(capsys)


# --- numbers: every flag bounded, no result that silently degenerates --------------------------------------

@pytest.mark.parametrize("flags, said", [
    (["--controller", "mpc", "--duty-weight", "1e14"], "--duty-weight 1e+14"),
    (["--controller", "lqr", "--duty-weight", "1e14"], "--duty-weight 1e+14"),
    (["--controller", "position", "--time-constant", "1e14"], "--time-constant 1e+14"),
])
def test_a_tuning_that_leaves_no_feedback_is_refused(flags, said, capsys):
    # before: exit 0 with every gain 0, "closed-loop poles: none (no feedback ...)" (at 1e308 too, now past the
    # bound of every number flag)
    assert main(["control", "design", "--a", "25", "--b", "3", *flags]) == 2
    line = _error(capsys)
    assert "the design has no feedback, every gain on the measurement is 0" in line and said in line


def test_the_designs_with_their_defaults_keep_their_feedback(capsys):
    for kind in ("mpc", "lqr", "lqr-integral", "lqr-position", "pi", "position"):
        assert main(["control", "design", "--a", "25", "--b", "3", "--controller", kind]) == 0
    assert "no feedback" not in capsys.readouterr().out


@pytest.mark.parametrize("argv, said", [
    (["simulate", "--a", "25", "--b", "3", "--initial-speed", "1e308"], "initial_speed must be within +-1e+12"),
    (["simulate", "--a", "25", "--b", "3", "--angle-noise", "1e308"], "angle_noise must be within +-1e+12"),
    (["simulate", "--a", "25", "--b", "3", "--count-offset", str(2**62)], "counts must stay within +-2**53"),
    (["simulate", "--a", "25", "--b", "3", "--counts-per-rev", "1e308"],      # before: a 309-digit integer said
     "counts_per_rev must be an integer, got '1e308'"),
    (["control", "design", "--a", "25", "--b", "3", "--controller", "pi", "--duration", "1e308"],
     "--duration must be a finite number within +-1e+15"),
])
def test_a_number_flag_past_any_bench_is_refused(tmp_path, argv, said, capsys):
    out = ["--duration", "1", "--out", str(tmp_path / "s.csv")] if argv[0] == "simulate" else []
    # before: exit 0 with counts of -9223372036854775808 (INT64_MIN) in the recording
    try:
        status = main([*argv, *out])
    except SystemExit as stop:         # refused where the flag is parsed
        status = stop.code
    assert status == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert said in err and len(err) < 300
    assert not (tmp_path / "s.csv").exists()


def test_robust_draws_are_bounded_and_the_seed_is_checked(model_doc, tmp_path, capsys):
    path = tmp_path / "m.json"
    path.write_text(json.dumps(model_doc))
    base = ["control", "design", "--model", str(path), "--controller", "pi", "--robust"]
    # before: hours of work (100 draws took 34 s here)
    assert main([*base, "--repetitions", "100000"]) == 2
    assert "--repetitions must be in 1...1000, got 100000" in _error(capsys)
    with pytest.raises(SystemExit) as stop:       # before: "internal error: ValueError: expected non-negative integer"
        main([*base, "--seed", "-1"])
    assert stop.value.code == 2
    assert "--seed must be an integer >= 0, got '-1'" in capsys.readouterr().err


# --- silent: read-only outputs, spreadsheet errors, pauses -------------------------------------------------

@pytest.mark.parametrize("argv, flag", [(["identify", "{rec}", "--save", "{out}.json"], "--save"),
                                        (["simulate", "--a", "25", "--b", "3", "--out", "{out}.csv"], "--out")])
def test_a_read_only_output_is_refused_not_replaced(rec_path, tmp_path, argv, flag, capsys):
    ext = ".json" if flag == "--save" else ".csv"
    out = tmp_path / f"kept{ext}"
    out.write_text("the user's own\n")
    out.chmod(0o444)
    # before: replaced without a word (os.replace needs only the folder's permission)
    assert main([a.format(rec=rec_path, out=tmp_path / "kept") for a in argv]) == 2
    line = _error(capsys)
    assert line.startswith(f"motorid: error: {flag} {out}: it is read-only (mode 0444)")
    assert out.read_text() == "the user's own\n"


@pytest.mark.parametrize("cell", ["#N/A", "#DIV/0!", "#VALUE!"])
def test_a_spreadsheet_error_row_is_refused_not_skipped_as_a_comment(tmp_path, cell, capsys):
    path = tmp_path / "lab.csv"
    path.write_text(f"# exported\nt,u_duty,y_rad_s\n0,1,0\n0.01,1,0.1\n{cell},{cell},{cell}\n0.02,1,0.2\n")
    # before: exit 0, the row dropped as a comment and 3 samples written without a word
    assert main(["import", str(path), "--time", "t", "--input", "u_duty", "--speed", "y_rad_s",
                 "--out", str(tmp_path / "o.csv")]) == 2
    assert f"line 5: column 't' must hold a finite number, got '{cell}' (a spreadsheet's error value" in _error(capsys)


def test_an_hours_pause_is_said_and_read_as_two_segments(tmp_path, capsys):
    from motorsim import read_recording
    rows = ["t,u_duty,y_rad_s"] + [f"{k * 0.01 + (3600 if k >= 150 else 0):.2f},100,{k * 0.001:.4f}"
                                   for k in range(300)]
    (tmp_path / "pause.csv").write_text("\n".join(rows) + "\n")
    assert main(["import", str(tmp_path / "pause.csv"), "--time", "t", "--input", "u_duty", "--speed", "y_rad_s",
                 "--out", str(tmp_path / "o.csv")]) == 0
    # before: nothing said of the 360 000 periods between the two halves
    assert ("1 gap(s), 360000 sample periods of 0.01 s with no row, the longest 3600 s after t = 1.49 s: read as 2 "
            "segments") in capsys.readouterr().err
    assert [len(s) for s in read_recording(tmp_path / "o.csv").segments()] == [150, 150]


@pytest.mark.parametrize("make, said", [(os.mkfifo, "not a regular file (a FIFO (named pipe))"),
                                        (lambda p: Path(p).write_text('name = "x\\u001b[2J\\nforged"\n'),
                                         "name must be printable text, got 'x\\x1b[2J\\nforged'")])
def test_a_scenario_that_is_a_fifo_or_names_itself_with_escapes_is_refused(tmp_path, make, said, capsys):
    path = tmp_path / "s.toml"
    make(path)
    # before: "an existing .toml file, got 's.toml'" for a FIFO that exists; the name printed raw in the table
    assert main(["sweep", str(path), "--out", str(tmp_path / "out")]) == 2
    assert said in _error(capsys)


def test_control_design_states_the_feedforward_of_the_friction_and_bias_it_was_given(capsys):
    # before: "feedforward kS 0 duty ... k0 -0 duty" whatever --friction and --bias said
    assert main(["control", "design", "--a", "25", "--b", "3", "--friction", "5", "--bias", "2",
                 "--controller", "pi"]) == 0
    line = next(s for s in capsys.readouterr().out.splitlines() if s.startswith("feedforward kS"))
    # closed form: kS = c / b = 5/3, kV = a / b = 25/3, kA = 1 / b, k0 = -d / b = -2/3
    assert line.startswith("feedforward kS 1.667 duty, kV 8.333 duty/(rad/s), kA 0.3333 duty/(rad/s^2), "
                           "k0 -0.6667 duty"), line


@pytest.mark.parametrize("value", ["nan", "-1", "1e308", "abc"])
def test_a_recordings_input_limit_that_is_no_magnitude_is_refused(rec_path, tmp_path, value, capsys):
    path = tmp_path / "r.csv"
    path.write_text(rec_path.read_text().replace("# sample_period:", f"# input_limit: {value}\n# sample_period:", 1))
    # before: taken as unknown, exit 0, the checks of a run at its limit silently off
    assert main(["identify", str(path)]) == 2
    assert f"metadata input_limit must be a number > 0 (the largest input magnitude the drive accepts) or none, got " \
           f"'{value}'" in _error(capsys)

"""More hostile cases of the fourth round, written from the rules rather than from reported cases: every
numeric flag swept with 1e308, -1e308, nan, 0, -1, 1e-300, 2**63, 1e-320 and 2**32 + 1; devices, FIFOs and
links in place of files; a device's clock running back.

Each failed before its change (the line in each case says how) and now ends in one ``motorid: error:``
line naming the flag or file, the rule and the value, or in a right answer; the FIFO and device cases held
already and are kept as the sweep over every file argument.
"""
from __future__ import annotations

import os

import numpy as np
import pytest

from motorid.cli import main


def _error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert err and err[-1].startswith("motorid: error:"), err
    return err[-1]


@pytest.fixture(scope="module")
def rec_path(tmp_path_factory):
    path = tmp_path_factory.mktemp("rec") / "rec.csv"
    assert main(["simulate", "--a", "25", "--b", "3", "--duration", "2", "--out", str(path)]) == 0
    return path


@pytest.fixture()
def lab(tmp_path):
    t = np.arange(400) * 0.005
    path = tmp_path / "lab.csv"
    path.write_text("t,u,w\n" + "".join(f"{a:.6f},{100 if (a * 3) % 2 < 1 else -100},{np.sin(a):.5f}\n" for a in t))
    return path


_LAB = ["--time", "t:s", "--input", "u:duty", "--speed", "w:rad/s"]


# --- flags that describe a foreign file: 0 is a value, not "not given" --------------------------------------

@pytest.mark.parametrize("flag", ["--counts-per-rev", "--input-limit"])
def test_a_foreign_files_flag_given_as_0_to_a_recording_is_refused_not_ignored(rec_path, flag, capsys):
    # before: exit 0, the flag ignored as if not given (0 was taken for "none")
    assert main(["identify", str(rec_path), flag, "0"]) == 2
    assert f"{flag} describes a foreign file's columns" in _error(capsys)


@pytest.mark.parametrize("value", ["0", "-1"])
def test_an_encoder_resolution_that_is_none_is_refused_on_import(lab, tmp_path, value, capsys):
    # before: exit 0 (the file's speed column needs no resolution; the flag was dropped unread)
    assert main(["import", str(lab), *_LAB, "--counts-per-rev", value, "--out", str(tmp_path / "o.csv")]) == 2
    assert f"--counts-per-rev must be an encoder's counts per revolution, in 1...4294967296, got {value}" \
        in _error(capsys)
    assert not (tmp_path / "o.csv").exists()


def test_an_encoder_resolution_for_a_speed_column_is_refused_as_without_effect(lab, tmp_path, capsys):
    assert main(["import", str(lab), *_LAB, "--counts-per-rev", "1000", "--out", str(tmp_path / "o.csv")]) == 2
    assert "--counts-per-rev 1000 describes a counts column" in _error(capsys)


@pytest.mark.parametrize("limit, said", [("1e-300", "--input-limit must be a number in 1e-100...1e+12 duty"),
                                         ("50", "--input-limit 50 duty is below the input"),
                                         ("1e13", "--input-limit must be a number in 1e-100...1e+12 duty")])
def test_an_input_limit_no_drive_has_or_below_the_input_recorded_is_refused(lab, tmp_path, limit, said, capsys):
    # before: 1e-300 and 50 were written as the recording's limit (exit 0) while it records +-100
    assert main(["import", str(lab), *_LAB, "--input-limit", limit, "--out", str(tmp_path / "o.csv")]) == 2
    line = _error(capsys)
    assert said in line and (limit != "50" or str(lab) in line)
    assert not (tmp_path / "o.csv").exists()


def test_a_design_within_an_input_limit_of_1e_300_is_refused(capsys):
    # before: exit 0, "tracking RMS 0 rad/s, largest input 0 duty" for a reference of 4e-302 rad/s
    assert main(["control", "design", "--a", "25", "--b", "3", "--controller", "pi", "--input-limit", "1e-300"]) == 2
    assert "--input-limit must be a number in 1e-100...1e+12 duty (a drive's largest input), got 1e-300" \
        in _error(capsys)


@pytest.mark.parametrize("a, b", [("1e-300", "3"), ("25", "1e-300")])
def test_design_guesses_beyond_any_motor_are_refused(tmp_path, a, b, capsys):
    # before: a = 1e-300 "internal error: OverflowError", b = 1e-300 exit 0 with every standard error inf
    assert main(["design", "--a", a, "--b", b, "--sample-period", "0.005", "--counts-per-rev", "1000", "--no-plots",
                 "--out", str(tmp_path / "d")]) == 2
    assert "the predicted standard errors are not finite at any frequency" in _error(capsys)


@pytest.mark.parametrize("level", ["1e-300", "0.3", "1"])
def test_a_confidence_level_that_bounds_nothing_is_refused(rec_path, level, capsys):
    # before (1e-300): exit 0, "1e-298 % bounds", every model outside its zero-width bound
    assert main(["frequency", str(rec_path), "--level", level]) == 2
    assert f"--level must be a probability in 0.5...1, got {float(level)!r}" in _error(capsys)


# --- inputs: only what the user named is read -------------------------------------------------------------

@pytest.mark.parametrize("where", ["absolute", "relative"])
def test_a_bag_folder_whose_database_links_outside_it_is_refused_not_followed(tmp_path, where, capsys):
    outside = tmp_path / "elsewhere" / "secret.db3"
    outside.parent.mkdir()
    outside.write_bytes(b"SQLite format 3\x00" + b"\x00" * 100)
    bag = tmp_path / "bag"
    bag.mkdir()
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information:\n  relative_file_paths: [bag_0.db3]\n")
    os.symlink(outside if where == "absolute" else os.path.join("..", "elsewhere", "secret.db3"), bag / "bag_0.db3")
    for named in (bag, bag / "bag_0.db3"):
        assert main(["import", str(named), "--time", "t", "--input", "u:duty", "--speed", "y:rad/s",
                     "--out", str(tmp_path / "o.csv")]) == 2
        line = _error(capsys)
        assert "outside the bag's folder" in line and "bag_0.db3" in line
    assert not (tmp_path / "o.csv").exists()


@pytest.mark.parametrize("make", ["fifo", "device"])
@pytest.mark.parametrize("argv", [["identify", "{p}"], ["frequency", "{p}"], ["identify", "{rec}", "--validate", "{p}"],
                                  ["control", "design", "--model", "{p}", "--controller", "pi"],
                                  ["frequency", "{rec}", "--model", "{p}"], ["sweep", "{p}", "--out", "{tmp}/sw"]])
def test_every_file_argument_refuses_a_fifo_or_a_device(rec_path, tmp_path, make, argv, capsys):
    if make == "fifo":
        path = tmp_path / "pipe"
        os.mkfifo(path)
    else:
        path = "/dev/zero"                  # a device that never ends
    assert main([a.format(p=path, rec=rec_path, tmp=tmp_path) for a in argv]) == 2
    line = _error(capsys)
    assert str(path) in line and ("FIFO" in line if make == "fifo" else "a device" in line)


@pytest.mark.parametrize("flag, value, said", [
    ("--baud", "9223372036854775808", "--baud must be a line rate in 1...50000000 baud"),     # before: exit 0
    ("--timeout", "4294967297", "--timeout must be a number of seconds > 0 and < 3600"),     # 136 years' wait
])
def test_live_link_flags_are_bounded(tmp_path, flag, value, said, capsys):
    out = tmp_path / "run.csv"
    assert main(["live", "--port", "fake://?a=25&b=3", "--duration", "0.2", flag, value, "--out", str(out)]) == 2
    assert said in _error(capsys) and not out.exists()


# --- a locale without UTF-8 ---------------------------------------------------------------------------------

@pytest.mark.parametrize("argv", [["identify", "{rec}"], ["frequency", "{rec}"],
                                  ["import", "{lab}", *_LAB, "--out", "{tmp}/o.csv"]])
def test_reading_commands_print_plain_ascii_under_the_c_locale(rec_path, lab, tmp_path, argv):
    import subprocess
    import sys
    from pathlib import Path
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONIOENCODING", "PYTHONUTF8", "LANG", "LC_CTYPE")}
    env.update(LC_ALL="C", PYTHONUTF8="0", PYTHONPATH=str(Path(__file__).resolve().parents[2]))
    done = subprocess.run([sys.executable, "-m", "motorid", *[a.format(rec=rec_path, lab=lab, tmp=tmp_path)
                                                               for a in argv]],
                          capture_output=True, env=env, timeout=600)
    assert done.returncode == 0, done.stderr.decode("ascii", "replace")
    assert done.stdout.isascii() and done.stderr.isascii() and b"Error" not in done.stderr


# --- a compressed ROS 2 bag: memory bounded by what the bag can honestly hold -------------------------------

def _zstd_bag(path, bomb_mib: int = 0):
    """A bag of two Float64 topics, each message zstd-compressed (``ros2 bag record --compression-mode message``);
    with ``bomb_mib``, one message replaced by a zstd stream of that many MiB of zeros (no size in its header)."""
    pytest.importorskip("rosbags", reason="rosbags (the ros extra) is not installed")
    import sqlite3

    from rosbags.rosbag2 import CompressionFormat, CompressionMode, Writer
    from rosbags.typesys import Stores, get_typestore
    try:
        from compression import zstd  # type: ignore[import-not-found]
    except ImportError:
        from backports import zstd  # type: ignore[import-not-found,no-redef]
    store = get_typestore(Stores.ROS2_HUMBLE)
    f64 = store.types["std_msgs/msg/Float64"]
    writer = Writer(path, version=9)
    writer.set_compression(CompressionMode.MESSAGE, CompressionFormat.ZSTD)
    t = np.arange(400) * 0.005
    speed = np.cumsum(np.where((t // 0.25) % 2 == 0, 1.0, -1.0)) * 0.01
    with writer:
        cmd = writer.add_connection("/cmd", f64.__msgtype__, typestore=store)
        spd = writer.add_connection("/speed", f64.__msgtype__, typestore=store)
        for k in range(len(t)):
            ns = 10**9 + int(round(t[k] * 1e9))
            writer.write(cmd, ns, store.serialize_cdr(f64(data=100.0 if (t[k] // 0.25) % 2 == 0 else -100.0),
                                                      f64.__msgtype__))
            writer.write(spd, ns + 1000, store.serialize_cdr(f64(data=float(speed[k])), f64.__msgtype__))
    if bomb_mib:
        packer, zeros, blob = zstd.ZstdCompressor(), bytes(1 << 20), b""
        blob = b"".join(packer.compress(zeros) for _ in range(bomb_mib)) + packer.flush()
        db = next(path.glob("*.db3"))
        with sqlite3.connect(db) as con:
            con.execute("update messages set data = ? where id = 5", (blob,))
        con.close()
    return path


def test_a_compressed_bag_that_unpacks_beyond_its_bound_is_refused(tmp_path, monkeypatch, capsys):
    # before: a 135 kB bag whose one message unpacks to 2.5 GB took 5.2 GB of memory and 31 s, then "CDR
    # message size mismatch"; here the bound is lowered to 64 MiB so that 300 MiB show it in a test's memory
    import motorsim.robot_logs as logs
    monkeypatch.setattr(logs, "BAG_MEMORY_FLOOR", 64 << 20)
    flags = ["--time", "time_s", "--input", "/cmd:duty", "--speed", "/speed:rad/s"]
    honest = _zstd_bag(tmp_path / "honest")
    assert main(["import", str(honest), *flags, "--out", str(tmp_path / "h.csv")]) == 0   # within the bound
    capsys.readouterr()
    bomb = _zstd_bag(tmp_path / "bomb", bomb_mib=300)
    assert main(["import", str(bomb), *flags, "--out", str(tmp_path / "b.csv")]) == 2
    line = _error(capsys)
    assert line.startswith(f"motorid: error: {bomb}: reading this bag needs more than the") and \
        "a decompression bomb or a damaged bag, refused" in line
    assert not (tmp_path / "b.csv").exists()


def test_a_bag_compressed_by_file_that_unpacks_beyond_its_bound_is_refused(tmp_path, monkeypatch, capsys):
    # ros2 bag record --compression-mode file: the reader unpacks the database to a temporary file; before,
    # a few kB unpacked to as much disk as the stream says (300 MiB here, then "not a readable ROS 2 bag")
    pytest.importorskip("rosbags", reason="rosbags (the ros extra) is not installed")
    from rosbags.rosbag2 import CompressionFormat, CompressionMode, Writer
    from rosbags.typesys import Stores, get_typestore

    import motorsim.robot_logs as logs
    try:
        from compression import zstd  # type: ignore[import-not-found]
    except ImportError:
        from backports import zstd  # type: ignore[import-not-found,no-redef]
    monkeypatch.setattr(logs, "BAG_MEMORY_FLOOR", 64 << 20)
    store = get_typestore(Stores.ROS2_HUMBLE)
    f64 = store.types["std_msgs/msg/Float64"]
    bag = tmp_path / "bomb"
    writer = Writer(bag, version=9)
    writer.set_compression(CompressionMode.FILE, CompressionFormat.ZSTD)
    with writer:
        conn = writer.add_connection("/speed", f64.__msgtype__, typestore=store)
        writer.write(conn, 10**9, store.serialize_cdr(f64(data=1.0), f64.__msgtype__))
    packed = next(bag.glob("*.zstd"))
    packer, zeros = zstd.ZstdCompressor(), bytes(1 << 20)
    packed.write_bytes(b"".join(packer.compress(zeros) for _ in range(300)) + packer.flush())
    assert main(["import", str(bag), "--time", "time_s", "--input", "/speed:duty", "--speed", "/speed:rad/s",
                 "--out", str(tmp_path / "b.csv")]) == 2
    assert "a decompression bomb or a damaged bag, refused" in _error(capsys)

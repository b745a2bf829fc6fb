"""Output files of the commands: never destroyed, never followed, never half-written; one clear line when impossible."""
from __future__ import annotations

import errno
import os
import tempfile
from pathlib import Path

import pytest

from hardware.serial_rig import SerialRig
from motorid.cli import main
from motorsim import read_recording
from motorsim.writing import RecordingWriter

LIVE = ["live", "--port", "fake://?a=25&b=3&speed=0", "--duration", "1", "--quiet"]


@pytest.fixture
def full_disk(tmp_path, monkeypatch):
    """Files under ``tmp_path/full`` fail to reach the disk (ENOSPC at fsync); the temporary folder is elsewhere."""
    full = tmp_path / "full"
    full.mkdir()
    rescue = tmp_path / "rescue"
    rescue.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(rescue))
    real_fsync = os.fsync

    def fsync(fd):
        if os.readlink(f"/proc/self/fd/{fd}").startswith(str(full)):
            raise OSError(errno.ENOSPC, "No space left on device")
        real_fsync(fd)
    monkeypatch.setattr(os, "fsync", fsync)
    return full, rescue


@pytest.fixture
def motor_starts(monkeypatch):
    """Counts the runs SerialRig starts."""
    runs = []
    real = SerialRig.run

    def run(self, experiment, **kw):
        runs.append(experiment)
        return real(self, experiment, **kw)
    monkeypatch.setattr(SerialRig, "run", run)
    return runs


def _error_line(capsys) -> str:
    err = capsys.readouterr().err
    assert "Traceback" not in err
    lines = [line for line in err.splitlines() if line.startswith("motorid: error:")]
    assert len(lines) == 1, err
    return lines[0]


@pytest.mark.skipif(not Path("/proc/self/fd").is_dir(), reason="needs /proc to tell files apart")
def test_a_full_disk_mid_run_stops_the_motor_and_keeps_every_sample_elsewhere(tmp_path, full_disk, monkeypatch,
                                                                               capsys):
    full, rescue = full_disk
    flush = RecordingWriter.flush

    def flush_until_full(self):
        if self.n_rows >= 50:
            raise OSError(errno.ENOSPC, "No space left on device", str(self.partial_path))
        flush(self)
    monkeypatch.setattr(RecordingWriter, "flush", flush_until_full)
    monkeypatch.setattr(RecordingWriter, "__init__", _small_flush_interval(RecordingWriter.__init__))
    # a device on the wall clock (speed=1): unpaced, it ran as fast as the host read, so on a loaded
    # machine it could finish the whole run before the host's STOP reached it
    paced = [LIVE[0], "--port", "fake://?a=25&b=3", *LIVE[3:]]
    status = main([*paced, "--duration", "5", "--out", str(full / "run.csv")])
    line = _error_line(capsys)
    assert status == 2
    assert "No space left on device" in line and "the motor was stopped" in line
    [kept] = rescue.iterdir()
    assert str(kept) in line
    rec = read_recording(kept)
    m = rec.metadata
    # everything the rig received, with END's counters (the device saw STOP: reason 1)
    assert m["complete"] == "false" and m["device_end_reason"] == "1"
    assert 50 <= len(rec) == int(m["samples_received"]) == int(m["device_samples_sent"]) < 1000
    assert not (full / "run.csv").exists()


def _small_flush_interval(init):
    def wrapped(self, *args, **kw):
        init(self, *args, **{**kw, "flush_interval": 0.0})
    return wrapped


@pytest.mark.skipif(not Path("/proc/self/fd").is_dir(), reason="needs /proc to tell files apart")
def test_a_full_disk_at_the_end_keeps_the_recording_and_the_estimate(tmp_path, full_disk, capsys):
    full, rescue = full_disk
    status = main([*LIVE, "--out", str(full / "run.csv")])
    captured = capsys.readouterr()
    assert status == 2 and "Traceback" not in captured.err
    assert "No space left on device" in captured.err and "method      oe" in captured.out
    [kept] = rescue.iterdir()
    rec = read_recording(kept)
    assert len(rec) == 200 and rec.metadata["complete"] == "true" and rec.metadata["device_samples_sent"] == "200"
    assert (full / "run.csv.partial").exists() and not (full / "run.csv").exists()


@pytest.mark.parametrize("out, rule", [
    ("missing/run.csv", "does not exist"),
    (".", "is a folder"),
    ("/proc/motorid-run.csv", "cannot create files in /proc"),
], ids=["missing-folder", "folder", "proc"])
def test_an_out_that_cannot_be_written_is_refused_before_the_motor_starts(tmp_path, motor_starts, capsys, out, rule):
    path = out if out.startswith("/") else str(tmp_path / out)
    assert main([*LIVE, "--out", path]) == 2
    assert rule in _error_line(capsys) and motor_starts == []


def test_an_existing_recording_is_refused_unless_overwrite(tmp_path, motor_starts, capsys):
    out = tmp_path / "run.csv"
    out.write_text("an earlier recording")
    assert main([*LIVE, "--out", str(out)]) == 2
    assert "exists; pass --overwrite" in _error_line(capsys) and motor_starts == []
    assert out.read_text() == "an earlier recording"
    assert main([*LIVE, "--out", str(out), "--overwrite"]) == 0
    assert len(read_recording(out)) == 200


def test_a_device_node_is_never_replaced_even_with_overwrite(tmp_path, motor_starts, capsys):
    node = tmp_path / "fifo"          # a FIFO stands for /dev/null: not a regular file
    os.mkfifo(node)
    assert main([*LIVE, "--out", str(node), "--overwrite"]) == 2
    assert "not a regular file" in _error_line(capsys) and motor_starts == []
    assert not node.is_file() and node.exists()


def test_a_crashed_runs_partial_is_kept_and_a_planted_link_is_not_followed(tmp_path, motor_starts, capsys):
    partial = tmp_path / "run.csv.partial"
    partial.write_text("# motorid recording v1\nrows of a run that crashed\n")
    assert main([*LIVE, "--out", str(tmp_path / "run.csv")]) == 2
    assert "an earlier run that did not finish" in _error_line(capsys)
    assert partial.read_text().endswith("crashed\n")
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    (tmp_path / "b.csv.partial").symlink_to(victim)
    assert main([*LIVE, "--out", str(tmp_path / "b.csv")]) == 2
    assert "symbolic link" in _error_line(capsys) and motor_starts == []
    assert victim.read_text() == "precious"


SIM = ["simulate", "--a", "25", "--b", "3", "--duration", "0.5"]
DESIGN = ["design", "--a", "25", "--b", "3", "--sample-period", "0.005", "--counts-per-rev", "1000"]


@pytest.mark.parametrize("command", ["simulate", "design", "sweep"])
@pytest.mark.parametrize("where", ["missing", "folder-or-file", "proc"])
def test_commands_refuse_an_unwritable_out_in_one_line_and_keep_the_old_file(tmp_path, capsys, command, where):
    old = tmp_path / "old.csv"
    old.write_text("old")
    target = {"missing": str(tmp_path / "missing" / "deeper" / "x.csv") if command == "simulate" else "/proc/none/x",
              "folder-or-file": str(tmp_path) if command == "simulate" else str(old),
              "proc": "/proc/motorid-x.csv" if command == "simulate" else "/proc/motorid-x"}[where]
    argv = {"simulate": SIM, "design": DESIGN,
            "sweep": ["sweep", "article", "--repetitions", "1", "--workers", "1", "--quiet", "--no-plots"]}[command]
    assert main([*argv, "--out", target]) == 2
    assert _error_line(capsys)
    assert old.read_text() == "old" and sorted(p.name for p in tmp_path.iterdir()) == ["old.csv"]


def test_a_full_disk_keeps_the_old_recording_of_simulate(tmp_path, full_disk, capsys):
    full, _ = full_disk
    out = full / "run.csv"
    out.write_text("old")
    assert main([*SIM, "--out", str(out)]) == 2
    assert "No space left on device; the old file is unchanged" in _error_line(capsys)
    assert out.read_text() == "old" and sorted(p.name for p in full.iterdir()) == ["run.csv"]


@pytest.mark.parametrize("name", ["../../escaped", "/tmp/escaped-absolute"], ids=["dotdot", "absolute"])
def test_a_scenario_name_never_writes_outside_the_output_folder(tmp_path, monkeypatch, capsys, name):
    work = tmp_path / "a" / "b"
    work.mkdir(parents=True)
    monkeypatch.chdir(work)
    (work / "s.toml").write_text(f'name = "{name}"\nrepetitions = 1\nmethods = ["zoh-ls"]\n'
                                 f'[bench]\nduration = 0.5\n', encoding="utf-8")
    assert main(["sweep", "s.toml", "--workers", "1", "--quiet", "--no-plots"]) == 0
    written = sorted(p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*.csv"))
    assert len(written) == 1 and written[0].startswith("a/b/sweep-output/")
    assert not Path("/tmp/escaped-absolute").exists()


def _serve_once(reply: bytes):
    """A TCP server on localhost that answers every connection with ``reply`` (not Dask); returns its port."""
    import socket
    import threading
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(8)
    server.settimeout(30)

    def serve():
        with server:
            for _ in range(8):
                try:
                    conn, _ = server.accept()
                except OSError:
                    return
                with conn:
                    conn.sendall(reply)
    threading.Thread(target=serve, daemon=True).start()
    return server.getsockname()[1]


def test_dask_at_an_address_that_is_not_a_scheduler_is_one_clear_line(tmp_path, capsys):
    pytest.importorskip("dask.distributed")
    port = _serve_once(b"HTTP/1.0 200 OK\r\n\r\nhello, I am a web server\n" * 4)
    argv = ["sweep", "article", "--repetitions", "1", "--quiet", "--no-plots", "--out", str(tmp_path / "o")]
    assert main([*argv, "--dask", f"tcp://127.0.0.1:{port}"]) == 2
    line = _error_line(capsys)
    assert f"--dask tcp://127.0.0.1:{port}" in line and "Dask" in line


def test_dask_where_nothing_listens_gives_up_with_one_line(tmp_path, capsys, monkeypatch):
    pytest.importorskip("dask.distributed")
    import motorid.commands.sweep
    monkeypatch.setattr(motorid.commands.sweep, "DASK_CONNECT_TIMEOUT", 1.0)
    argv = ["sweep", "article", "--repetitions", "1", "--quiet", "--no-plots", "--out", str(tmp_path / "o")]
    assert main([*argv, "--dask", "tcp://127.0.0.1:1"]) == 2
    line = _error_line(capsys)
    assert "no Dask scheduler answered within 1 s" in line

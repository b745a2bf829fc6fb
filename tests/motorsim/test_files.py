"""motorsim.files: exclusive, atomic, never through a link, never over a folder or a device, umask."""
from __future__ import annotations

import errno
import os
import stat

import pytest

from motorsim.files import (
    OutputFileError,
    atomic_writer,
    check_output_file,
    open_exclusive,
    safe_file_name,
    write_atomically,
)


@pytest.fixture
def umask_022():
    old = os.umask(0o022)
    yield
    os.umask(old)


def test_open_exclusive_never_follows_or_truncates_a_planted_link(tmp_path):
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    (tmp_path / "run.csv.partial").symlink_to(victim)
    with pytest.raises(FileExistsError):
        open_exclusive(tmp_path / "run.csv.partial")
    assert victim.read_text() == "precious"


def test_files_follow_the_umask_even_when_replacing_a_0644_file(tmp_path, umask_022):
    path = tmp_path / "out.csv"
    path.write_text("old")
    path.chmod(0o644)
    write_atomically(path, "new")
    assert stat.S_IMODE(path.stat().st_mode) == 0o644 and path.read_text() == "new"
    os.umask(0o077)
    write_atomically(tmp_path / "private.csv", "x")
    assert stat.S_IMODE((tmp_path / "private.csv").stat().st_mode) == 0o600


def test_a_device_node_or_a_folder_is_never_replaced(tmp_path):
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    for target, rule in ((fifo, "not a regular file"), (tmp_path, "is a folder")):
        with pytest.raises(OutputFileError, match=rule):
            write_atomically(target, "x")
        with pytest.raises(OutputFileError, match=rule):
            check_output_file(target, overwrite=True)
    assert stat.S_ISFIFO(fifo.stat().st_mode)


def test_a_failure_while_writing_keeps_the_old_file_and_leaves_no_temporary(tmp_path, monkeypatch):
    path = tmp_path / "out.csv"
    path.write_text("old")

    def disk_full(fd):
        raise OSError(errno.ENOSPC, "No space left on device")
    monkeypatch.setattr(os, "fsync", disk_full)
    with pytest.raises(OutputFileError, match=r"out.csv: No space left on device; the old file is unchanged"):
        write_atomically(path, "new")
    assert path.read_text() == "old" and sorted(p.name for p in tmp_path.iterdir()) == ["out.csv"]


def test_an_exception_inside_atomic_writer_leaves_the_old_file(tmp_path):
    path = tmp_path / "out.csv"
    path.write_text("old")
    with pytest.raises(KeyboardInterrupt), atomic_writer(path) as f:
        f.write("half")
        raise KeyboardInterrupt
    assert path.read_text() == "old" and sorted(p.name for p in tmp_path.iterdir()) == ["out.csv"]


def test_check_output_file_refuses_what_cannot_be_written(tmp_path):
    (tmp_path / "old.csv").write_text("old")
    with pytest.raises(OutputFileError, match="exists; pass --overwrite"):
        check_output_file(tmp_path / "old.csv", overwrite=False)
    assert check_output_file(tmp_path / "old.csv", overwrite=True) == tmp_path / "old.csv"
    with pytest.raises(OutputFileError, match="does not exist"):
        check_output_file(tmp_path / "missing" / "x.csv")
    with pytest.raises(OutputFileError, match="is not a folder"):
        check_output_file(tmp_path / "old.csv" / "x.csv")
    with pytest.raises(OutputFileError, match="cannot create files in /proc"):
        check_output_file("/proc/motorid-test.csv")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["old.csv"]     # the probe is removed


@pytest.mark.parametrize("name, expected", [
    ("../../..", "unnamed"), ("/etc/passwd", "etc_passwd"), ("..\\..\\win", "win"), ("a/../b", "a_b"),
    ("ok-name_1.5", "ok-name_1.5"), ("", "unnamed"), (".hidden", "hidden"), ("x" * 300, "x" * 100),
], ids=["dotdot", "absolute", "backslashes", "inner-dotdot", "plain", "empty", "hidden", "long"])
def test_safe_file_name_is_one_harmless_path_component(name, expected):
    safe = safe_file_name(name)
    assert safe == expected
    assert "/" not in safe and "\\" not in safe and ".." not in safe and not safe.startswith(".")

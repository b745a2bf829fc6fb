"""Every input is checked for its kind and size before it is read: nothing waits forever, nothing is misnamed."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from motorid.cli import main

ROOT = Path(__file__).resolve().parents[2]
HANG_GUARD = 60.0   # s: only against a hung test


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("rec") / "r.csv"
    assert main(["simulate", "--a", "25", "--b", "3", "--duration", "2", "--out", str(path)]) == 0
    return path


def _motorid(*args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    try:
        return subprocess.run([sys.executable, "-m", "motorid", *args], env=env, capture_output=True, text=True,
                              timeout=HANG_GUARD)
    except subprocess.TimeoutExpired:
        raise AssertionError(f"motorid {' '.join(args)} waited on its input") from None


@pytest.fixture
def fifo(tmp_path) -> Path:
    path = tmp_path / "pipe.json"
    os.mkfifo(path)
    return path


@pytest.mark.parametrize("case", ["recording", "model", "validate", "frequency model", "import"])
def test_a_fifo_given_as_any_input_is_refused_at_once(recording, fifo, case):
    args = {"recording": ["identify", str(fifo)],
            "model": ["control", "design", "--controller", "pi", "--model", str(fifo)],
            "validate": ["identify", str(recording), "--validate", str(fifo)],
            "frequency model": ["frequency", str(recording), "--model", str(fifo)],
            "import": ["import", str(fifo), "--time", "0", "--input", "1", "--speed", "2", "--out", "x.csv"]}[case]
    done = _motorid(*args)
    assert done.returncode == 2, done.stderr
    assert "FIFO" in done.stderr and "Traceback" not in done.stderr


def test_a_model_that_is_dev_zero_is_refused_as_a_device():
    done = _motorid("control", "design", "--controller", "pi", "--model", "/dev/zero")
    assert done.returncode == 2 and "device" in done.stderr


@pytest.mark.parametrize("command", ["import", "identify-columns"])
def test_a_directory_is_named_a_directory_not_a_missing_file(tmp_path, capsys, command):
    columns = ["--time", "0", "--input", "1", "--speed", "2"]
    argv = (["import", str(tmp_path), *columns, "--out", str(tmp_path / "x.csv")] if command == "import"
            else ["identify", str(tmp_path), *columns])
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "directory" in err and "no such file" not in err


@pytest.fixture(scope="module")
def mat_bytes(tmp_path_factory) -> bytes:
    from scipy import io
    path = tmp_path_factory.mktemp("mat") / "good.mat"
    io.savemat(path, {"t": np.arange(200) * 0.005, "u": np.ones(200), "y": np.ones(200)})
    return path.read_bytes()


@pytest.mark.parametrize("cut", ["half", "header", "empty", "text"])
def test_a_damaged_mat_file_is_a_user_error_that_says_so(tmp_path, capsys, mat_bytes, cut):
    data = {"half": mat_bytes[:len(mat_bytes) // 2], "header": mat_bytes[:100], "empty": b"",
            "text": b"t,u,y\n0,1,2\n"}[cut]
    path = tmp_path / "run.mat"
    path.write_bytes(data)
    assert main(["import", str(path), "--time", "t", "--input", "u", "--speed", "y",
                 "--out", str(tmp_path / "x.csv")]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and "internal error" not in err
    assert "could not read bytes" not in err.split("(")[0]
    assert "run.mat" in err

"""The command line in a pipe: one JSON document on stdout, quiet when the reader goes away, --version."""
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).parents[2]
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}
MOTORID = [sys.executable, "-m", "motorid.cli"]


@pytest.fixture(scope="module")
def run_csv(tmp_path_factory):
    path = tmp_path_factory.mktemp("pipe") / "run.csv"
    subprocess.run([*MOTORID, "simulate", "--a", "25", "--b", "3", "--duration", "2", "--sine", "10,200",
                    "--out", str(path)], check=True, env=ENV, capture_output=True)
    return path


def test_identify_json_pipes_into_json_tool(run_csv):
    """``motorid identify run.csv --json | python -m json.tool``, as a shell pipe."""
    identify = subprocess.Popen([*MOTORID, "identify", str(run_csv), "--json"], stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, env=ENV)
    tool = subprocess.run([sys.executable, "-m", "json.tool"], stdin=identify.stdout, capture_output=True, text=True)
    identify.stdout.close()
    err = identify.stderr.read().decode()
    identify.stderr.close()
    assert identify.wait() == 0 and tool.returncode == 0, tool.stderr
    doc = json.loads(tool.stdout)
    assert doc["method"] == "oe" and abs(doc["a"] - 25) < 0.01
    assert "method      oe" in err                       # the human text went to stderr


@pytest.mark.parametrize("command", [["identify", "{run}"], ["identify", "{run}", "--json"], ["sweep", "--list"]],
                         ids=["identify", "identify-json", "sweep-list"])
def test_a_closed_pipe_ends_quietly(run_csv, command):
    """As ``| head`` that has already exited: no BrokenPipeError traceback, status 141 (SIGPIPE)."""
    read_end, write_end = os.pipe()
    os.close(read_end)                                    # the reader is gone before the first write
    try:
        proc = subprocess.run([*MOTORID, *(c.format(run=run_csv) for c in command)], stdout=write_end,
                              stderr=subprocess.PIPE, env=ENV, text=True)
    finally:
        os.close(write_end)
    assert "Traceback" not in proc.stderr and "BrokenPipeError" not in proc.stderr, proc.stderr
    assert proc.returncode == 141


def test_version():
    proc = subprocess.run([*MOTORID, "--version"], capture_output=True, text=True, env=ENV)
    assert proc.returncode == 0 and proc.stdout.startswith("motorid ") and len(proc.stdout.split()) == 2

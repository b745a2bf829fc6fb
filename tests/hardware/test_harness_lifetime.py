"""The emulator's harness dies with the process that started it, even one killed by SIGKILL.

The launcher asks Linux to signal it (``PR_SET_PDEATHSIG``); the harness also watches its parent
pid itself, which the tests of the real harness started without the launcher check.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from tests.processes import processes_with

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux's")

# A parent that starts the harness through AvrSimulation.start() (the build replaced by a stand-in
# harness that announces a pty and then spins, as the real one does), prints its pid, and waits.
_PARENT = textwrap.dedent("""
    import sys, time
    import hardware.sim.launcher as launcher
    launcher.build = lambda baudrate, driver: (sys.argv[1], sys.argv[2])
    sim = launcher.AvrSimulation()
    sim.start()
    print(sim._process.pid, flush=True)
    time.sleep(60)
""")


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(") ")[1][0] != "Z"
    except FileNotFoundError:
        return False


def test_the_harness_ends_when_its_parent_is_killed(tmp_path):
    harness = tmp_path / "harness"
    harness.write_text("#!/bin/sh\necho 'PTY /dev/null'\nexec sleep 60\n")
    harness.chmod(0o755)
    parent = subprocess.Popen([sys.executable, "-c", _PARENT, str(tmp_path / "elf"), str(harness)],
                              stdout=subprocess.PIPE, text=True, cwd=os.getcwd())
    assert parent.stdout is not None
    child = int(parent.stdout.readline())
    assert _alive(child)
    parent.send_signal(signal.SIGKILL)
    parent.wait()
    parent.stdout.close()
    deadline = time.monotonic() + 10      # SIGTERM is delivered at once; 10 s only bounds a loaded machine
    while _alive(child) and time.monotonic() < deadline:
        time.sleep(0.05)
    alive = _alive(child)
    if alive:
        os.kill(child, signal.SIGKILL)
    assert not alive


# A parent that builds and starts the real harness itself, without the launcher's
# PR_SET_PDEATHSIG (so only the harness's own watch on its parent can end it), prints its pid,
# opens its pseudo-terminal when asked (the emulation then runs), and waits.
_BARE_PARENT = textwrap.dedent("""
    import subprocess, sys, time
    from hardware.sim.launcher import HarnessOptions, build
    elf, harness = build()
    proc = subprocess.Popen([str(harness), str(elf), *HarnessOptions().argv()],
                            stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, text=True)
    line = proc.stdout.readline()
    while line and not line.startswith("PTY "):     # simavr's own lines come first
        line = proc.stdout.readline()
    if sys.argv[1] == "open":
        port = open(line[4:].strip(), "rb", buffering=0)
    print(proc.pid, flush=True)
    time.sleep(120)
""")
_POLLS = 400      # 0.05 s apart: the harness checks its parent every few ms; 20 s only bounds a hang


def _gone_within_polls(pid: int) -> bool:
    for _ in range(_POLLS):
        if not _alive(pid):
            return True
        time.sleep(0.05)
    os.kill(pid, signal.SIGKILL)
    return False


@pytest.mark.parametrize("host", ["closed", "open"], ids=["waiting-for-the-host", "emulating"])
def test_the_harness_itself_ends_when_its_parent_is_killed(host):
    from hardware.sim.launcher import missing_tools
    if missing_tools():
        pytest.skip(f"the emulator needs {missing_tools()}")
    parent = subprocess.Popen([sys.executable, "-c", _BARE_PARENT, host], stdout=subprocess.PIPE, text=True,
                              cwd=os.getcwd(), env={**os.environ, "PYTHONPATH": os.getcwd()})
    assert parent.stdout is not None
    child = int(parent.stdout.readline())
    time.sleep(0.3)                # the parent is waiting; the harness is running, not just starting
    assert _alive(child)
    parent.send_signal(signal.SIGKILL)
    parent.wait()
    parent.stdout.close()
    assert _gone_within_polls(child)


def test_kill_9_of_motorid_live_on_avr_sim_leaves_no_emulator(tmp_path):
    from hardware.sim.launcher import missing_tools
    if missing_tools():
        pytest.skip(f"the emulator needs {missing_tools()}")
    out = tmp_path / "run.csv"
    marker = f"harness-lifetime-{os.getpid()}-{time.monotonic_ns()}"
    root = os.getcwd()
    env = {**os.environ, "PYTHONPATH": root, "MOTORID_TEST_MARKER": marker}
    errors = tmp_path / "stderr.txt"
    with errors.open("w") as err:
        proc = subprocess.Popen([sys.executable, "-m", "motorid.cli", "live", "--port", "avr-sim://?a=25&b=3",
                                 "--duration", "60", "--quiet", "--out", str(out)],
                                env=env, cwd=root, stdout=subprocess.DEVNULL, stderr=err)
    partial = Path(f"{out}.partial")
    try:
        for _ in range(_POLLS * 6):     # building the firmware on a fresh tree takes a while
            if (partial.exists() and partial.stat().st_size > 0) or proc.poll() is not None:
                break
            time.sleep(0.05)
        assert proc.poll() is None, errors.read_text()
        harnesses = [pid for pid in processes_with(marker) if pid != proc.pid]
        assert harnesses, "no emulator process found while live ran"
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        left = [pid for pid in harnesses if not _gone_within_polls(pid)]
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert not left, f"emulator processes left running: {left}"

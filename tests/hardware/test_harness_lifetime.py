"""The emulator's harness dies with the process that started it, even one killed by SIGKILL."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time

import pytest

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

"""SIGTERM and SIGHUP end ``motorid live`` and ``motorid sweep`` as Ctrl-C does: nothing left running, data kept.

Each test runs ``motorid`` as a subprocess, waits until it is demonstrably mid-run (its
partial file exists), sends the signal, and checks what is left: the exit status, the
files, and the processes (found by a marker in their environment, which children inherit).
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path

import pytest

from motorsim import read_recording
from tests.processes import processes_with

ROOT = Path(__file__).resolve().parents[2]
HANG_GUARD = 120.0   # s: only against a hung test, never a speed assertion

pytestmark = pytest.mark.skipif(not Path("/proc/self/environ").exists(), reason="needs /proc to find processes")


def _start(args, marker):
    env = {**os.environ, "PYTHONPATH": str(ROOT), "MOTORID_TEST_MARKER": marker}
    return subprocess.Popen([sys.executable, "-m", "motorid.cli", *args], env=env, cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _wait_for(predicate, what: str, proc: subprocess.Popen) -> None:
    deadline = time.monotonic() + HANG_GUARD
    while not predicate():
        if proc.poll() is not None:
            raise AssertionError(f"motorid ended before {what}: {proc.communicate()}")
        if time.monotonic() > deadline:
            proc.kill()
            raise AssertionError(f"never saw {what}")
        time.sleep(0.05)


def _has_rows(path: Path):
    """True once ``path`` exists and is not empty (the partial recording has its first rows)."""
    return lambda: path.exists() and path.stat().st_size > 0


def _signal_mid_run(args, mid_run, what: str, signum: int) -> tuple[int, str, str]:
    marker = uuid.uuid4().hex
    proc = _start(args, marker)
    left: list[int] = []
    try:
        _wait_for(mid_run, what, proc)
        proc.send_signal(signum)
        out, err = proc.communicate(timeout=HANG_GUARD)
        # a child being reaped may take a moment to disappear from /proc
        deadline = time.monotonic() + 5.0
        while processes_with(marker) and time.monotonic() < deadline:
            time.sleep(0.05)
        left = processes_with(marker)
    finally:      # whatever failed, no process of this test outlives it
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        for pid in processes_with(marker):
            os.kill(pid, signal.SIGKILL)
    assert not left, f"processes left running after the signal: {left}"
    return proc.returncode, out, err


def _assert_stopped_recording(out: Path, reason: str) -> None:
    assert not Path(f"{out}.partial").exists()
    rec = read_recording(out)
    m = rec.metadata
    assert m["complete"] == "false" and m["incomplete_reason"] == reason
    # STOP reached the device: it ended the run with reason 1 (stopped by host) and its counters
    assert m["device_end_reason"] == "1"
    assert 0 < len(rec) == int(m["samples_received"]) == int(m["device_samples_sent"]) < int(m["samples_expected"])
    assert list(rec.seq) == list(range(len(rec)))


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGHUP], ids=["SIGTERM", "SIGHUP"])
def test_a_signal_during_live_on_fake_sends_stop_and_writes_the_final_recording(tmp_path, signum):
    out = tmp_path / "run.csv"
    status, _, err = _signal_mid_run(["live", "--port", "fake://?a=25&b=3", "--duration", "60", "--quiet",
                                      "--watchdog-ms", "0", "--out", str(out)],
                                     _has_rows(Path(f"{out}.partial")), "rows in the partial recording", signum)
    name = signal.Signals(signum).name
    assert status == 128 + signum, err
    assert f"interrupted ({name})" in err and "Traceback" not in err
    _assert_stopped_recording(out, f"interrupted ({name})")


@pytest.mark.firmware
def test_sigterm_during_live_on_the_emulated_firmware_stops_it_and_reaps_the_emulator(tmp_path):
    out = tmp_path / "run.csv"
    status, _, err = _signal_mid_run(["live", "--port", "avr-sim://?a=25&b=3", "--duration", "60", "--quiet",
                                      "--watchdog-ms", "0", "--out", str(out)],
                                     _has_rows(Path(f"{out}.partial")), "rows in the partial recording",
                                     signal.SIGTERM)
    assert status == 143 and "Traceback" not in err, err
    _assert_stopped_recording(out, "interrupted (SIGTERM)")


@pytest.mark.slow
def test_sigterm_during_a_sweep_leaves_no_partial_csv_and_no_worker(tmp_path):
    status, _, err = _signal_mid_run(["sweep", "reality", "--workers", "2", "--repetitions", "2000", "--quiet",
                                      "--no-plots", "--out", str(tmp_path)],
                                     lambda: any(p.name.startswith(".sweep.csv.") for p in tmp_path.iterdir()),
                                     "the unfinished sweep CSV", signal.SIGTERM)
    assert status == 143 and "interrupted (SIGTERM)" in err and "Traceback" not in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == []


@pytest.mark.firmware
def test_an_interrupt_while_the_emulator_starts_ends_its_process(monkeypatch):
    # Ctrl-C or SIGTERM can arrive while the harness is starting (before its pty is known).
    from hardware.sim import launcher
    sim = launcher.AvrSimulation()
    started = []
    popen = launcher.subprocess.Popen

    def popen_then_interrupt(*args, **kw):
        process = popen(*args, **kw)
        started.append(process)
        return process

    def select_interrupted(*args):
        raise KeyboardInterrupt
    monkeypatch.setattr(launcher.subprocess, "Popen", popen_then_interrupt)
    monkeypatch.setattr(launcher.select, "select", select_interrupted)
    with pytest.raises(KeyboardInterrupt):
        sim.start()
    [process] = started
    assert process.poll() is not None, "the harness was left running"

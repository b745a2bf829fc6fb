"""A signal at any moment, the first instants included, ends motorid with 128 + n and no traceback."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("delay", [0.15, 0.3], ids=["0.15 s", "0.3 s"])
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_signal_soon_after_start_gives_its_status_and_no_traceback(tmp_path, signum, delay):
    for _ in range(3):   # -n: the signal came before the interpreter itself was up (a loaded machine); again
        status, err = _signal_after(tmp_path, signum, delay)
        if status != -signum:
            break
    assert "Traceback" not in err, err
    if status == 0:                 # a fast machine finished first
        pytest.skip("the command ended before the signal")
    assert status == 128 + signum, (status, err)


def _signal_after(tmp_path: Path, signum: int, delay: float) -> tuple[int, str]:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen([sys.executable, "-m", "motorid", "simulate", "--a", "25", "--b", "3",
                             "--duration", "2000", "--out", str(tmp_path / "r.csv")],
                            env=env, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    time.sleep(delay)
    proc.send_signal(signum)
    try:
        _, err = proc.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        proc.kill()
        raise AssertionError("motorid did not end after the signal") from None
    return proc.returncode, err


def test_the_entry_point_imports_nothing_before_its_handlers_and_installs_them_before_the_parser(monkeypatch):
    """What the entry module loads runs unprotected: only ``sys``; the handlers come before every command's import."""
    code = ("import sys\nbefore = set(sys.modules)\nimport motorid.cli\n"
            "print(' '.join(sorted(set(sys.modules) - before)))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT,
                          env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert proc.returncode == 0, proc.stderr
    assert set(proc.stdout.split()) <= {"motorid", "motorid.cli"}, proc.stdout

    import motorid.cli
    seen = {}

    def build_parser():
        seen.update((s, signal.getsignal(s)) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP))
        raise KeyboardInterrupt          # stop here: nothing of a command is needed
    monkeypatch.setattr(motorid.cli, "build_parser", build_parser)
    outside = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    assert motorid.cli.main(["simulate"]) == 130
    assert all(seen[s] is not outside[s] and callable(seen[s]) for s in seen), seen
    assert {s: signal.getsignal(s) for s in outside} == outside             # restored


def test_an_interrupt_the_interpreter_swallows_is_raised_later_and_prints_no_traceback(capfd):
    from motorid.interrupts import Terminated, signals_as_interrupts

    class Finalised:
        def __del__(self):               # an exception raised here is "ignored" by the interpreter
            signal.raise_signal(signal.SIGTERM)

    with pytest.raises(Terminated) as raised:
        with signals_as_interrupts() as checkpoint:
            Finalised()                  # collected at once: SIGTERM arrives inside __del__
            ran_on = True
            checkpoint()
            ran_on = False
    assert ran_on and raised.value.signum == signal.SIGTERM
    assert capfd.readouterr().err == ""                      # no "Exception ignored ... Traceback"

    with pytest.raises(Terminated):      # without a checkpoint, the block raises it when it ends
        with signals_as_interrupts():
            Finalised()


def test_ctrl_c_seen_by_the_interpreters_code_runner_does_not_override_the_exit_status(tmp_path):
    """Run as ``python -m`` (as ``python -m motorid`` is), the interpreter ends with SIGINT (status -2)
    whatever the program returns once a bare KeyboardInterrupt has passed through its C code runner;
    ours is a subclass, which it does not mark."""
    (tmp_path / "runner_probe.py").write_text(
        "import ctypes, sys\nfrom motorid.interrupts import exit_status, signals_as_interrupts\n"
        "try:\n"
        "    with signals_as_interrupts():\n"
        "        ctypes.pythonapi.PyRun_SimpleString(b'import signal; signal.raise_signal(signal.SIGINT)')\n"
        "except KeyboardInterrupt as exc:\n"
        "    sys.exit(exit_status(exc))\n")
    proc = subprocess.run([sys.executable, "-m", "runner_probe"], capture_output=True, text=True, cwd=tmp_path,
                          env={**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), str(tmp_path)])})
    assert proc.returncode == 130, (proc.returncode, proc.stderr)


@pytest.mark.parametrize("where", ["imports", "command"])
def test_an_interrupt_an_extension_turns_into_another_error_ends_as_the_interrupt(monkeypatch, tmp_path, capsys,
                                                                                    where):
    """numpy's C start-up reports a signal that hits it as an ImportError; it is still SIGTERM, status 143."""
    import motorid.cli

    def numpy_like():
        try:
            signal.raise_signal(signal.SIGTERM)
        except KeyboardInterrupt:
            raise ImportError("Importing the numpy C-extensions failed") from None

    def load():
        if where == "imports":
            numpy_like()
        return (lambda parser: None), (lambda args: numpy_like())
    monkeypatch.setattr(motorid.cli, "COMMANDS", {"probe": motorid.cli.Command("a probe", load)})
    assert motorid.cli.main(["probe"]) == 143
    err = capsys.readouterr().err
    assert err == "motorid: interrupted (SIGTERM)\n", err

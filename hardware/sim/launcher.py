"""Run the bench firmware in the simavr emulator and talk to it through a pseudo-terminal.

``avr-sim://?a=25&b=3`` is a port URL (``hardware/ports.py``): :func:`open_avr_sim` builds the
firmware and the harness when needed (``make firmware avr-sim``), starts
``hardware/sim/build/motorid-avr-sim`` with the motor from the URL, opens the harness's
pseudo-terminal with pyserial and, on exit, closes it and stops the harness.

URL query keys (all optional):

``a``, ``b``, ``friction``
    The harness's motor ``d omega/dt + a omega = b u - friction sign(omega)`` (defaults 25, 3, 0).
``counts_per_rev``
    Encoder counts per revolution with 4x decoding (default 16667).
``encoder_rate``
    Turn the encoder at this many counts/s whatever the duty (measures the encoder ceiling).
``driver``
    ``dir-pwm`` (default) or ``in1-in2``: the H-bridge wiring (the firmware is built to match).
``speed``
    Largest ratio of emulated to wall-clock time (default 1.0; 0 runs free).  The host's
    heartbeats follow the wall clock and the firmware's host-silence watchdog counts emulated
    time, so capping emulation at real time keeps the watchdog honest.
``substep_cycles``
    CPU cycles per motor integration step (default 16, i.e. 1 us).
``boot_delay``
    The AVR starts when the host opens the pty (an Uno resets when its port is opened), this
    many seconds later (default 0.05), so the host's open cannot flush the BOOT frame.

The firmware's baud rate and H-bridge type are fixed when it is compiled: a ``baudrate`` other
than 250000 or ``driver=in1-in2`` use a firmware built with ``-DBAUD_RATE=...`` /
``-DDRIVER_TYPE=DRIVER_IN1_IN2`` in ``hardware/firmware/build/<variant>/``.
"""
from __future__ import annotations

import contextlib
import dataclasses
import math
import os
import select
import signal
import subprocess
import time
from pathlib import Path
from typing import Iterator, Mapping
from urllib.parse import parse_qsl, urlsplit

import serial

__all__ = ["open_avr_sim", "AvrSimulation", "HarnessOptions", "parse_avr_sim_url", "build",
           "firmware_elf", "SUPPORTED_BAUDRATES", "DEFAULT_BAUDRATE", "REPO_ROOT"]

#: The repository root (the harness and firmware are built from the source tree).
REPO_ROOT = Path(__file__).resolve().parents[2]
#: Baud rates the firmware can be built for (exact or within 2.1 % at 16 MHz).
SUPPORTED_BAUDRATES = (57600, 115200, 230400, 250000, 500000, 1000000)
#: The firmware's default (``config.h``), also ``SerialRig``'s default.
DEFAULT_BAUDRATE = 250000

_HARNESS = REPO_ROOT / "hardware" / "sim" / "build" / "motorid-avr-sim"
_SOURCES = [REPO_ROOT / "hardware" / "firmware" / "motorid_bench" / name
            for name in ("motorid_bench.ino", "config.h", "sine_table.h")]
_HARNESS_SOURCES = [REPO_ROOT / "hardware" / "sim" / "motorid_avr_sim.c"]
_STARTUP_TIMEOUT = 10.0
_STOP_TIMEOUT = 5.0


@dataclasses.dataclass(frozen=True)
class HarnessOptions:
    """The harness's motor and encoder.

    Parameters
    ----------
    a, b : float
        Motor ``d omega/dt + a omega = b u`` in 1/s and (rad/s^2) per duty unit.
    friction : float
        Coulomb friction in rad/s^2 (>= 0).
    counts_per_rev : float
        Encoder counts per revolution with x4 decoding.
    encoder_rate : float
        If nonzero, the encoder turns at this many x4 counts/s whatever the duty.
    driver : {"dir-pwm", "in1-in2"}
        H-bridge wiring; the firmware is built to match.
    speed : float
        Largest ratio of emulated to wall-clock time (0 runs free).
    substep_cycles : int
        CPU cycles per motor integration step (16 = 1 us).
    boot_delay : float
        Seconds between the host opening the pty and the AVR starting (0...10), as an Uno
        boots when its port is opened.
    """

    a: float = 25.0
    b: float = 3.0
    friction: float = 0.0
    counts_per_rev: float = 16667.0
    encoder_rate: float = 0.0
    driver: str = "dir-pwm"
    speed: float = 1.0
    substep_cycles: int = 16
    boot_delay: float = 0.05

    def __post_init__(self):
        for name in ("a", "b", "friction", "counts_per_rev", "encoder_rate", "speed", "boot_delay"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ValueError(f"{name} must be a finite number, got {value!r}")
        if self.a <= 0:
            raise ValueError(f"a must be > 0 (1/s), got {self.a!r}")
        if self.friction < 0:
            raise ValueError(f"friction must be >= 0 (rad/s^2), got {self.friction!r}")
        if self.counts_per_rev <= 0:
            raise ValueError(f"counts_per_rev must be > 0, got {self.counts_per_rev!r}")
        if self.speed < 0:
            raise ValueError(f"speed must be >= 0 (0 runs free), got {self.speed!r}")
        if not 0 <= self.boot_delay <= 10:
            raise ValueError(f"boot_delay must be in 0...10 s, got {self.boot_delay!r}")
        if self.driver not in ("dir-pwm", "in1-in2"):
            raise ValueError(f"driver must be 'dir-pwm' or 'in1-in2', got {self.driver!r}")
        if not 1 <= int(self.substep_cycles) <= 16000 or int(self.substep_cycles) != self.substep_cycles:
            raise ValueError(f"substep_cycles must be an integer in 1...16000, got {self.substep_cycles!r}")

    def argv(self) -> list[str]:
        """Command-line options for ``motorid-avr-sim``."""
        return ["--a", repr(float(self.a)), "--b", repr(float(self.b)),
                "--friction", repr(float(self.friction)),
                "--counts-per-rev", repr(float(self.counts_per_rev)),
                "--encoder-rate", repr(float(self.encoder_rate)), "--driver", self.driver,
                "--speed", repr(float(self.speed)), "--substep-cycles", str(int(self.substep_cycles)),
                "--boot-delay", repr(float(self.boot_delay))]


def parse_avr_sim_url(url: str) -> HarnessOptions:
    """Read :class:`HarnessOptions` from a URL such as ``avr-sim://?a=25&b=3``.

    Parameters
    ----------
    url : str
        ``avr-sim://`` and a query of :class:`HarnessOptions` fields (``-`` may stand for ``_``).

    Raises
    ------
    ValueError
        If the scheme is not ``avr-sim``, a key is unknown or a value is not a number.
    """
    if not isinstance(url, str):
        raise TypeError(f"url must be a str, got {type(url).__name__}")
    parts = urlsplit(url)
    if parts.scheme != "avr-sim":
        raise ValueError(f"url must start with 'avr-sim://', got {url!r}")
    fields = {f.name: f for f in dataclasses.fields(HarnessOptions)}
    values: dict[str, object] = {}
    for key, text in parse_qsl(parts.query, keep_blank_values=True, strict_parsing=False):
        key = key.replace("-", "_")
        if key not in fields:
            raise ValueError(f"avr-sim URL key must be one of {sorted(fields)}, got {key!r} in {url!r}")
        if key == "driver":
            values[key] = text
            continue
        try:
            number = float(text)
        except ValueError:
            raise ValueError(f"avr-sim URL key {key!r} must be a number, got {text!r}") from None
        values[key] = int(number) if key == "substep_cycles" and number.is_integer() else number
    return HarnessOptions(**values)


def _check_baudrate(baudrate: int) -> int:
    if isinstance(baudrate, bool) or not isinstance(baudrate, int) or baudrate not in SUPPORTED_BAUDRATES:
        raise ValueError(f"baudrate must be one of {SUPPORTED_BAUDRATES}, got {baudrate!r}")
    return baudrate


_DRIVERS = {"dir-pwm": "DRIVER_DIR_PWM", "in1-in2": "DRIVER_IN1_IN2"}


def _variant(baudrate: int, driver: str) -> tuple[str, list[str]]:
    """Build sub-directory and -D flags of a firmware variant ("" for the default build)."""
    _check_baudrate(baudrate)
    if driver not in _DRIVERS:
        raise ValueError(f"driver must be one of {sorted(_DRIVERS)}, got {driver!r}")
    parts, defs = [], []
    if baudrate != DEFAULT_BAUDRATE:
        parts.append(f"baud{baudrate}")
        defs.append(f"-DBAUD_RATE={baudrate}")
    if driver != "dir-pwm":
        parts.append(driver)
        defs.append(f"-DDRIVER_TYPE={_DRIVERS[driver]}")
    return "-".join(parts), defs


def firmware_elf(baudrate: int = DEFAULT_BAUDRATE, driver: str = "dir-pwm") -> Path:
    """Path of the firmware ELF built for ``baudrate`` and the H-bridge ``driver``.

    Parameters
    ----------
    baudrate : int
        One of :data:`SUPPORTED_BAUDRATES`.
    driver : {"dir-pwm", "in1-in2"}
        H-bridge type the firmware is built for.
    """
    sub, _ = _variant(baudrate, driver)
    build = REPO_ROOT / "hardware" / "firmware" / "build"
    return (build / sub if sub else build) / "motorid_bench.elf"


def _stale(target: Path, sources: list[Path]) -> bool:
    if not target.exists():
        return True
    built = target.stat().st_mtime
    return any(src.stat().st_mtime > built for src in sources)


def build(baudrate: int = DEFAULT_BAUDRATE, driver: str = "dir-pwm") -> tuple[Path, Path]:
    """Build the firmware (for ``baudrate`` and ``driver``) and the harness when missing or stale.

    Runs ``make firmware avr-sim`` in the repository, which apt-installs the Debian packages
    when they are missing.

    Parameters
    ----------
    baudrate : int
        One of :data:`SUPPORTED_BAUDRATES`.
    driver : {"dir-pwm", "in1-in2"}
        H-bridge type the firmware is built for.

    Returns
    -------
    (elf, harness) : tuple of Path
    """
    sub, defs = _variant(baudrate, driver)
    elf = firmware_elf(baudrate, driver)
    if not (REPO_ROOT / "hardware" / "avr.mk").exists():
        raise FileNotFoundError(f"avr-sim needs the motorid source tree (hardware/avr.mk) under {REPO_ROOT}")
    targets = []
    if _stale(elf, _SOURCES):
        targets.append("firmware")
    if _stale(_HARNESS, _HARNESS_SOURCES):
        targets.append("avr-sim")
    if targets:
        cmd = ["make", "--no-print-directory", "-s", "-C", str(REPO_ROOT), *targets]
        if sub:
            cmd += [f"FIRMWARE_BUILD={elf.parent.relative_to(REPO_ROOT)}", f"FIRMWARE_DEFS={' '.join(defs)}"]
        done = subprocess.run(cmd, capture_output=True, text=True)
        if done.returncode != 0:
            raise RuntimeError(f"building the AVR firmware/harness failed ({' '.join(cmd)}):\n"
                               f"{done.stdout[-2000:]}{done.stderr[-2000:]}")
    return elf, _HARNESS


class AvrSimulation:
    """The harness process running the firmware, with its pseudo-terminal.

    Use as a context manager; :attr:`port_path` is the pty, :attr:`stats` (after exit) holds
    the harness's last words: ``emulated_s``, ``wall_s``, ``ratio``, ``counts`` (what the
    encoder pins showed, 4x), ``edges``, ``resets``, ``speed_rad_s``.

    Parameters
    ----------
    options : HarnessOptions
        Motor and encoder of the harness.
    baudrate : int
        The firmware's baud rate (selects the firmware build).
    """

    def __init__(self, options: HarnessOptions | None = None, baudrate: int = DEFAULT_BAUDRATE):
        if options is not None and not isinstance(options, HarnessOptions):
            raise TypeError(f"options must be HarnessOptions, got {type(options).__name__}")
        self.options = options or HarnessOptions()
        self.baudrate = _check_baudrate(baudrate)
        self.port_path: str | None = None
        self.stats: Mapping[str, float] = {}
        self._process: subprocess.Popen | None = None

    def start(self) -> str:
        """Build if needed, start the harness and return its pty path."""
        elf, harness = build(self.baudrate, self.options.driver)
        self._process = subprocess.Popen([str(harness), str(elf), *self.options.argv()],
                                         stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                         stderr=subprocess.PIPE, text=True)
        # Read the raw pipe (a buffered readline would hide lines from select()).
        fd = self._process.stdout.fileno()
        deadline = time.monotonic() + _STARTUP_TIMEOUT
        text = b""
        while True:
            for line in text.split(b"\n")[:-1]:
                if line.startswith(b"PTY "):
                    self.port_path = line[4:].strip().decode()
                    return self.port_path
            remaining = deadline - time.monotonic()
            ready, _, _ = select.select([fd], [], [], max(remaining, 0))
            if not ready:
                self.stop()
                raise TimeoutError(f"motorid-avr-sim printed no PTY line within {_STARTUP_TIMEOUT} s")
            chunk = os.read(fd, 4096)
            if not chunk:
                err = self._process.stderr.read()
                self.stop()
                raise RuntimeError(f"motorid-avr-sim exited before opening its pty: {err.strip()}")
            text += chunk

    def hang_firmware(self) -> None:
        """Make the firmware hang (an endless loop, interrupts on), as a bug in ``loop()`` would.

        The AVR watchdog, no longer fed, resets the chip; the firmware boots again and sends
        BOOT with ``reset_cause`` bit 3.
        """
        if self._process is None or self._process.poll() is not None:
            raise RuntimeError("the harness is not running")
        self._process.send_signal(signal.SIGUSR1)

    def stop(self) -> Mapping[str, float]:
        """Stop the harness (SIGTERM, then SIGKILL) and return its final statistics."""
        proc, self._process = self._process, None
        if proc is None:
            return self.stats
        if proc.poll() is None:
            proc.terminate()
        try:
            out, _ = proc.communicate(timeout=_STOP_TIMEOUT)
        except subprocess.TimeoutExpired:
            proc.kill()
            out, _ = proc.communicate()
        stats: dict[str, float] = {}
        for line in out.splitlines():
            if line.startswith("STATS "):
                for item in line.split()[1:]:
                    key, _, value = item.partition("=")
                    stats[key] = float(value)
        self.stats = stats
        return stats

    def __enter__(self) -> "AvrSimulation":
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()


@contextlib.contextmanager
def open_avr_sim(url: str, baudrate: int = DEFAULT_BAUDRATE, timeout: float = 1.0) -> Iterator[serial.Serial]:
    """Open ``avr-sim://?...`` as a pyserial port connected to the emulated firmware.

    Parameters
    ----------
    url : str
        ``avr-sim://`` plus an optional query (see the module docstring).
    baudrate : int
        Must be one of :data:`SUPPORTED_BAUDRATES`; selects the firmware build.
    timeout : float
        Read timeout of the port in s.

    Yields
    ------
    serial.Serial
        The open port. Its attribute ``avr_simulation`` is the :class:`AvrSimulation`, whose
        ``stats`` are filled in when the context exits.
    """
    options = parse_avr_sim_url(url)
    sim = AvrSimulation(options, baudrate)
    path = sim.start()
    try:
        port = serial.Serial(path, baudrate, timeout=timeout)
    except BaseException:
        sim.stop()
        raise
    port.avr_simulation = sim
    try:
        yield port
    finally:
        port.close()
        sim.stop()

"""Run the bench firmware in the simavr emulator and talk to it through a pseudo-terminal.

``avr-sim://?a=25&b=3`` is a port URL (``hardware/ports.py``): :func:`open_avr_sim` builds the
firmware and the harness when needed (``make firmware avr-sim``), starts
``hardware/sim/build/motorid-avr-sim`` with the motor from the URL and, on exit, stops it.

By default the emulated AVR runs in lock-step with the host (:mod:`hardware.lockstep`): its
cycles advance only as the host reads, over a socket to the harness, so a run gives the same
recording on an idle and on a loaded machine, and a slow machine only makes it take longer.
``realtime=1`` runs it against the wall clock instead, on a pseudo-terminal opened with
pyserial, as a board on a USB port: what that proves (the host keeping up with the firmware's
real deadlines) depends on the machine, and a loaded one can fail it.

URL query keys (all optional; :func:`url_keys`):

``a``, ``b``, ``friction``
    The harness's motor ``d omega/dt + a omega = b u - friction sign(omega)`` (defaults 25, 3, 0),
    named and parsed as the bench knobs of ``motorsim.Motor``.
``counts_per_rev``
    Encoder counts per revolution with 4x decoding, an integer (default 16667).
``encoder_rate``
    Turn the encoder at this many counts/s whatever the duty (measures the encoder ceiling).
``driver``
    ``dir-pwm`` (default) or ``in1-in2``: the H-bridge wiring (the firmware is built to match).
``speed``
    Largest ratio of emulated to wall-clock time (default 1.0, a board's pace; 0 runs free, as
    fast as the machine goes).  In lock-step the host paces itself; with ``realtime=1`` the
    harness does, and there the host's heartbeats follow the wall clock while the firmware's
    host-silence watchdog counts emulated time, so capping emulation at real time keeps the
    watchdog honest.
``realtime``
    ``1`` (or ``true``): the emulated AVR on the wall clock, on a pseudo-terminal (default
    ``0``: in lock-step with the host, in simulated time).
``substep_cycles``
    CPU cycles per motor integration step (default 16, i.e. 1 us).
``boot_delay``
    With ``realtime=1``, the AVR starts when the host opens the pty (an Uno resets when its port
    is opened), this many seconds later (default 0.05), so the host's open cannot flush the BOOT
    frame.  In lock-step the AVR starts at the port's first read, and this key is not used.

The firmware's baud rate and H-bridge type are fixed when it is compiled: a ``baudrate`` other
than 250000 or ``driver=in1-in2`` use a firmware built with ``-DBAUD_RATE=...`` /
``-DDRIVER_TYPE=DRIVER_IN1_IN2`` in ``hardware/firmware/build/<variant>/``.
"""
from __future__ import annotations

import contextlib
import dataclasses
import functools
import math
import os
import select
import shutil
import signal
import socket
import struct
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Iterator, Mapping
from urllib.parse import parse_qsl, urlsplit

import serial

from motorsim.checks import ParameterError, ParameterTypeError, check_choice, check_int, check_real
from motorsim.knobs import Knob, knob, knobs_of
from motorsim.rig import bench_knobs
from motorsim.sensors import DEFAULT_COUNTS_PER_REV

from ..lockstep import LockstepPort

__all__ = ["open_avr_sim", "die_with_parent", "url_keys", "missing_tools", "ARDUINO_CORE", "AvrSimulation",
           "AvrLockstepPort", "HarnessOptions", "parse_avr_sim_url", "build", "F_CPU_HZ",
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
_PR_SET_PDEATHSIG = 1       # <linux/prctl.h>
#: The emulated ATmega328P's clock (an Uno's).
F_CPU_HZ = 16_000_000
#: Bytes of host input one lock-step grant carries at most (the harness's UART queue holds 4096).
_GRANT_BYTES = 1024
#: H-bridge wiring -> the firmware's DRIVER_TYPE.
_DRIVERS = {"dir-pwm": "DRIVER_DIR_PWM", "in1-in2": "DRIVER_IN1_IN2"}


@dataclasses.dataclass(frozen=True)
class HarnessOptions:
    """The harness's motor and encoder.

    Parameters
    ----------
    a, b : float
        Motor ``d omega/dt + a omega = b u`` in 1/s and (rad/s^2) per duty unit.
    friction : float
        Coulomb friction in rad/s^2 (>= 0).
    counts_per_rev : int
        Encoder counts per revolution with x4 decoding.
    encoder_rate : float
        If nonzero, the encoder turns at this many x4 counts/s whatever the duty.
    driver : {"dir-pwm", "in1-in2"}
        H-bridge wiring; the firmware is built to match.
    speed : float
        Largest ratio of emulated to wall-clock time (0 runs free).
    realtime : bool
        Run against the wall clock on a pseudo-terminal (default False: in lock-step with the
        host, in simulated time).
    substep_cycles : int
        CPU cycles per motor integration step (16 = 1 us).
    boot_delay : float
        Seconds between the host opening the pty and the AVR starting (0...10), as an Uno
        boots when its port is opened.
    """

    a: float = 25.0
    b: float = 3.0
    friction: float = 0.0
    counts_per_rev: int = DEFAULT_COUNTS_PER_REV
    encoder_rate: float = knob(0.0, unit="counts/s", help="turn the encoder at this rate whatever the duty")
    driver: str = "dir-pwm"
    speed: float = knob(1.0, unit="", help="largest ratio of emulated to wall-clock time (0 runs free)")
    realtime: bool = knob(False, unit="", help="on the wall clock, on a pseudo-terminal (default: in lock-step "
                                               "with the host, in simulated time)")
    substep_cycles: int = knob(16, unit="cycles", help="CPU cycles per motor integration step")
    boot_delay: float = knob(0.05, unit="s", help="time between opening the pty and the AVR starting")

    def __post_init__(self):
        for name in ("a", "b", "friction", "encoder_rate", "speed", "boot_delay"):
            object.__setattr__(self, name, check_real(name, getattr(self, name)))
        check_real("a", self.a, positive=True)
        check_real("friction", self.friction, nonnegative=True)
        object.__setattr__(self, "counts_per_rev", check_int("counts_per_rev", self.counts_per_rev, 1, 2**31 - 1))
        check_real("speed", self.speed, nonnegative=True)
        if not 0 <= self.boot_delay <= 10:
            raise ParameterError(f"boot_delay must be in 0...10 s, got {self.boot_delay!r}")
        check_choice("driver", self.driver, _DRIVERS)
        if not isinstance(self.realtime, bool):
            raise ParameterTypeError(f"realtime must be a bool, got {self.realtime!r}")
        object.__setattr__(self, "substep_cycles", check_int("substep_cycles", self.substep_cycles, 1, 16000))

    def argv(self) -> list[str]:
        """Command-line options for ``motorid-avr-sim`` (in real time; lock-step adds ``--lockstep-fd``)."""
        return ["--a", repr(float(self.a)), "--b", repr(float(self.b)),
                "--friction", repr(float(self.friction)),
                "--counts-per-rev", str(int(self.counts_per_rev)),
                "--encoder-rate", repr(float(self.encoder_rate)), "--driver", self.driver,
                "--speed", repr(float(self.speed)), "--substep-cycles", str(int(self.substep_cycles)),
                "--boot-delay", repr(float(self.boot_delay))]


def _url_knobs() -> dict[str, Knob]:
    """The numeric keys: the bench knobs the harness has, then its own."""
    names = {f.name for f in dataclasses.fields(HarnessOptions)}
    bench = {k.name: k for k in bench_knobs() if k.name in names}
    return {**bench, **{k.name: k for k in knobs_of(HarnessOptions)}}


def url_keys() -> tuple[str, ...]:
    """The query keys of ``avr-sim://`` (the fields of :class:`HarnessOptions`).

    Examples
    --------
    >>> url_keys()[:4]
    ('a', 'b', 'friction', 'counts_per_rev')
    """
    return tuple(f.name for f in dataclasses.fields(HarnessOptions))


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

    Examples
    --------
    >>> parse_avr_sim_url("avr-sim://?a=30&counts_per_rev=2000").counts_per_rev
    2000
    """
    if not isinstance(url, str):
        raise ParameterTypeError(f"url must be a str, got {type(url).__name__}")
    parts = urlsplit(url)
    if parts.scheme != "avr-sim":
        raise ParameterError(f"url must start with 'avr-sim://', got {url!r}")
    keys, knobs = url_keys(), _url_knobs()
    values: dict[str, Any] = {}
    for key, text in parse_qsl(parts.query, keep_blank_values=True, strict_parsing=False):
        key = key.replace("-", "_")
        if key not in keys:
            raise ParameterError(f"avr-sim URL key must be one of {sorted(keys)}, got {key!r} in {url!r}")
        try:
            values[key] = knobs[key].parse(text) if key in knobs else text
        except ValueError as exc:
            raise ParameterError(f"avr-sim URL key {exc}") from None
    return HarnessOptions(**values)


def _check_baudrate(baudrate: int) -> int:
    if check_int("baudrate", baudrate, allow_integral_float=False) not in SUPPORTED_BAUDRATES:
        raise ParameterError(f"baudrate must be one of {SUPPORTED_BAUDRATES}, got {baudrate!r}")
    return baudrate


def _variant(baudrate: int, driver: str) -> tuple[str, list[str]]:
    """Build sub-directory and -D flags of a firmware variant ("" for the default build)."""
    _check_baudrate(baudrate)
    if driver not in _DRIVERS:
        raise ParameterError(f"driver must be one of {sorted(_DRIVERS)}, got {driver!r}")
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


#: What building the firmware and the harness needs: programs on PATH, and pkg-config's simavr.
_TOOLS = ("make", "cc", "avr-gcc", "avr-g++", "avr-ar", "avr-objcopy", "avr-size", "pkg-config")
#: The Arduino core the Makefile compiles (Debian's arduino-core-avr).
ARDUINO_CORE = Path("/usr/share/arduino/hardware/arduino/avr")


def missing_tools() -> list[str]:
    """What is missing to build the firmware and the harness (empty when everything is there).

    ``make firmware-deps`` installs the Debian packages that provide them.
    """
    missing = [tool for tool in _TOOLS if shutil.which(tool) is None]
    if shutil.which("pkg-config") is not None and subprocess.run(
            ["pkg-config", "--exists", "simavr"], capture_output=True).returncode != 0:
        missing.append("simavr (pkg-config: libsimavr-dev)")
    if not (ARDUINO_CORE / "cores" / "arduino").is_dir():
        missing.append(f"the Arduino core in {ARDUINO_CORE} (arduino-core-avr)")
    return missing


def build(baudrate: int = DEFAULT_BAUDRATE, driver: str = "dir-pwm") -> tuple[Path, Path]:
    """Build the firmware (for ``baudrate`` and ``driver``) and the harness when missing or stale.

    Runs ``make firmware avr-sim`` in the repository without installing anything: when a tool
    is missing (:func:`missing_tools`) it raises, naming it and ``make firmware-deps``.

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
        missing = missing_tools()
        if missing:
            raise RuntimeError(f"building the AVR firmware/harness needs {', '.join(missing)}; "
                               f"install them with 'make firmware-deps'")
        cmd = ["make", "--no-print-directory", "-s", "-C", str(REPO_ROOT), *targets, "FIRMWARE_DEPS="]
        if sub:
            cmd += [f"FIRMWARE_BUILD={elf.parent.relative_to(REPO_ROOT)}", f"FIRMWARE_DEFS={' '.join(defs)}"]
        done = subprocess.run(cmd, capture_output=True, text=True)
        if done.returncode != 0:
            raise RuntimeError(f"building the AVR firmware/harness failed ({' '.join(cmd)}):\n"
                               f"{done.stdout[-2000:]}{done.stderr[-2000:]}")
    return elf, _HARNESS


def die_with_parent(parent_pid: int) -> None:
    """In a child about to run the harness: be sent SIGTERM when the parent dies, even by SIGKILL.

    Linux's ``prctl(PR_SET_PDEATHSIG)``, through ``ctypes`` (run between ``fork`` and
    ``exec``; the setting survives ``exec``).  A parent that died before it took effect is
    seen by the parent pid no longer being ``parent_pid``, and the child ends at once.  Elsewhere nothing
    is done here; the harness itself also ends when its parent pid changes (its parent died), on
    every system, within a few milliseconds of emulation.
    """
    if not sys.platform.startswith("linux"):
        return
    import ctypes
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)
    except (OSError, AttributeError):     # pragma: no cover - every Linux libc has prctl
        return
    if os.getppid() != parent_pid:
        os._exit(1)


class AvrSimulation:
    """The harness process running the firmware, with its pseudo-terminal.

    Use as a context manager.  With ``options.realtime``, :attr:`port_path` is the pty; else
    :attr:`lockstep_socket` is the host's end of the lock-step exchange (:class:`AvrLockstepPort`
    speaks it).  :attr:`stats` (after exit) holds
    the harness's last words: ``emulated_s``, ``wall_s``, ``ratio``, ``counts`` (what the
    encoder pins showed, 4x), ``edges``, ``resets``, ``speed_rad_s``, ``unwatched_drive_changes`` (drive
    changes no register write announced, so applied from the middle of their microsecond).

    Parameters
    ----------
    options : HarnessOptions
        Motor and encoder of the harness.
    baudrate : int
        The firmware's baud rate (selects the firmware build).
    """

    def __init__(self, options: HarnessOptions | None = None, baudrate: int = DEFAULT_BAUDRATE):
        if options is not None and not isinstance(options, HarnessOptions):
            raise ParameterTypeError(f"options must be HarnessOptions, got {type(options).__name__}")
        self.options = options or HarnessOptions()
        self.baudrate = _check_baudrate(baudrate)
        self.port_path: str | None = None
        self.lockstep_socket: socket.socket | None = None
        self.stats: Mapping[str, float] = {}
        self._process: subprocess.Popen | None = None

    def start(self) -> str:
        """Build if needed, start the harness; returns its pty path (real time) or ``"lockstep"``."""
        elf, harness = build(self.baudrate, self.options.driver)
        argv = [str(harness), str(elf), *self.options.argv()]
        pass_fds: tuple[int, ...] = ()
        theirs = None
        if not self.options.realtime:
            self.lockstep_socket, theirs = socket.socketpair()
            argv += ["--lockstep-fd", str(theirs.fileno())]
            pass_fds = (theirs.fileno(),)
        try:
            process = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                       stderr=subprocess.PIPE, text=True, pass_fds=pass_fds,
                                       preexec_fn=functools.partial(die_with_parent, os.getpid()))
        except BaseException:
            self._close_socket()
            raise
        finally:
            if theirs is not None:
                theirs.close()
        self._process = process
        try:
            return self._read_pty_path(process)
        except BaseException:      # including Ctrl-C or SIGTERM while it starts: never leave it running
            self.stop()
            raise

    def _close_socket(self) -> None:
        sock, self.lockstep_socket = self.lockstep_socket, None
        if sock is not None:
            sock.close()

    def _read_pty_path(self, process: subprocess.Popen) -> str:
        stdout, stderr = process.stdout, process.stderr
        if stdout is None or stderr is None:   # pragma: no cover - PIPE always gives both
            raise RuntimeError("motorid-avr-sim was started without its output pipes")
        # Read the raw pipe (a buffered readline would hide lines from select()).
        fd = stdout.fileno()
        deadline = time.monotonic() + _STARTUP_TIMEOUT
        text = b""
        while True:
            for line in text.split(b"\n")[:-1]:
                if line.startswith(b"PTY "):
                    self.port_path = line[4:].strip().decode()
                    return self.port_path
                if line.strip() == b"LOCKSTEP":
                    return "lockstep"
            remaining = deadline - time.monotonic()
            ready, _, _ = select.select([fd], [], [], max(remaining, 0))
            if not ready:
                self.stop()
                raise TimeoutError(f"motorid-avr-sim printed no PTY or LOCKSTEP line within {_STARTUP_TIMEOUT} s")
            chunk = os.read(fd, 4096)
            if not chunk:
                err = stderr.read()
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
        self._close_socket()       # in lock-step the harness ends when its host's socket closes
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
    AvrLockstepPort or serial.Serial
        The open port: in lock-step (the default) an :class:`AvrLockstepPort`, with ``realtime=1``
        a ``serial.Serial`` on the harness's pty.  Its attribute ``avr_simulation`` is the
        :class:`AvrSimulation`, whose ``stats`` are filled in when the context exits.
    """
    options = parse_avr_sim_url(url)
    sim = AvrSimulation(options, baudrate)
    path = sim.start()
    port: Any
    try:
        if options.realtime:
            port = serial.Serial(path, baudrate, timeout=timeout)
        else:
            port = AvrLockstepPort(sim, url, timeout, options.speed)
    except BaseException:
        sim.stop()
        raise
    port.avr_simulation = sim
    try:
        yield port
    finally:
        port.close()
        sim.stop()


class AvrLockstepPort(LockstepPort):
    """The emulated AVR in lock-step with the host (:class:`hardware.lockstep.LockstepPort`).

    Speaks the harness's lock-step exchange (``hardware/sim/motorid_avr_sim.c``) over
    :attr:`AvrSimulation.lockstep_socket`: each grant carries what the host wrote and the CPU
    cycle to run to; each answer the cycle reached and what the UART sent.

    Parameters
    ----------
    simulation : AvrSimulation
        A started harness in lock-step mode.
    name : str
        The port's name (its URL).
    timeout : float or None
        Read timeout in emulated seconds.
    speed : float
        Largest ratio of emulated to wall-clock time (0: as fast as the machine goes).
    """

    def __init__(self, simulation: AvrSimulation, name: str, timeout: float | None, speed: float):
        if simulation.lockstep_socket is None:
            raise ParameterError("simulation must be a started AvrSimulation in lock-step mode (realtime off)")
        super().__init__(name, timeout, speed)
        self.avr_simulation = simulation
        self._socket = simulation.lockstep_socket
        self._cycle = 0
        self._inbox = bytearray()           # the harness's answers, as received
        self._next_id = 0
        self._awaiting: int | None = None   # the grant whose answer has not been read

    def _exchange(self, until: float, stop_on_frame: bool) -> float:
        if self._awaiting is not None:        # an exchange cut short (Ctrl-C, SIGTERM): finish it first
            self._grant(self._cycle, b"", False)
        target = max(self._cycle, math.ceil(until * F_CPU_HZ - 1e-6))
        data = self._take_written()
        while len(data) > _GRANT_BYTES:       # a long write goes in pieces, at this same cycle
            self._grant(self._cycle, data[:_GRANT_BYTES], False)
            data = data[_GRANT_BYTES:]
        self._grant(target, data, stop_on_frame)
        now = self._cycle / F_CPU_HZ
        return max(now, until) if self._cycle >= target else now

    def _grant(self, until_cycle: int, data: bytes, stop_on_frame: bool) -> None:
        """One exchange: the grant sent, the answers read up to its own (an interrupted one's first)."""
        grant = self._next_id
        self._next_id = (grant + 1) & 0xFFFFFFFF
        self._awaiting = grant
        try:
            self._socket.sendall(struct.pack("<QIII", until_cycle, int(stop_on_frame), grant, len(data)) + data)
            while True:
                cycle, state, answered = self._answer()
                self._cycle = cycle
                if state in _CPU_ENDED:
                    raise serial.SerialException(f"the emulated AVR behind {self.name} stopped "
                                                 f"({_CPU_ENDED[state]}) at cycle {cycle}")
                if answered == grant:
                    break
        except OSError as exc:
            raise serial.SerialException(f"the emulator behind {self.name} failed: {exc}") from None
        self._awaiting = None

    def _answer(self) -> tuple[int, int, int]:
        """One answer from the harness: its UART bytes appended to what the host reads; (cycle, state, id)."""
        self._fill(20)
        cycle, state, answered, n = struct.unpack_from("<QIII", self._inbox)
        self._fill(20 + n)
        self._rx += self._inbox[20:20 + n]
        del self._inbox[:20 + n]
        return cycle, state, answered

    def _fill(self, n: int) -> None:
        while len(self._inbox) < n:
            chunk = self._socket.recv(1 << 16)
            if not chunk:
                raise serial.SerialException(f"the emulator behind {self.name} exited")
            self._inbox += chunk


#: simavr's cpu states that end an emulation (``sim_avr.h``: cpu_Done 6, cpu_Crashed 7).
_CPU_ENDED = {6: "done", 7: "crashed"}

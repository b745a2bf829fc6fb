"""An emulated bench Arduino: speaks ``hardware/PROTOCOL.md`` over a pseudo-terminal, drives a simulated motor.

:class:`FakeDevice` opens a pty pair (``os.openpty``, both ends raw), runs the
firmware's behaviour in a background thread on the master end, and offers the
slave end's path (:attr:`FakeDevice.port_name`) to anything that opens serial
ports: ``serial.Serial(dev.port_name)``, :class:`~hardware.serial_rig.SerialRig`,
or ``motorid live --port 'fake://?a=25&b=3'`` (see :func:`open_fake`).

What it emulates, as the firmware does it
-----------------------------------------
- BOOT after (optional) time in the bootloader; HELLO -> HELLO_ACK; CONFIG, WAVE,
  START answered by ACK or NAK with the documented reasons and ranges; STOP;
  HEARTBEAT; the host-silence watchdog (FAULT 1, END 2).
- The clock and the waveform on the device: tick ``k`` snapshots the encoder,
  computes ``duty_k`` from the WAVE with :func:`hardware.protocol.expand`'s
  integer arithmetic, queues a SAMPLE, and applies ``duty_k`` at tick ``k + 1``
  (``DEVICE_INPUT_DELAY``: the duty held from tick ``k`` to ``k + 1`` is ``duty_{k-1}``,
  0 at ``k = 0``) while the motor is simulated exactly over each period
  (its exact step, :class:`motorsim.plant.Stepper`).
- Closed loop (protocol v2): after a CONTROL naming a controller and a REFERENCE, tick
  ``k`` computes ``duty_k`` from the counts just read with the controller's integer step,
  :class:`motorsim.fixed_point.ControlLoop` (the reference the firmware's C step is tested against),
  applied at tick ``k + 1`` as in open loop.
- A bounded transmit queue: a sample that finds it full is dropped and counted
  (``samples_dropped``, FAULT 2 the first time), never overwritten.
- Absolute encoder counts from boot; END with the device's counters.

POSIX only (Linux, macOS): it needs ``os.openpty``.

Time: a :class:`FakeDevice` started with :meth:`FakeDevice.start` runs on the wall clock in a
thread: ``speed`` scales the device clock against it (1 = real time) and ``speed=0`` ticks as
fast as the host reads, losslessly.  ``fake://`` URLs run it in lock-step with the host instead
(:class:`FakeLockstepPort`, no thread, no pty): the device's clock is simulated time that moves
only as the host reads, so a run gives the same recording however loaded the machine is, and
``speed`` only paces it against the wall clock (0: as fast as the host goes).  ``realtime=1``
keeps the threaded device on a pty.

Fault injection (:class:`FaultPlan`) acts on the device-to-host SAMPLE frames
(bit flips, frames lost on the link, garbage bytes) and on the device itself
(queue drops, going silent, disconnecting, a watchdog trip, never answering
HELLO, another protocol version, time in the bootloader).

One concept, the emulated device, in one module although it is long: its message
handling, clock, queue and fault injection are the firmware's behaviour, which they
mirror as one piece (the URL parsing at the end only builds one).
"""
from __future__ import annotations

import contextlib
import dataclasses
import errno
import math
import os
import select
import sys
import threading
import time
import urllib.parse
from typing import Any, Iterator

import numpy as np

from motorsim.checks import ParameterError, ParameterTypeError, check_bool, check_int, check_real
from motorsim.fixed_point import ControlLoop, gains_from_wire, reference_values
from motorsim.knobs import Knob, knob, knobs_of
from motorsim.plant import Motor, Plant, Stepper, further_parameters, named_plant, registered_structures
from motorsim.ranges import check_bench_values
from motorsim.rig import bench_knobs
from motorsim.sensors import Encoder

from . import protocol as P
from .lockstep import LockstepPort

__all__ = ["FaultPlan", "FakeDevice", "FakeLockstepPort", "open_fake", "parse_fake_url", "url_keys"]

_SAMPLE_WIRE = 21


@dataclasses.dataclass(frozen=True)
class FaultPlan:
    """Faults the emulated device injects (all off by default).

    Parameters
    ----------
    flip_rate : float
        Probability that a SAMPLE frame has one random bit flipped on the wire.
    drop_rate : float
        Probability that a SAMPLE frame is lost on the link (its ``seq`` is used up).
    garbage_rate : float
        Probability that 1-8 random bytes and a 0x00 are sent before a SAMPLE frame.
    queue_drop_rate : float
        Probability that a sample is dropped on the device as if its queue were full
        (counted in END ``samples_dropped``).
    stall_at : int or None
        Sample index from which the device transmits nothing more (it keeps receiving,
        so a STOP still stops the motor).
    repeat_at : int or None
        Sample index from which the device sends that same SAMPLE again at every tick, forever
        (a device that talks but never progresses; the run never ends by itself).
    disconnect_at : int or None
        Sample index at which the device closes the link (the host sees the port fail), once the
        host has read the samples before it.
    watchdog_trip_at : int or None
        Sample index at which the device acts as if the host had gone silent.
    mute : bool
        Never answer anything (a board without the firmware).
    version : int
        Protocol version reported in HELLO_ACK and BOOT.
    boot_delay : float
        Seconds in the "bootloader" after start, ignoring input, before BOOT.
    """

    flip_rate: float = knob(0.0, unit="", help="probability that a SAMPLE frame has one bit flipped")
    drop_rate: float = knob(0.0, unit="", help="probability that a SAMPLE frame is lost on the link")
    garbage_rate: float = knob(0.0, unit="", help="probability of random bytes before a SAMPLE frame")
    queue_drop_rate: float = knob(0.0, unit="", help="probability that the device drops a sample")
    stall_at: int | None = knob(None, kind=int, unit="samples", help="sample from which the device sends nothing")
    repeat_at: int | None = knob(None, kind=int, unit="samples",
                                 help="sample the device repeats forever from then on")
    disconnect_at: int | None = knob(None, kind=int, unit="samples", help="sample at which the link closes")
    watchdog_trip_at: int | None = knob(None, kind=int, unit="samples",
                                        help="sample at which the host-silence watchdog trips")
    mute: bool = knob(False, unit="", help="never answer (a board without the firmware)")
    version: int = knob(P.PROTOCOL_VERSION, unit="", help="protocol version the device reports")
    boot_delay: float = knob(0.0, unit="s", help="time in the bootloader before BOOT")

    def __post_init__(self):
        for name in ("flip_rate", "drop_rate", "garbage_rate", "queue_drop_rate"):
            v = check_real(name, getattr(self, name), nonnegative=True)
            if v >= 1:
                raise ParameterError(f"{name} must be a probability in [0, 1), got {v!r}")
            object.__setattr__(self, name, v)
        for name in ("stall_at", "repeat_at", "disconnect_at", "watchdog_trip_at"):
            if getattr(self, name) is not None:
                object.__setattr__(self, name, check_int(name, getattr(self, name), 0, 2**32 - 1))
        object.__setattr__(self, "version", check_int("version", self.version, 0, 255))
        object.__setattr__(self, "boot_delay", check_real("boot_delay", self.boot_delay, nonnegative=True))
        object.__setattr__(self, "mute", check_bool("mute", self.mute))


class FakeDevice:
    """The emulated bench firmware on a pty; a context manager (``with FakeDevice(...) as dev``).

    Parameters
    ----------
    motor : Motor
        The simulated motor (any friction, bias, dead zone, input delay).
    encoder : Encoder, optional
        Counts per revolution (after the configured decoding), boot offset and angle noise.
    faults : FaultPlan, optional
        Faults to inject.
    speed : float, optional
        Device time per wall-clock time (1 = real time, default); 0 = as fast as the host reads.
    queue_size : int, optional
        Transmit queue in SAMPLE frames (default 16).
    rng : numpy.random.Generator, optional
        Source of angle noise and injected faults; default ``default_rng(0)``.

    Attributes
    ----------
    duty : int
        Duty applied to the motor now.
    stops_received : int
        STOP frames received.
    runs_started : int
        Runs started by START.
    last_end : hardware.protocol.End or None
        The last END sent (or that would have been sent).
    """

    def __init__(self, motor: Plant, encoder: Encoder | None = None, faults: FaultPlan | None = None, *,
                 speed: float = 1.0, queue_size: int = 16, rng: np.random.Generator | None = None):
        if not isinstance(motor, Plant):
            raise ParameterTypeError(f"motor must be a plant (a Motor), got {type(motor).__name__}")
        self.motor = motor
        self.encoder = encoder if encoder is not None else Encoder()
        if not isinstance(self.encoder, Encoder):
            raise ParameterTypeError(f"encoder must be an Encoder, got {type(self.encoder).__name__}")
        self.faults = faults if faults is not None else FaultPlan()
        if not isinstance(self.faults, FaultPlan):
            raise ParameterTypeError(f"faults must be a FaultPlan, got {type(self.faults).__name__}")
        self.speed = check_real("speed", speed, nonnegative=True)
        self.queue_size = check_int("queue_size", queue_size, 1, 10_000)
        self.rng = rng if rng is not None else np.random.default_rng(0)
        if not isinstance(self.rng, np.random.Generator):
            raise ParameterTypeError(f"rng must be a numpy.random.Generator, got {self.rng!r}")
        self._motor0 = motor.replace(input_delay=0)
        self._stepper: Stepper | None = None          # the plant's exact step over the last interval length
        self._stepper_h = 0.0
        self.duty = 0
        self.stops_received = 0
        self.runs_started = 0
        self.last_end: P.End | None = None
        self.rx_errors = 0
        self._repeated: P.Sample | None = None     # the sample a repeat_at fault sends again
        self._master = self._slave = -1
        self.port_name = ""
        self._thread: threading.Thread | None = None
        self._stop_event = threading.Event()
        self.error: BaseException | None = None
        self._lockstep = False
        self._sim_time = 0.0
        self._running = self._link_down = self._booted = False
        self._next_tick = 0.0

    # -------------------------------------------------------------- lifecycle
    def start(self) -> "FakeDevice":
        """Open the pty and start the device thread; returns ``self``."""
        if self._thread is not None:
            raise RuntimeError("this FakeDevice is already started")
        import tty  # POSIX only: imported here so that `import hardware` works on Windows
        self._master, self._slave = os.openpty()
        tty.setraw(self._master)
        tty.setraw(self._slave)
        os.set_blocking(self._master, False)
        self.port_name = os.ttyname(self._slave)
        self._thread = threading.Thread(target=self._main, name="motorid-fake-device", daemon=True)
        self._thread.start()
        return self

    def close(self) -> None:
        """Stop the device thread and close the pty."""
        self._stop_event.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        for fd in (self._master, self._slave):
            if fd >= 0:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self._master = self._slave = -1

    def start_lockstep(self) -> "FakeDevice":
        """Run in simulated time, driven by :meth:`advance` (no thread, no pty); returns ``self``."""
        if self._thread is not None or self._lockstep:
            raise RuntimeError("this FakeDevice is already started")
        self._lockstep = True
        self._sim_time = 0.0
        self._reset()
        return self

    @property
    def link_down(self) -> bool:
        """Whether the device has closed the link (a ``disconnect_at`` fault)."""
        return self._link_down

    def advance(self, until: float, data: bytes = b"", *, stop_on_frame: bool = True) -> bytes:
        """In lock-step: take the host's ``data`` now, run the device to ``until`` s of simulated time.

        Stops early, with ``stop_on_frame``, as soon as the device has something to send (an
        answer to ``data``, a SAMPLE, ...).  Returns the bytes sent; :attr:`sim_time` is where it stopped.
        """
        if not self._lockstep:
            raise RuntimeError("advance() drives a FakeDevice started with start_lockstep()")
        if data and self._booted and not self._link_down:
            self._accept_bytes(data)          # bytes that arrive in the bootloader are lost
        boot_at = float(self.faults.boot_delay)
        while not self._link_down and not (stop_on_frame and self._out):
            t = until
            if not self._booted:
                t = min(t, boot_at)
            elif self._running:
                t = min(t, self._next_tick)
            self._sim_time = max(self._sim_time, t)
            if not self._booted and self._sim_time >= boot_at:
                self._booted = True
                self._send(P.Boot(self.faults.version, 1))
                self._last_rx = self._sim_time
            if self._running:
                self._ticks(self._sim_time)
            if self._running:
                self._check_watchdog(self._sim_time)
            if t >= until:
                break
        out = bytes(self._out)
        self._out.clear()
        self._queued_samples = 0
        return out

    @property
    def sim_time(self) -> float:
        """Simulated seconds since :meth:`start_lockstep`."""
        return self._sim_time

    def __enter__(self) -> "FakeDevice":
        return self.start()

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close()
        if self.error is not None and exc_type is None:
            raise RuntimeError(f"the fake device's thread failed: {self.error!r}") from self.error

    # -------------------------------------------------------------- the firmware
    def _main(self) -> None:
        try:
            self._run_firmware()
        except BaseException as exc:  # surfaced to tests through .error
            self.error = exc

    def _now(self) -> float:
        """The device's clock: simulated seconds in lock-step, else the wall clock."""
        return self._sim_time if self._lockstep else time.monotonic()

    def _reset(self) -> None:
        """The firmware's state after a reset (before BOOT)."""
        self._out = bytearray()
        self._queued_samples = 0
        self._tx_frame_seq = 0
        self._splitter = P.FrameSplitter()
        self._config: P.Config | None = None
        self._wave = None
        self._control = P.Control(P.ControllerKind.NONE, 0, ())
        self._reference: P.ReferenceWords | None = None
        self._loop: ControlLoop | None = None
        self._running = False
        self._link_down = False
        self._silent = False
        self._angle, self._speed_rad_s = 0.0, 0.0
        self._state = self.motor.initial_state()   # angle, speed and the plant's own (a lag's current)
        self._idle_since = self._now()
        self._last_rx = self._now()
        self._booted = False

    def _run_firmware(self) -> None:
        self._reset()
        if self.faults.boot_delay:
            self._stop_event.wait(self.faults.boot_delay)
            self._drain_input(discard=True)
        self._send(P.Boot(self.faults.version, 1))
        self._last_rx = time.monotonic()
        loop_end = time.monotonic()
        while not self._stop_event.is_set() and not self._link_down:
            now = time.monotonic()
            timeout = 0.02
            if self._running:
                # unpaced: poll the host's reading every 0.5 ms rather than spin (the host needs the GIL)
                timeout = 0.0005 if self.speed == 0 else max(0.0, min(timeout, self._next_tick - now))
            wlist = [self._master] if self._out else []
            try:
                r, w, _ = select.select([self._master], wlist, [], timeout)
            except (OSError, ValueError):
                return
            if r:
                self._drain_input()
            if self._running:
                self._ticks(time.monotonic())
            self._flush()
            # Time this thread was not running (the emulator starved of CPU, not the host silent)
            # does not count towards the host-silence watchdog: a real device's loop never takes
            # more than its wait plus a few ms.
            now = time.monotonic()
            stalled = (now - loop_end) - timeout - 0.02
            if stalled > 0:
                self._last_rx += stalled
            self._check_watchdog(now)
            loop_end = time.monotonic()

    def _drain_input(self, discard: bool = False) -> None:
        try:
            data = os.read(self._master, 4096)
        except BlockingIOError:
            return
        except OSError as exc:
            if exc.errno == errno.EIO:   # the host closed its end; wait for it to reopen
                time.sleep(0.01)
                return
            raise
        if not discard:
            self._accept_bytes(data)

    def _accept_bytes(self, data: bytes) -> None:
        """Bytes from the host, frame by frame as the firmware's receiver takes them."""
        if self.faults.mute:
            return
        parts, overflow = self._splitter.split(data)
        if overflow:      # an overlong frame, discarded up to the next 0x00: one error
            self.rx_errors += 1
        for part in parts:
            if part:
                self._receive(part)

    def _receive(self, encoded: bytes) -> None:
        """Act on one encoded frame as the firmware does: answer it, or count it as an error."""
        try:
            msg_type, frame_seq, payload = P.decode_frame(encoded)
        except P.FrameError:
            self.rx_errors += 1
            return
        try:
            msg = P.decode_message(msg_type, payload)
            if msg_type >= 0x40:
                raise P.FrameError(f"type {msg_type:#04x} is not a host-to-device type")
        except P.FrameError:
            self.rx_errors += 1
            self._send(P.Nak(msg_type, frame_seq, _nak_reason(msg_type, payload)))
            return
        self._last_rx = self._now()   # any valid frame refreshes the watchdog
        if isinstance(msg, P.Heartbeat):
            return
        if isinstance(msg, P.Stop):
            self.stops_received += 1
            self.duty = 0
            self._send(P.Ack(msg_type, frame_seq))
            if self._running:
                self._end(P.EndReason.STOPPED_BY_HOST)
            return
        if self._running:
            self._send(P.Nak(msg_type, frame_seq, P.NakReason.BUSY))
            return
        self._answer_idle(msg, msg_type, frame_seq)

    def _answer_idle(self, msg, msg_type: int, frame_seq: int) -> None:
        """HELLO, CONFIG, WAVE or START while no run is going on."""
        def ack_if(ok: bool) -> None:
            self._send(P.Ack(msg_type, frame_seq) if ok else P.Nak(msg_type, frame_seq, P.NakReason.BAD_VALUE))

        if isinstance(msg, P.Hello):
            self._send(P.HelloAck(self.faults.version, 0x0100, 16_000_000, 1, P.MAX_PAYLOAD, "fake",
                                  self.encoder.counts_per_rev))
        elif isinstance(msg, P.Config):
            ok = _config_ok(msg)
            if ok:
                self._config = msg
                self._control = P.Control(P.ControllerKind.NONE, 0, ())   # CONFIG returns to open loop
            ack_if(ok)
        elif msg_type == P.MsgType.WAVE:
            ok = not P.wave_range_problems(msg)
            if ok:
                self._wave = msg
            ack_if(ok)
        elif isinstance(msg, P.Control):
            ok = not P.control_problems(msg)
            if ok:
                self._control = msg
            ack_if(ok)
        elif isinstance(msg, P.ReferenceWords):
            ok = not P.reference_problems(msg)
            if ok:
                self._reference = msg
            ack_if(ok)
        elif isinstance(msg, P.Start):
            closed = self._control.controller != P.ControllerKind.NONE
            if self._config is None or (self._reference if closed else self._wave) is None:
                self._send(P.Nak(msg_type, frame_seq, P.NakReason.NOT_CONFIGURED))
            else:
                self._send(P.Ack(msg_type, frame_seq))
                self._start_run(self._config, self._wave)

    def _start_run(self, cfg: P.Config, wave: P.Wave | None) -> None:
        if cfg.n_samples > 10**8:
            raise RuntimeError(f"the fake device emulates runs of at most 10**8 samples, got {cfg.n_samples}")
        self._run_config = cfg
        self._loop = None
        if self._control.controller != P.ControllerKind.NONE and self._reference is not None:
            c = self._control
            name = P.controller_name(c.controller)
            reference = reference_values(self._reference, cfg.n_samples + c.preview)
            self._loop = ControlLoop(name, gains_from_wire(name, c.gains), c.preview, reference, cfg.duty_limit)
        elif wave is not None:
            self._duty_seq = P.expand(wave, cfg.n_samples, cfg.duty_limit)
        self._dt = cfg.sample_period_us * 1e-6
        # the motor coasted with duty 0 since the last run
        idle = (self._now() - self._idle_since) * (1.0 if self._lockstep else (self.speed or 1.0))
        if idle > 0:
            self._advance_motor(0.0, idle)
        # the firmware applies each duty at the tick after the one that computed it (DEVICE_INPUT_DELAY)
        self._latched = 0
        self._delay_line = [0] * self.motor.input_delay
        self._k = 0
        self._t0_us = int(self.rng.integers(0, 2**32))   # micros() is wherever it is
        self._counters = dict(sent=0, dropped=0, encoder_errors=0, overruns=0)
        self._overflow_reported = False
        self._next_tick = self._now()
        self._running = True
        self.runs_started += 1

    def _advance_motor(self, duty: float, h: float) -> None:
        """Hold ``duty`` for ``h`` s: the plant's exact step (:class:`motorsim.plant.Stepper`)."""
        if self._stepper is None or self._stepper_h != h:
            self._stepper, self._stepper_h = self._motor0.stepper(h), h
        self._state = self._stepper.step(0, (self._angle, self._speed_rad_s, *self._state[2:]), duty)
        self._angle, self._speed_rad_s = self._state[0], self._state[1]

    def _ticks(self, now: float) -> None:
        cfg = self._run_config
        while self._running:
            if self.speed == 0 and not self._lockstep:
                # unpaced: wait for the host to read (lossless). The queue counts samples: under load
                # the pty takes a frame in pieces, and a byte count of a partly written queue reads one
                # frame short of full (it dropped samples then)
                if (self._queued_samples >= self.queue_size
                        or self._unread_bytes() + len(self._out) >= self.queue_size * _SAMPLE_WIRE):
                    return
            elif now < self._next_tick:
                return
            k = self._k
            f = self.faults
            if f.disconnect_at is not None and k >= f.disconnect_at:
                self._disconnect()
                return
            if f.watchdog_trip_at is not None and k >= f.watchdog_trip_at:
                self._watchdog_trip()
                return
            if f.stall_at is not None and k >= f.stall_at:
                self._silent = True
            if f.repeat_at is not None and k > f.repeat_at and self._repeated is not None:
                self._send_sample(self._repeated)      # the same sample again; k never advances
                self._counters["sent"] -= 1            # a repeat is not a new sample sent
                self._next_tick += self._tick_interval()
                continue
            counts = int(self.encoder.counts(np.array([self._angle]), self.rng)[0])
            duty = self._loop.step(k, counts) if self._loop is not None else int(self._duty_seq[k])
            # the bridge holds the duty latched at the previous tick; the motor's own delay follows
            self.duty, self._latched = self._latched, duty
            self._delay_line.append(self.duty)
            drive = self._delay_line.pop(0)
            self._advance_motor(float(drive), self._dt)
            time_us = (self._t0_us + k * cfg.sample_period_us) & 0xFFFFFFFF
            sample = P.Sample(k, time_us, counts, duty, 0)
            self._repeated = sample
            if self._queued_samples >= self.queue_size or self.rng.random() < f.queue_drop_rate:
                self._counters["dropped"] += 1
                if not self._overflow_reported:
                    self._overflow_reported = True
                    self._send(P.Fault(P.FaultCode.QUEUE_OVERFLOW, k))
            else:
                self._send_sample(sample)
            self._k += 1
            self._next_tick += self._tick_interval()
            if self._k >= cfg.n_samples:
                self.duty = 0
                self._end(P.EndReason.COMPLETE)

    def _tick_interval(self) -> float:
        """The device clock's time from one tick to the next."""
        if self._lockstep:
            return self._dt
        return self._dt / self.speed if self.speed else 0.0

    def _unread_bytes(self) -> int:
        """Bytes written to the pty that the host has not read yet (FIONREAD on the slave end)."""
        import fcntl
        import termios
        try:
            buf = fcntl.ioctl(self._slave, termios.FIONREAD, b"\0\0\0\0")
        except OSError:
            return 0
        return int.from_bytes(buf, sys.byteorder)

    def _send_sample(self, sample: P.Sample) -> None:
        f, rng = self.faults, self.rng
        wire = P.encode_message(sample, self._tx_frame_seq)
        self._tx_frame_seq = (self._tx_frame_seq + 1) & 0xFF
        self._counters["sent"] += 1
        if f.garbage_rate and rng.random() < f.garbage_rate:
            self._emit(bytes(rng.integers(1, 256, int(rng.integers(1, 9)), dtype=np.uint8)) + b"\x00")
        if f.drop_rate and rng.random() < f.drop_rate:
            return
        if f.flip_rate and rng.random() < f.flip_rate:
            bad = bytearray(wire)
            i = int(rng.integers(0, len(wire) - 1))
            bad[i] ^= 1 << int(rng.integers(0, 8))
            wire = bytes(bad)
        self._emit(wire, sample=True)

    def _end(self, reason: int) -> None:
        c = self._counters
        self._running = False
        self.duty = 0
        self._idle_since = self._now()
        end = P.End(int(reason), c["sent"], c["dropped"], c["encoder_errors"], min(self.rx_errors, 0xFFFF),
                    c["overruns"])
        self.last_end = end
        self._send(end)

    def _watchdog_trip(self) -> None:
        self.duty = 0
        self._send(P.Fault(P.FaultCode.HOST_SILENCE, self._k))
        self._end(P.EndReason.HOST_SILENCE)

    def _check_watchdog(self, now: float) -> None:
        watchdog_ms = self._run_config.watchdog_ms if self._running else 0
        if watchdog_ms and now - self._last_rx > watchdog_ms / 1000:
            self._watchdog_trip()

    def _disconnect(self) -> None:
        if self._lockstep:          # the host reads what was sent before, then the port fails
            self.duty = 0
            self._running = False
            self._link_down = True
            return
        # Let the host read what was sent before the disconnect (up to 1 s), so that the
        # fault is exactly "the link ends after sample disconnect_at - 1".
        deadline = time.monotonic() + 3.0
        while self._out and time.monotonic() < deadline:
            self._flush()
            time.sleep(0.001)
        # The kernel moves written bytes to the host's queue asynchronously (the pty's flip
        # buffer), so wait until the queue has stayed empty for 100 ms.
        empty_since = None
        while time.monotonic() < deadline:
            if self._unread_bytes() > 0:
                empty_since = None
            elif empty_since is None:
                empty_since = time.monotonic()
            elif time.monotonic() - empty_since > 0.1:
                break
            time.sleep(0.005)
        self.duty = 0
        self._running = False
        self._link_down = True
        for fd in (self._master, self._slave):
            with contextlib.suppress(OSError):
                os.close(fd)
        self._master = self._slave = -1

    # -------------------------------------------------------------- transmit
    def _send(self, msg) -> None:
        self._emit(P.encode_message(msg, self._tx_frame_seq))
        self._tx_frame_seq = (self._tx_frame_seq + 1) & 0xFF

    def _emit(self, wire: bytes, sample: bool = False) -> None:
        if self._silent or self.faults.mute:
            return
        self._out += wire
        if sample and not self._lockstep:   # in lock-step the host's buffer takes every frame at once
            self._queued_samples += 1
        self._flush()

    def _flush(self) -> None:
        if not self._out or self._master < 0:
            return
        try:
            n = os.write(self._master, self._out)
        except BlockingIOError:
            return
        except OSError as exc:
            if exc.errno == errno.EIO:
                return
            raise
        del self._out[:n]
        self._queued_samples = min(self._queued_samples, math.ceil(len(self._out) / _SAMPLE_WIRE))


def _nak_reason(msg_type: int, payload: bytes) -> int:
    """Why the firmware NAKs a frame whose COBS and CRC are good but whose message is not."""
    known = msg_type in P.MsgType._value2member_map_ and msg_type < 0x40
    if msg_type == P.MsgType.REFERENCE and payload and payload[0] not in P.ReferenceKind._value2member_map_:
        return P.NakReason.BAD_VALUE
    if msg_type == P.MsgType.WAVE and payload and (
            payload[0] not in P.WaveKind._value2member_map_
            or (payload[0] == P.WaveKind.MULTISINE and len(payload) >= 4 and not 1 <= payload[3] <= 4)):
        return P.NakReason.BAD_VALUE
    return P.NakReason.BAD_LENGTH if known else P.NakReason.UNKNOWN_TYPE


def _config_ok(msg: P.Config) -> bool:
    """The CONFIG ranges of PROTOCOL.md."""
    return (100 <= msg.sample_period_us <= 1_000_000 and msg.n_samples >= 1 and 0 <= msg.duty_limit <= 255
            and msg.decoding in (1, 2, 4) and (msg.watchdog_ms == 0 or 50 <= msg.watchdog_ms <= 60_000))


#: Defaults of the fake device's motor (``Motor`` itself has none for ``a`` and ``b``).
_MOTOR_DEFAULTS = {"a": 25.0, "b": 3.0}
#: Keys of the emulated device itself (not bench knobs, not faults).
_DEVICE_KNOBS = (
    Knob("seed", FakeDevice, int, 0, "", "seed of the angle noise and of the injected faults"),
    Knob("speed", FakeDevice, float, 1.0, "", "device time per wall-clock time at most (0: as fast as the host reads)"),
    Knob("realtime", FakeDevice, bool, False, "", "on the wall clock in a thread, on a pty (default: in lock-step "
                                                 "with the host, in simulated time)"),
    Knob("queue", FakeDevice, int, 16, "SAMPLE frames", "transmit queue length"),
)
#: Keys earlier versions accepted, and their names now.
_RENAMED_KEYS = {"cpr": "counts_per_rev", "noise": "angle_noise", "offset": "count_offset"}


def _url_knobs() -> tuple[Knob, ...]:
    bench = tuple(k for k in bench_knobs() if k.owner in (Motor, Encoder))
    return bench + _DEVICE_KNOBS + knobs_of(FaultPlan) + _structure_knobs()


def _structure_knobs() -> tuple[Knob, ...]:
    """``structure`` and the further parameters of the registered structures (:func:`motorsim.plant.named_plant`)."""
    structures = registered_structures()
    return (Knob("structure", FakeDevice, str, "", "", "the model structure of the device's plant (default: the "
                 "Motor of the motor's knobs)"),
            *(Knob(name, FakeDevice, float, None, "", f"a parameter of the structures {_having(structures, name)}")
              for name in further_parameters(structures)))


def _having(structures, name: str) -> list[str]:
    return [n for n, s in structures.items() if name in s.param_names]


def url_keys() -> tuple[str, ...]:
    """The query keys of ``fake://``: the motor's and encoder's bench knobs, the device's
    (``seed``, ``speed``, ``realtime``, ``queue``), the :class:`FaultPlan` fields, and ``structure`` with the further
    parameters of the registered model structures (those ``identify`` registers when imported).

    Examples
    --------
    >>> url_keys()[:6]
    ('a', 'b', 'friction', 'bias', 'dead_zone', 'input_delay')
    >>> url_keys()[6:9]
    ('electrical_time_constant', 'static_friction', 'counts_per_rev')
    """
    return tuple(k.name for k in _url_knobs())


def parse_fake_url(url: str) -> FakeDevice:
    """A (not yet started) :class:`FakeDevice` from ``fake://?a=25&b=3&...``.

    Whether it runs in lock-step (:func:`open_fake`) is the URL's ``realtime`` key (:func:`fake_url_realtime`).

    Query keys (:func:`url_keys`): the bench knobs of ``Motor`` (``a``, ``b``, defaults 25 and 3;
    ``friction``, ``bias``, ``dead_zone``, ``input_delay``) and ``Encoder`` (``counts_per_rev``,
    ``count_offset``, ``angle_noise``) under their own names; ``seed``, ``speed``, ``realtime``, ``queue``;
    every :class:`FaultPlan` field (``flip_rate``, ..., ``mute``, ``version``, ``boot_delay``); and ``structure``, a
    registered model structure whose plant the device runs, with its own parameters under their names
    (``fake://?structure=two-mass&inertia_ratio=1.5&shaft_frequency=150&shaft_damping=0.1``; a parameter the
    structure does not have is refused by name).

    Examples
    --------
    >>> device = parse_fake_url("fake://?a=30&b=2&counts_per_rev=2000&speed=0")
    >>> device.motor.a, device.encoder.counts_per_rev, device.speed
    (30.0, 2000, 0.0)
    """
    parsed = urllib.parse.urlsplit(url)
    if parsed.scheme != "fake":
        raise ParameterError(f"url must start with fake://, got {url!r}")
    query = dict(urllib.parse.parse_qsl(parsed.query, keep_blank_values=True))
    for old, new in _RENAMED_KEYS.items():
        if old in query:
            raise ParameterError(f"fake:// url key {old!r} is now called {new!r}")
    knobs = {k.name: k for k in _url_knobs()}
    unknown = set(query) - set(knobs)
    if unknown:
        raise ParameterError(f"fake:// url has unknown keys {sorted(unknown)}; known: {sorted(knobs)}")
    try:
        values: dict[str, Any] = {name: knobs[name].parse(text) if knobs[name].kind is not str else text
                  for name, text in query.items()}
    except ValueError as exc:
        raise ParameterError(f"fake:// url key {exc}") from None

    def fields_of(cls: type) -> dict:
        return {k.name: values[k.name] for k in knobs_of(cls) if k.name in values}

    plant_keys = [k.name for k in knobs_of(Motor)] + [k.name for k in _structure_knobs()[1:]]
    given = {name: values[name] for name in plant_keys if name in values}
    # the ranges motorid simulate holds its flags to; the run's sample period and length come later, from the host:
    # the rules in sample periods wait for them, and the speeds are the steady ones (motorsim.ranges)
    check_bench_values({**_MOTOR_DEFAULTS, **values}, lambda name: f"fake:// url key {name!r}")
    motor = named_plant(values.get("structure", ""), {**_MOTOR_DEFAULTS, **given}, registered_structures())
    return FakeDevice(motor, Encoder(**fields_of(Encoder)), FaultPlan(**fields_of(FaultPlan)),
                      speed=values.get("speed", 1.0), queue_size=values.get("queue", 16),
                      rng=np.random.default_rng(values.get("seed", 0)))


def fake_url_realtime(url: str) -> bool:
    """Whether ``fake://...`` asks for the wall clock (``realtime=1``) rather than lock-step."""
    query = dict(urllib.parse.parse_qsl(urllib.parse.urlsplit(url).query, keep_blank_values=True))
    if "realtime" not in query:
        return False
    try:
        return bool(next(k for k in _DEVICE_KNOBS if k.name == "realtime").parse(query["realtime"]))
    except ValueError as exc:
        raise ParameterError(f"fake:// url key {exc}") from None


class FakeLockstepPort(LockstepPort):
    """The fake device in lock-step with the host (:class:`hardware.lockstep.LockstepPort`).

    The device runs in this process, in simulated time, only inside :meth:`read` (and
    :meth:`wait`): no thread, no pty, and every run of the same URL gives the same bytes.

    Parameters
    ----------
    device : FakeDevice
        A device not yet started; started here with :meth:`FakeDevice.start_lockstep`.
    name : str
        The port's name (its URL).
    timeout : float or None
        Read timeout in simulated seconds.
    """

    def __init__(self, device: FakeDevice, name: str, timeout: float | None):
        super().__init__(name, timeout, device.speed)
        self.fake_device = device.start_lockstep()

    def _exchange(self, until: float, stop_on_frame: bool) -> float:
        import serial

        device = self.fake_device
        if device.link_down:
            raise serial.SerialException(f"the device on {self.name} closed the link")
        out = device.advance(until, self._take_written(), stop_on_frame=stop_on_frame)
        self._rx += out
        if device.link_down and not out:
            raise serial.SerialException(f"the device on {self.name} closed the link")
        return device.sim_time


@contextlib.contextmanager
def open_fake(url: str, baudrate: int, timeout: float) -> Iterator:
    """Start the fake device described by ``url`` and yield an open port to it.

    In lock-step (the default) the port is a :class:`FakeLockstepPort`; with ``realtime=1`` a
    ``serial.Serial`` on the threaded device's pty (``baudrate`` is set on the pty but, as
    with USB serial, does not limit its speed).  The port has an extra attribute
    ``fake_device`` (the running :class:`FakeDevice`).
    """
    import serial

    device = parse_fake_url(url)
    if not fake_url_realtime(url):
        port = FakeLockstepPort(device, url, timeout)
        try:
            yield port
        finally:
            port.close()
        return
    with device:
        port = serial.Serial(device.port_name, baudrate=baudrate, timeout=timeout)
        port.fake_device = device
        try:
            yield port
        finally:
            port.close()

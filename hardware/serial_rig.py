"""``SerialRig``: the real bench (or the emulated one) behind ``Rig.run(experiment) -> Recording``.

The host uploads the experiment (CONFIG, WAVE), sends START and then only reads
SAMPLEs, while a background thread sends a HEARTBEAT every ``watchdog_ms / 4`` (so
a slow callback cannot trip the device's watchdog); the clock and the
waveform live on the device (``hardware/PROTOCOL.md``).  Every loss is visible:

- a SAMPLE lost on the link or dropped by the device leaves a gap in the
  recording's ``seq`` (its sample index), and is counted in the metadata, on every
  ending: ``samples_ticked`` (samples the device ran), ``samples_lost`` (of those, not
  received) and ``loss_fraction``, with the link's ``host_link_frames_lost`` and
  ``host_rx_errors`` (frames with a bad CRC or COBS) and END's ``device_*`` counters;
- every SAMPLE's duty is checked against :func:`hardware.protocol.expand` of the
  WAVE sent (in closed loop: against the controller's integer step run here on the
  counts received, until the first lost sample), and END's counters against what
  arrived (:class:`RigCheckError`);
- the device going silent or never advancing ``seq`` for ``timeout`` s, or the run
  passing its deadline (duration + :func:`run_margin`) (:class:`RigTimeoutError`), the port failing
  (:class:`RigDisconnectedError`), a NAK (:class:`DeviceRefusedError`) or a
  device fault (:class:`DeviceFaultError`) raise with the samples received so far
  attached as ``exc.recording``;
- on a port that keeps simulated time (``fake://`` and ``avr-sim://`` by default, whose
  ports have a ``clock()``: :mod:`hardware.lockstep`), every timeout, the HEARTBEATs and the
  deadline count the device's simulated seconds and the HEARTBEATs are sent from the reading
  loop, so a run's recording does not depend on the machine's load;
- whenever a run is left early (an error, Ctrl-C, or SIGTERM raised as an exception),
  STOP is sent and END awaited for :data:`STOP_TIMEOUT` s, so the recording attached to
  the exception (``exc.recording``, also on a ``KeyboardInterrupt``) holds the samples
  still in flight and the device's END counters (``device_end_reason`` 1: stopped by host).

One concept, a run on the serial bench, in one module although it is long: the
upload, the heartbeats, the checks of every sample and the orderly stop share one run's
state and are only correct together.
"""
from __future__ import annotations

import contextlib
import dataclasses
import threading
import time
import warnings
from typing import Any, Callable

import numpy as np

from motorsim.checks import ParameterError, ParameterTypeError, check_int, check_real
from motorsim.control import ClosedLoopExperiment
from motorsim.recording import Recording
from motorsim.rig import Experiment
from motorsim.sensors import DEFAULT_COUNTS_PER_REV
from motorsim.text import printable

from . import protocol as P
from .errors import DeviceFaultError, DeviceRefusedError, RigCheckError, RigDisconnectedError, RigError, RigTimeoutError
from .ports import open_port

_FAULT_NAMES = ", ".join(f"{c.value} {c.name}" for c in P.FaultCode)

__all__ = ["SerialRig", "RecordedSample", "HELLO_INTERVAL", "STOP_TIMEOUT", "run_margin"]

#: Seconds between HELLOs while waiting for the device to boot (PROTOCOL.md).
HELLO_INTERVAL = 0.2
#: Seconds to wait for END after a STOP sent to end a run early (two tries).
STOP_TIMEOUT = 0.5
_READ_TIMEOUT = 0.02
_SAMPLE_BITS = 21 * 10      # a SAMPLE frame on the wire: 21 bytes of 10 bits (8N1)


@dataclasses.dataclass(frozen=True, slots=True)
class RecordedSample:
    """One row of the recording as it arrives (what ``on_sample`` receives).

    Attributes
    ----------
    seq : int
        Sample index on the device (gaps mean lost samples).
    time_s : float
        Time in s from the run's first sample.
    duty : int
        Duty applied from this sample until the next.
    counts : int
        Absolute encoder count at this sample.
    """

    seq: int
    time_s: float
    duty: int
    counts: int


#: The fastest line rate taken, in baud: beyond any UART or USB serial bridge (12 Mbaud for the fastest).
MAX_BAUDRATE = 50_000_000
#: The longest wait for a device, in s: an hour without a word is a device that is gone, not a slow one (the
#: motor holds its last duty until the device's watchdog stops it).
MAX_TIMEOUT = 3600.0


class SerialRig:
    """The bench over a serial port, a context manager; implements ``motorsim.rig.Rig``.

    Parameters
    ----------
    port : str or serial port object
        A device path (``/dev/ttyACM0``), a pyserial URL (``loop://``, ``socket://...``),
        ``fake://?a=25&b=3`` (the emulated device), ``avr-sim://...``; or an already open
        pyserial-compatible object (``read``, ``write``, ``in_waiting``), which is not closed.
    baudrate : int
        Line rate, default 250 000 (115 200 is the safe choice at <= 250 Hz).
    counts_per_rev : int, optional
        Encoder counts per revolution after decoding.  Default: what the device reports in
        HELLO_ACK, else 16667; a value given here that differs from the device's is an error.
    decoding : {1, 2, 4}
        Quadrature decoding the device applies.
    watchdog_ms : int
        Device's host-silence watchdog in ms (0 off, else 50...60 000); HEARTBEAT every quarter of it.
    timeout : float
        Seconds without a new sample during a run (silence, or frames that do not advance
        ``seq``) before :class:`RigTimeoutError`; a run also ends in that error once it takes
        its duration plus :func:`run_margin` (10 % + 2 s + ``timeout``).  On a port that keeps
        simulated time (``fake://``, ``avr-sim://``; :mod:`hardware.lockstep`) these seconds,
        ``hello_timeout``'s, ``command_timeout``'s and the HEARTBEATs' are the device's simulated ones.
    hello_timeout : float
        Seconds to wait for HELLO_ACK (an Uno spends 1-2 s in its bootloader after the port opens).
    command_timeout : float
        Seconds to wait for the ACK of CONFIG, WAVE, START (each is sent up to 3 times).

    Examples
    --------
    The emulated device (``fake://``, here unpaced with ``speed=0``) runs a 0.5 s sine:

    >>> from motorsim import Experiment, Sine
    >>> with SerialRig("fake://?a=25&b=3&speed=0") as rig:
    ...     rec = rig.run(Experiment(Sine(10, 200), sample_period=0.005, duration=0.5))
    >>> len(rec), rec.metadata["complete"], rec.duty[:4].tolist(), rec.has_gaps
    (100, 'true', [0.0, 10.0, 20.0, 30.0], False)
    """

    def __init__(self, port, baudrate: int = 250_000, *, counts_per_rev: int | None = None,
                 decoding: int = 4, watchdog_ms: int = 500, timeout: float = 1.0, hello_timeout: float = 5.0,
                 command_timeout: float = 0.5):
        if isinstance(port, str):
            if not port:
                raise ParameterError("port must be a device path or URL, got ''")
        elif not all(hasattr(port, a) for a in ("read", "write")):
            raise ParameterTypeError(f"port must be a str or an open serial port, got {type(port).__name__}")
        baudrate = check_int("baudrate", baudrate, 1, MAX_BAUDRATE, allow_integral_float=False)
        if counts_per_rev is not None:
            counts_per_rev = check_int("counts_per_rev", counts_per_rev, 1, allow_integral_float=False)
        if decoding not in (1, 2, 4):
            raise ParameterError(f"decoding must be 1, 2 or 4, got {decoding!r}")
        if not (watchdog_ms == 0 or (isinstance(watchdog_ms, int) and 50 <= watchdog_ms <= 60_000)):
            raise ParameterError(f"watchdog_ms must be 0 (off) or an integer in 50...60 000, got {watchdog_ms!r}")
        for name, value in (("timeout", timeout), ("hello_timeout", hello_timeout),
                            ("command_timeout", command_timeout)):
            check_real(name, value, positive=True, below=MAX_TIMEOUT)
        self.port = port
        self.baudrate = baudrate
        self.requested_counts_per_rev = counts_per_rev
        self.counts_per_rev = counts_per_rev or DEFAULT_COUNTS_PER_REV
        self.decoding = decoding
        self.watchdog_ms = watchdog_ms
        self.timeout = float(timeout)
        self.hello_timeout = float(hello_timeout)
        self.command_timeout = float(command_timeout)
        self._stack: contextlib.ExitStack | None = None
        self._port: Any = None    # a pyserial-compatible port while open
        self._reader = P.FrameReader()
        self._tx_frame_seq = 0
        self._rx_frame_seq: int | None = None
        self._link_lost = 0
        self._boot: P.Boot | None = None
        self._backlog: list = []
        self._write_lock = threading.Lock()
        self._now: Callable[[], float] = time.monotonic
        self._simulated = False
        self.device: P.HelloAck | None = None

    # -------------------------------------------------------------- connection
    def __enter__(self) -> "SerialRig":
        self.open()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def port_name(self) -> str:
        """The port as given (its URL or the object's ``name``)."""
        return self.port if isinstance(self.port, str) else str(getattr(self.port, "name", "<port object>"))

    def open(self) -> None:
        """Open the port and shake hands (HELLO every 0.2 s until HELLO_ACK); idempotent.

        A device still running an earlier session's experiment NAKs HELLO as BUSY; it is
        sent STOP and asked again.
        """
        if self._port is not None:
            return
        stack = contextlib.ExitStack()
        try:
            if isinstance(self.port, str):
                self._port = stack.enter_context(open_port(self.port, self.baudrate, _READ_TIMEOUT))
            else:
                self._port = self.port
            clock = getattr(self._port, "clock", None)
            self._simulated = callable(clock)
            self._now = clock if callable(clock) else time.monotonic
            self._stack = stack
            self._handshake()
        except BaseException:
            self._port = None
            self._stack = None
            stack.close()
            raise

    @property
    def simulated_time(self) -> bool:
        """Whether the open port keeps the device's simulated time (every timeout then counts it)."""
        return self._simulated

    def close(self) -> None:
        """Close the port (if this rig opened it)."""
        self._now, self._simulated = time.monotonic, False
        stack, self._stack, self._port = self._stack, None, None
        if stack is not None:
            stack.close()

    def _write(self, msg) -> int:
        """Send ``msg``; returns its frame_seq."""
        with self._write_lock:     # the heartbeat thread writes too
            frame_seq = self._tx_frame_seq
            try:
                self._port.write(P.encode_message(msg, frame_seq))
            except Exception as exc:   # pyserial raises SerialException / OSError / portNotOpenError
                raise RigDisconnectedError(f"writing to {self.port_name} failed: {exc}") from None
            self._tx_frame_seq = (frame_seq + 1) & 0xFF
            return frame_seq

    def _read(self) -> list:
        if self._backlog:
            out, self._backlog = self._backlog, []
            return out
        port = self._port
        try:
            waiting = getattr(port, "in_waiting", 0)
            data = port.read(max(1, min(waiting, 65536)))
        except Exception as exc:
            raise RigDisconnectedError(f"reading from {self.port_name} failed: {exc}") from None
        if not data:
            return []
        frames = self._reader.feed(data)
        for frame_seq, msg in frames:
            if isinstance(msg, P.Boot):
                self._boot = msg
            elif self._rx_frame_seq is not None:
                self._link_lost += (frame_seq - self._rx_frame_seq - 1) & 0xFF
            self._rx_frame_seq = frame_seq
        return [msg for _, msg in frames]

    def _handshake(self) -> None:
        start = self._now()
        next_hello, sent = start, 0
        while True:
            now = self._now()
            if now >= next_hello:
                self._write(P.Hello(P.PROTOCOL_VERSION))
                sent += 1
                next_hello = now + HELLO_INTERVAL
            msgs = self._read()
            for i, msg in enumerate(msgs):
                if isinstance(msg, P.HelloAck):
                    P.check_version(msg.version)
                    self._adopt_counts_per_rev(msg.counts_per_rev)
                    self.device = msg
                    self._backlog = msgs[i + 1:]
                    return
                if isinstance(msg, P.Nak) and msg.refused_type == P.MsgType.HELLO and msg.reason == P.NakReason.BUSY:
                    self._write(P.Stop())   # a run left over from an earlier session: stop it, then retry
                    next_hello = self._now()
            if self._now() - start > self.hello_timeout:
                raise RigTimeoutError(
                    f"the device on {self.port_name} never answered HELLO ({sent} sent over "
                    f"{self.hello_timeout:g} s): check the port, the baud rate ({self.baudrate}) and that "
                    f"the motorid firmware (protocol version {P.PROTOCOL_VERSION}) is flashed")

    def _adopt_counts_per_rev(self, reported: int) -> None:
        """Use the encoder resolution the device reports (0: it does not know), refusing a contradiction."""
        if not reported:
            return
        requested = self.requested_counts_per_rev
        if requested is not None and requested != reported:
            raise ParameterError(f"counts_per_rev {requested} was given but the device on {self.port_name} reports "
                             f"{reported} counts per revolution; drop --counts-per-rev or fix the device's setting")
        self.counts_per_rev = reported

    def _command(self, msg) -> None:
        """Send ``msg`` until ACKed (3 tries, ``command_timeout`` each); NAK raises.

        For START, frames of the run that arrive with or before its ACK are kept for the
        run loop, and samples arriving (or a retry NAKed BUSY) show that a START whose ACK
        was lost did start the run.
        """
        msg_type = P.msg_type_of(msg)
        is_start = msg_type == P.MsgType.START
        run_frames: list = []
        for attempt in range(3):
            frame_seq = self._write(msg)
            deadline = self._now() + self.command_timeout
            while self._now() < deadline:
                replies = self._read()
                for i, reply in enumerate(replies):
                    if isinstance(reply, P.Ack) and reply.acked_frame_seq == frame_seq and reply.acked_type == msg_type:
                        self._backlog = run_frames + replies[i + 1:]
                        return
                    if (isinstance(reply, P.Nak) and reply.refused_frame_seq == frame_seq
                            and reply.refused_type == msg_type):
                        if is_start and attempt > 0 and reply.reason == P.NakReason.BUSY:
                            self._backlog = run_frames + replies[i + 1:]
                            return     # the first START did start the run; its ACK was lost
                        try:
                            reason = P.NakReason(reply.reason).name
                        except ValueError:
                            reason = f"reason {reply.reason}"
                        raise DeviceRefusedError(f"the device refused {P.MsgType(msg_type).name} {msg!r}: {reason}")
                    if is_start and isinstance(reply, (P.Sample, P.End, P.Fault)):
                        run_frames.append(reply)
                if is_start and any(isinstance(m, P.Sample) for m in run_frames):
                    self._backlog = run_frames
                    return             # START's ACK was lost but samples are arriving
        raise RigTimeoutError(f"the device on {self.port_name} did not acknowledge {P.MsgType(msg_type).name} "
                              f"(3 tries, {self.command_timeout:g} s each)")

    def _receive_run(self, run: "_RunState", on_sample) -> P.End:
        """Read the run's frames until END and return it.

        Two limits, both raising :class:`RigTimeoutError`: ``timeout`` s without a new
        sample (silence, or frames that do not advance ``seq``: a device repeating itself),
        and the run's deadline, its duration plus :func:`run_margin`.
        """
        start = last_progress = loop_end = self._now()
        duration = run.experiment.duration
        margin = run_margin(duration, self.timeout)
        deadline = start + duration + margin
        frames = 0
        # In simulated time the heartbeats go from here, at the device's own instants.
        beat = self.watchdog_ms / 4000 if self.watchdog_ms and self.simulated_time else 0.0
        next_beat = start + beat
        while run.end is None:
            if beat and self._now() >= next_beat:
                self._write(P.Heartbeat())
                next_beat = self._now() + beat
            msgs = self._read()
            now = self._now()
            # An iteration far longer than a read timeout means this process was not running
            # (or a callback was slow): that is not the device's silence, nor its slowness.
            # (In simulated time a slow host stops the device's clock too.)
            if now - loop_end > 0.25 and not self.simulated_time:
                last_progress += now - loop_end - _READ_TIMEOUT
                deadline += now - loop_end - _READ_TIMEOUT
            loop_end = now
            if msgs:
                frames += len(msgs)
                before = (run.last_index, run.fault)
                run.accept(msgs, on_sample)
                if (run.last_index, run.fault) != before or run.end is not None:
                    last_progress, frames = now, 0
            if run.end is None and now - last_progress > self.timeout:
                what = (f"sent {frames} frames but no new sample" if frames else "went silent")
                raise RigTimeoutError(f"the device on {self.port_name} {what} for {self.timeout:g} s "
                                      f"after sample {run.last_index}")
            if run.end is None and now > deadline:
                raise RigTimeoutError(
                    f"the run on {self.port_name} passed its deadline ({now - start:.1f} s for a "
                    f"{duration:g} s experiment, margin {margin:g} s) "
                    f"at sample {run.last_index} of {len(run.expected)}: the device is slower than its clock")
            if run.boot is not None:
                raise DeviceFaultError(f"the device reset during the run (BOOT, reset cause "
                                       f"{run.boot.reset_cause:#04x}) after sample {run.last_index}")
            loop_end = self._now()
        return run.end

    # -------------------------------------------------------------- the run
    def line_load(self, sample_period: float) -> float:
        """Fraction of the line the SAMPLE frames take at ``sample_period`` s (21 bytes, 8N1 = 210 bits each)."""
        return _SAMPLE_BITS / sample_period / self.baudrate

    def run(self, experiment: Experiment | ClosedLoopExperiment, *,
            on_sample: Callable[[RecordedSample], None] | None = None) -> Recording:
        """Run ``experiment`` on the device and return its recording.

        Parameters
        ----------
        experiment : Experiment or ClosedLoopExperiment
            What to run; its sample period must be a whole number of µs (100 µs...1 s).  In
            closed loop the device runs the controller (CONTROL, REFERENCE) and the recording
            gains the ``reference`` column.
        on_sample : callable, optional
            Called with each :class:`RecordedSample` as it arrives (incremental recording,
            running estimates, progress); an exception in it ends the run (STOP is sent).

        Returns
        -------
        Recording
            ``seq`` is the device's sample index (gaps are lost samples); ``time`` is the
            device's clock from the run's start; metadata hold the device's END counters
            (``device_*``), the host's (``host_*``) and ``complete: true``.
        """
        if not isinstance(experiment, (Experiment, ClosedLoopExperiment)):
            raise ParameterTypeError(f"experiment must be an Experiment, got {type(experiment).__name__}")
        load = self.line_load(experiment.sample_period)
        if load > 1:
            raise ParameterError(f"sample_period {experiment.sample_period!r} s needs "
                             f"{_SAMPLE_BITS / experiment.sample_period:.0f} baud for the SAMPLE frames alone, more "
                             f"than baudrate {self.baudrate}; use a longer sample period or a faster line "
                             f"(250 000 baud up to 500 Hz, 500 000 at 1 kHz)")
        config = P.config_for(experiment, decoding=self.decoding, watchdog_ms=self.watchdog_ms)
        setup: list = []
        if isinstance(experiment, ClosedLoopExperiment):
            setup = [P.control_for(experiment), P.reference_for(experiment)]
        else:
            setup = [P.wave_for(experiment)]
        self.open()
        if isinstance(experiment, ClosedLoopExperiment):
            designed = experiment.controller.model.counts_per_rev
            if designed != self.counts_per_rev:
                raise ParameterError(f"the controller was designed for {designed} counts per revolution, "
                                 f"the rig on {self.port_name} has {self.counts_per_rev}")
        run = _RunState(experiment, self)
        started = ended = False
        try:
            self._command(config)
            for msg in setup:
                self._command(msg)
            run.rx0, run.lost0 = self._reader.rx_errors, self._link_lost
            started = True             # from here on, leaving early sends STOP
            self._command(P.Start())
            with _Heartbeats(self, self.watchdog_ms / 4000 if self.watchdog_ms and not self.simulated_time else None):
                end = self._receive_run(run, on_sample)
            ended = True
            if end.reason != P.EndReason.COMPLETE:
                raise DeviceFaultError(f"the device ended the run early: {run.describe_end()}")
            problems = run.check(end)
            if problems:
                raise RigCheckError("the device's report contradicts what arrived: " + "; ".join(problems))
            if run.counter_wraps:
                warnings.warn(f"the device's 32-bit encoder counter wrapped {len(run.counter_wraps)} time(s) "
                              f"during the run (first at sample {run.counter_wraps[0]}): the counts are unwrapped "
                              "(metadata counter_wraps)", UserWarning, stacklevel=2)
            return run.recording(self, complete=True)
        except BaseException as exc:   # an error, Ctrl-C, SIGTERM: stop the motor, keep what arrived
            if started and not ended:
                self._stop_run(run, wait=not isinstance(exc, RigDisconnectedError))
            if getattr(exc, "recording", None) is None and run.n:
                reason = str(exc) if isinstance(exc, RigError) else f"{type(exc).__name__}: {exc}".rstrip(": ")
                with contextlib.suppress(AttributeError):   # an exception class with __slots__
                    exc.recording = run.recording(self, complete=False, reason=reason)  # type: ignore[attr-defined]
            raise

    def _stop_run(self, run: "_RunState", *, wait: bool) -> None:
        """Send STOP and read until the device's END (``STOP_TIMEOUT`` s per try, 2 tries).

        The samples still on the wire and END's counters go into ``run``, so that a run
        left early still records what the device sent and dropped.  Never raises: it runs
        while another exception is propagating.
        """
        pending, run.unaccepted = run.unaccepted, []
        run.accept(pending, None)
        if self._port is None:
            return
        for _ in range(2 if wait else 1):
            try:
                self._write(P.Stop())
                flush = getattr(self._port, "flush", None)
                if flush is not None:
                    flush()
                deadline = self._now() + STOP_TIMEOUT
                while wait and run.end is None and run.boot is None and self._now() < deadline:
                    run.accept(self._read(), None)
            except Exception:
                return
            if run.end is not None or run.boot is not None:
                return


def run_margin(duration: float, timeout: float) -> float:
    """Seconds a run may take beyond its ``duration`` before :class:`RigTimeoutError`: 10 % + 2 s + ``timeout``.

    Parameters
    ----------
    duration : float
        The experiment's duration in s (the device's clock).
    timeout : float
        The rig's silence timeout in s.

    Examples
    --------
    >>> run_margin(10.0, 1.0)
    4.0
    """
    return 0.1 * duration + 2.0 + timeout


class _Heartbeats:
    """HEARTBEAT every ``interval`` s from a background thread while a run is read.

    A slow ``on_sample`` callback (a plot redraw on a busy laptop) must not starve the
    device's host-silence watchdog; a dead or killed host process still stops the
    heartbeats, and every run ends by itself after ``n_samples`` anyway.
    """

    def __init__(self, rig: SerialRig, interval: float | None):
        self._rig, self._interval = rig, interval
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def __enter__(self) -> "_Heartbeats":
        if self._interval:
            self._thread = threading.Thread(target=self._loop, name="motorid-heartbeat", daemon=True)
            self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()

    def _loop(self) -> None:
        while not self._stop.wait(self._interval):
            try:
                self._rig._write(P.Heartbeat())
            except RigDisconnectedError:
                return      # the reading thread sees the failure too and raises it


class _RunState:
    """What one run has received (private to SerialRig.run)."""

    def __init__(self, experiment: Experiment | ClosedLoopExperiment, rig: "SerialRig"):
        self._rig = rig
        self.experiment = experiment
        self.loop = None
        self.reference = None
        if isinstance(experiment, ClosedLoopExperiment):
            self.loop = experiment.controller.start(experiment.reference_samples(), experiment.duty_limit)
            self.reference = experiment.reference_values()
            self.expected = np.zeros(experiment.n_samples, dtype=np.int64)   # filled as counts arrive
        else:
            self.expected = experiment.duty()
        self.unverified = 0
        self.dt = experiment.sample_period
        self.seq: list[int] = []
        self.time: list[float] = []
        self.duty: list[int] = []
        self.counts: list[int] = []
        self.end: P.End | None = None
        self.fault: P.Fault | None = None
        self.boot: P.Boot | None = None
        self.duty_mismatches = 0
        self.first_mismatch = ""
        self.out_of_order = 0
        self.clock_back = 0                     # samples whose device time did not advance: kept out
        self.first_clock_back = ""
        self.encoder_flags = 0
        self.late_flags = 0
        self.last_index = -1
        self.rx0, self.lost0 = rig._reader.rx_errors, rig._link_lost
        self.unaccepted: list = []
        self._first_us = self._prev_us = self._unwrapped = 0
        self._raw_counts = 0
        self.counter_wraps: list[int] = []      # the samples at which the device's int32 counter wrapped

    @property
    def n(self) -> int:
        return len(self.seq)

    @property
    def host_rx_errors(self) -> int:
        return self._rig._reader.rx_errors - self.rx0

    @property
    def link_lost(self) -> int:
        return self._rig._link_lost - self.lost0

    def accept(self, msgs: list, on_sample) -> None:
        """Take the frames ``msgs`` in; frames after one whose ``on_sample`` raised wait in ``unaccepted``."""
        n_expected = len(self.expected)
        for i, msg in enumerate(msgs):
            if type(msg) is P.Sample:
                k = msg.seq
                if k <= self.last_index or k >= n_expected:
                    self.out_of_order += 1
                    continue
                t = self._sample_time(k, msg.time_us)
                if t is None:
                    continue
                if self.loop is not None:
                    if k == self.last_index + 1 and not self.unverified:
                        self.expected[k] = self.loop.step(k, msg.counts)
                    else:   # after a lost sample the host no longer knows the controller's state
                        self.unverified += 1
                        self.expected[k] = msg.duty
                if msg.duty != self.expected[k]:
                    if not self.duty_mismatches:
                        self.first_mismatch = f"sample {k}: device applied {msg.duty}, expected {self.expected[k]}"
                    self.duty_mismatches += 1
                self.encoder_flags += msg.flags & 1
                self.late_flags += (msg.flags >> 1) & 1
                counts = self._unwrap_counts(k, msg.counts)
                self.last_index = k
                self.seq.append(k)
                self.time.append(t)
                self.duty.append(msg.duty)
                self.counts.append(counts)
                if on_sample is not None:
                    try:
                        on_sample(RecordedSample(k, t, msg.duty, counts))
                    except BaseException:
                        self.unaccepted = msgs[i + 1:]    # still received: recorded when the run is stopped
                        raise
            elif type(msg) is P.End:
                self.end = msg
                return
            elif type(msg) is P.Fault:
                self.fault = msg
            elif type(msg) is P.Boot:
                self.boot = msg
                return

    def _sample_time(self, k: int, time_us: int) -> float | None:
        """The time in s of sample ``k`` from the device's u32 microseconds, or None when it does not advance.

        The step is read as a signed 32-bit number: a wrap (every 71.6 minutes) is a small step forward; a step
        back (or none) contradicts the samples' order, and the sample is kept out and counted."""
        if not self.seq:
            self._first_us = self._prev_us = time_us
            self._unwrapped = 0
            self._t_offset = k * self.dt
            return self._t_offset
        step = (time_us - self._prev_us + 2**31) % 2**32 - 2**31
        if step <= 0:
            if not self.clock_back:
                self.first_clock_back = f"sample {k} at {time_us} us after sample {self.last_index} at " \
                                        f"{self._prev_us} us"
            self.clock_back += 1
            return None
        self._unwrapped += step
        self._prev_us = time_us
        return self._t_offset + self._unwrapped * 1e-6

    def _unwrap_counts(self, k: int, raw: int) -> int:
        """The count of sample ``k`` on a counter that does not wrap: the device's is an int32, which wraps
        from 2**31 - 1 to -2**31 on a long run (about 36 hours at 16 667 counts/rev and 1000 rpm, or a
        device started near its end); a step of more than 2**31 counts between two samples is a wrap."""
        if not self.counts:
            self._raw_counts = raw
            return raw
        step = (raw - self._raw_counts + 2**31) % 2**32 - 2**31
        if step != raw - self._raw_counts:
            self.counter_wraps.append(k)
        self._raw_counts = raw
        return self.counts[-1] + step

    def describe_fault(self) -> str:
        """The FAULT received, by name (a code this version does not know said as such)."""
        if self.fault is None:
            return ""
        try:
            name = P.FaultCode(self.fault.code).name
        except ValueError:
            name = f"code {self.fault.code} (not a fault code this version of motorid knows: {_FAULT_NAMES})"
        return f"FAULT {name} at sample {self.fault.seq}"

    def describe_end(self) -> str:
        out = []
        if self.end is not None:
            try:
                out.append(f"END {P.EndReason(self.end.reason).name}")
            except ValueError:
                out.append(f"END reason {self.end.reason}")
        if self.fault is not None:
            out.append(self.describe_fault())
        return ", ".join(out) + f"; {self.n} samples received"

    def check(self, e: P.End) -> list[str]:
        """END ``e`` against what arrived (PROTOCOL.md): the list of contradictions (empty if none)."""
        problems = []
        if self.fault is not None and self.fault.code not in set(P.FaultCode):
            problems.append(f"the device reported {self.describe_fault()}; what it means for the samples is "
                            "unknown (a firmware newer than this host?)")
        if self.duty_mismatches:
            problems.append(f"{self.duty_mismatches} samples carry a duty other than the WAVE's (or the controller's) "
                            f"(first: {self.first_mismatch})")
        if self.out_of_order:
            problems.append(f"{self.out_of_order} samples arrived out of order or beyond n_samples")
        if self.clock_back:
            problems.append(f"{self.clock_back} samples carry a device time that does not advance (first: "
                            f"{self.first_clock_back}), kept out of the recording")
        if self.n > e.samples_sent:
            problems.append(f"received {self.n} samples but the device sent {e.samples_sent}")
        elif e.samples_sent - (self.n + self.out_of_order + self.clock_back) > self.link_lost:
            kept_out = self.out_of_order + self.clock_back
            problems.append(f"the device sent {e.samples_sent} samples, {self.n} arrived"
                            + (f" (and {kept_out} kept out above)" if kept_out else "")
                            + f", but the link sequence shows only {self.link_lost} frames lost")
        ticks = e.samples_sent + e.samples_dropped
        if e.reason == P.EndReason.COMPLETE and ticks != len(self.expected):
            problems.append(f"END says {ticks} ticks (sent {e.samples_sent} + dropped {e.samples_dropped}), "
                            f"the experiment has {len(self.expected)}")
        if self.seq and self.seq[-1] >= ticks:
            problems.append(f"sample {self.seq[-1]} arrived but END counts only {ticks} ticks")
        return problems

    def losses(self, n: int) -> tuple[int, int]:
        """Samples the device ticked so far and how many of them did not arrive (lost or dropped).

        The ticks are END's ``samples_sent + samples_dropped`` once END arrived, else the
        index after the last sample received (the gaps before it are what is known lost).
        """
        ticks = self.last_index + 1
        if self.end is not None:
            ticks = max(ticks, self.end.samples_sent + self.end.samples_dropped)
        return ticks, max(ticks - n, 0)

    def recording(self, rig: SerialRig, *, complete: bool, reason: str = "") -> Recording:
        # an interrupt between the appends of accept() can leave one list a row longer
        n = min(len(self.seq), len(self.time), len(self.duty), len(self.counts))
        meta = {"source": "SerialRig", **self.experiment.metadata(), "port": rig.port_name,
                "baudrate": str(rig.baudrate), "line_load": f"{rig.line_load(self.dt):.3f}",
                "protocol_version": str(P.PROTOCOL_VERSION),
                "input_delay_samples": str(P.DEVICE_INPUT_DELAY),
                "complete": "true" if complete else "false"}
        if reason:
            meta["incomplete_reason"] = " ".join(reason.split())
        if rig.device is not None:
            d = rig.device
            meta.update(board=printable(d.board) or "?",
                        firmware_version=f"{d.firmware_version >> 8}.{d.firmware_version & 0xFF}",
                        f_cpu_hz=str(d.f_cpu_hz), reset_cause=f"{d.reset_cause:#04x}")
        meta.update(samples_expected=str(len(self.expected)), samples_received=str(n),
                    host_rx_errors=str(self.host_rx_errors), host_link_frames_lost=str(self.link_lost),
                    host_duty_mismatches=str(self.duty_mismatches), host_unverified_duties=str(self.unverified),
                    flagged_encoder_errors=str(self.encoder_flags),
                    flagged_late_ticks=str(self.late_flags))
        if self.end is not None:
            e = self.end
            meta.update(device_end_reason=str(e.reason), device_samples_sent=str(e.samples_sent),
                        device_samples_dropped=str(e.samples_dropped), device_encoder_errors=str(e.encoder_errors),
                        device_rx_errors=str(e.rx_errors), device_tick_overruns=str(e.tick_overruns))
        if self.fault is not None:
            meta.update(device_fault_code=str(self.fault.code), device_fault_index=str(self.fault.seq))
        if self.counter_wraps:
            meta.update(counter_wraps=str(len(self.counter_wraps)),
                        counter_wrap_samples=" ".join(map(str, self.counter_wraps[:10])))
        ticks, lost = self.losses(n)
        meta.update(samples_ticked=str(ticks), samples_lost=str(lost),
                    loss_fraction=f"{lost / ticks:.6g}" if ticks else "0")
        return Recording(time=np.array(self.time[:n]), duty=np.array(self.duty[:n], dtype=np.int64),
                         sample_period=self.dt, counts=np.array(self.counts[:n], dtype=np.int64),
                         seq=np.array(self.seq[:n], dtype=np.int64), counts_per_rev=rig.counts_per_rev,
                         metadata=meta,
                         reference=None if self.reference is None
                         else self.reference[np.array(self.seq[:n], dtype=int)])

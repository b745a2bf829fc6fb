"""``motorid live``: run an experiment on the bench, record it as it arrives, identify a and b.

The samples go three ways as they arrive: to a :class:`~motorsim.writing.RecordingWriter`
(so a fault or Ctrl-C leaves a valid recording marked ``complete: false``), to a
running RLS estimate (:mod:`identify.fits.recursive`) shown in the progress line, and
to an optional live plot.  After the run the recording is identified with
``identify.fit`` (default: ``identify.DEFAULT_METHOD``).

``--port 'fake://?a=25&b=3'`` runs the emulated Arduino, so this works without a board.
With ``--controller`` the device runs that controller (designed from ``--a/--b`` or
``--model``) against ``--reference`` instead of the excitation.
"""
from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path
from typing import NoReturn

from motorid.arguments import (
    CommandError,
    add_experiment_arguments,
    add_knob_flag,
    experiment_from_args,
    print_to_stderr,
)
from motorid.interrupts import describe_interrupt
from motorid.progress import ProgressBar
from motorsim.knobs import knobs_of
from motorsim.sensors import Encoder

__all__ = ["add_live_arguments", "run_live", "DEFAULT_MAX_LOSS", "default_out_path"]

#: Default ``--max-loss`` in %: more samples lost than this and ``live`` refuses to identify.
DEFAULT_MAX_LOSS = 2.0


def add_live_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags of ``motorid live``: the port, the bench's encoder, the experiment, the estimator."""
    from identify import DEFAULT_METHOD, available_methods

    g = parser.add_argument_group("bench")
    g.add_argument("--port", required=True, metavar="PORT",
                   help="serial port or URL: /dev/ttyACM0, COM3, socket://host:port, 'fake://?a=25&b=3' "
                        "(the emulated Arduino), avr-sim://...")
    g.add_argument("--baud", type=int, default=250_000, metavar="B",
                   help="line rate in baud (default 250000 for <= 500 Hz; 115200 is the safe choice at <= 250 Hz)")
    add_knob_flag(g, next(k for k in knobs_of(Encoder) if k.name == "counts_per_rev"))
    g.add_argument("--decoding", type=int, default=4, choices=(1, 2, 4),
                   help="quadrature decoding: counts per encoder line cycle, 1, 2 or 4 (default 4)")
    g.add_argument("--watchdog-ms", type=int, default=500, metavar="MS",
                   help="device stops the motor after this much host silence, in ms (default 500; 0 off)")
    g.add_argument("--timeout", type=float, default=1.0, metavar="S",
                   help="give up after this long without a new sample during a run, silent or not (default 1 s); "
                        "a run also gives up after its duration + 10 %% + 2 s + this timeout (on fake:// and "
                        "avr-sim://, in the device's simulated seconds)")
    parser.set_defaults(counts_per_rev=None)   # default: what the device reports, else 16667
    add_experiment_arguments(parser)
    from motorid.commands.control import add_controller_arguments, add_model_arguments
    add_controller_arguments(parser)
    add_model_arguments(parser)
    parser.add_argument("--out", default=None, metavar="FILE.csv",
                        help="path of the recording to write (default live-YYYYMMDD-HHMMSS.csv in the current "
                             "folder, named on stderr; checked before the motor starts; an existing file is "
                             "refused without --overwrite, a folder or a device always)")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing recording at --out")
    parser.add_argument("--method", default=DEFAULT_METHOD, choices=[DEFAULT_METHOD, *available_methods()],
                        help=f"estimator after the run (default {DEFAULT_METHOD}: delay and structure chosen by "
                             "evidence, as motorid identify)")
    parser.add_argument("--max-loss", type=float, default=DEFAULT_MAX_LOSS, metavar="PCT",
                        help=f"largest share of the samples run that may be lost (link or device) before live "
                             f"exits with status 2 instead of identifying, in %% (default {DEFAULT_MAX_LOSS:g})")
    parser.add_argument("--json", action="store_true",
                        help="print one JSON document on stdout (the human-readable text goes to stderr)")
    parser.add_argument("--plot", action="store_true",
                        help="show duty and speed live with the running estimate (matplotlib window; "
                             "without a display, FILE.csv.live.png is updated instead)")
    parser.add_argument("--quiet", action="store_true", help="no progress line")
    from motorid.commands.live_until import add_until_arguments
    add_until_arguments(parser)


def _estimate_note(running) -> str:
    """The running estimate as shown after the progress bar."""
    estimate = running.estimate()
    if not estimate.ready:
        return "estimate: waiting for data"
    return f"a ≈ {estimate.a:.4g} 1/s  b ≈ {estimate.b:.4g}  ({estimate.model}, {estimate.n_rows} rows)"


def _keep_what_arrived(writer, recording, reason: str) -> str:
    """Close ``writer`` as incomplete, with the rig's own copy of the run when it has one; say where it is.

    The rig's copy (``exc.recording``) also holds the samples that arrived after the last
    one written and the device's END counters read after STOP.  When the recording cannot
    be written where asked (a full disk), it goes to the temporary folder.

    Returns
    -------
    str
        Where the samples are and the loss figures, for the message; empty when none arrived.
    """
    from motorsim.recording import Recording
    if recording is None:
        try:
            path = writer.close(False, reason)
        except OSError as exc:
            return f"writing {writer.path} failed ({exc}); what was written is in {writer.partial_path}"
        return f"the {writer.n_rows} samples received are in {path} (complete: false){_unchanged(writer, path)}" \
            if path else ""
    meta = {**recording.metadata, "complete": "false", "incomplete_reason": " ".join(reason.split())}
    recording = Recording(time=recording.time, duty=recording.duty, sample_period=recording.sample_period,
                          counts=recording.counts, seq=recording.seq, counts_per_rev=recording.counts_per_rev,
                          metadata=meta)
    figures = f" ({_loss_note(meta)})"
    try:
        path = writer.close_with(recording)
    except OSError as exc:
        return f"writing {writer.path} failed ({exc}); {_rescue(recording, writer.path)}{figures}"
    return f"the {len(recording)} samples received are in {path} (complete: false){figures}{_unchanged(writer, path)}"


def _unchanged(writer, path) -> str:
    """Say that the recording already at ``--out`` was kept when an incomplete run went beside it."""
    return f"; {writer.path}, there before this run, is unchanged" if Path(path) != Path(writer.path) else ""


def _rescue(recording, path) -> str:
    """Write ``recording`` to the temporary folder when ``path`` cannot take it; say where it went."""
    import os
    import tempfile

    from motorsim.writing import write_recording
    rescue = Path(tempfile.gettempdir()) / f"motorid-rescued-{os.getpid()}-{Path(path).name}"
    try:
        write_recording(recording, rescue, at_once=True)
    except OSError as exc:
        return f"the {len(recording)} samples could not be saved anywhere (also {exc})"
    return f"the {len(recording)} samples received are in {rescue} instead"


def default_out_path(now: float | None = None) -> str:
    """``live-YYYYMMDD-HHMMSS.csv`` in the current folder (``-2``, ``-3``, ... when taken)."""
    stamp = time.strftime("%Y%m%d-%H%M%S", time.localtime(now))
    path, k = f"live-{stamp}.csv", 1
    while os.path.exists(path) or os.path.exists(f"{path}.partial"):
        k += 1
        path = f"live-{stamp}-{k}.csv"
    return path


def run_live(args: argparse.Namespace) -> int:
    """Run the experiment on the port, write the recording as it arrives, identify it."""
    from hardware.protocol import DEVICE_INPUT_DELAY
    from identify.fits.recursive import RunningEstimator
    from motorid.commands.control import refuse_controller_flags
    if not 0 <= args.max_loss <= 100:
        raise CommandError(f"--max-loss must be a percentage in 0...100, got {args.max_loss!r}")
    from motorid.commands.live_until import check_until_flags, run_live_until
    check_until_flags(args)                             # before the port opens
    if args.until is not None:
        return run_live_until(args, default_out_path)
    refuse_controller_flags(args, model_flags=True)     # before the port opens
    named = args.out is not None
    if not named:
        args.out = default_out_path()
    if args.plot:
        from motorsim.files import check_output_path
        check_output_path(f"{args.out}.live.png", flag="--plot (its figure FILE.csv.live.png)")
    rig, experiment, writer = _open_rig_and_writer(args, experiment_from_args(args), named)
    if not named:
        print_to_stderr(f"recording to {args.out}")
    # the device applies each duty one tick after its sample
    delay = DEVICE_INPUT_DELAY
    running = RunningEstimator(experiment.sample_period, args.counts_per_rev, input_delay=delay)
    progress = ProgressBar(experiment.n_samples, "live", unit="samples", interval=0.25,
                           enabled=None if not args.quiet and experiment.n_samples > 0 else False)
    plot = None
    if args.plot:
        from motorid.plots import LivePlot
        plot = LivePlot(experiment, counts_per_rev=args.counts_per_rev, fallback_path=f"{args.out}.live.png")

    def on_sample(s) -> None:
        writer.append(s.seq, s.time_s, s.duty, s.counts)
        running.add(s.seq, s.time_s, s.duty, s.counts)
        progress.set(s.seq + 1, lambda: _estimate_note(running))
        if plot is not None:
            plot.add(s, running)

    try:
        try:
            with rig:
                recording = rig.run(experiment, on_sample=on_sample)
        except BaseException as exc:   # a rig error, a write error, Ctrl-C, SIGTERM: keep what arrived
            progress.close()
            _keep_and_reraise(exc, writer)
        progress.set(experiment.n_samples, lambda: _estimate_note(running), force=True)
        progress.close()
        path, problem = _close_writer(writer, recording)
        status = _report(args, recording, path, running, plot)
    finally:
        if plot is not None:
            plot.close()
    if problem:
        raise CommandError(problem)
    return status


def _open_rig_and_writer(args: argparse.Namespace, experiment, named: bool = True):
    """Open the port (handshake only: the motor does not turn) and the recording writer.

    The device reports its encoder's counts per revolution in the handshake; a closed-loop
    experiment is designed with it.  The writer is made before the motor turns, so an
    ``--out`` that cannot be written stops here; a default name (not ``named``) that another
    run took meanwhile is moved on to the next free one.  Returns ``(rig, experiment, writer)``.
    """
    from hardware.protocol import DEVICE_INPUT_DELAY
    from motorid.commands.live_until import open_rig
    from motorsim.writing import RecordingWriter
    rig = open_rig(args)
    args.counts_per_rev = rig.counts_per_rev
    try:
        if args.controller:
            from motorid.commands.control import closed_loop_from_args
            experiment = closed_loop_from_args(args, experiment.sample_period, rig.counts_per_rev,
                                               rig_input_delay=DEVICE_INPUT_DELAY)
        metadata = {"source": "SerialRig", **experiment.metadata(), "port": args.port,
                    "input_delay_samples": str(DEVICE_INPUT_DELAY)}
        for _ in range(100):
            try:
                writer = RecordingWriter(args.out, experiment.sample_period, args.counts_per_rev,
                                         overwrite=args.overwrite, metadata=metadata)
                break
            except OSError:
                if named or not os.path.lexists(f"{args.out}.partial"):
                    raise
                args.out = default_out_path()     # another run started in the same second took the name
        else:
            raise CommandError(f"no free default recording name near {args.out}; give --out")
    except BaseException:
        rig.close()
        raise
    return rig, experiment, writer


def _keep_and_reraise(exc: BaseException, writer) -> NoReturn:
    """Keep what arrived before ``exc`` ended the run, say where, and raise the error to report."""
    from hardware.errors import RigError
    reason = describe_interrupt(exc) if isinstance(exc, KeyboardInterrupt) else f"{type(exc).__name__}: {exc}"
    kept = _keep_what_arrived(writer, getattr(exc, "recording", None), reason)
    if isinstance(exc, RigError):
        raise CommandError(f"{exc}; {kept}" if kept else str(exc)) from None
    if isinstance(exc, OSError):      # the recording could not be written: the rig sent STOP
        raise CommandError(f"{exc}; the motor was stopped; {kept}" if kept else str(exc)) from None
    if kept:
        print_to_stderr(f"motorid: {kept}")
    raise exc


def _close_writer(writer, recording) -> tuple[Path, str]:
    """Write the final recording; on a write failure (a full disk) rescue it and return the problem."""
    try:
        if recording.reference is not None:    # the rows written as they came do not carry the reference
            return writer.close_with(recording), ""
        path = writer.close(True, metadata=recording.metadata)
        return (path if path is not None else Path(writer.path)), ""
    except OSError as exc:         # the whole run is still in memory
        return Path(writer.path), f"writing {writer.path} failed ({exc}); {_rescue(recording, writer.path)}"


def _loss_note(m) -> str:
    """The loss figures of a run's metadata, as every ending of ``live`` states them."""
    ticked, lost = int(m.get("samples_ticked", 0)), int(m.get("samples_lost", 0))
    device = m.get("device_samples_dropped", "?")
    return (f"{m.get('samples_received', '?')} received of {m.get('samples_expected', '?')}; "
            f"{lost} of the {ticked} samples run lost ({100 * float(m.get('loss_fraction', 0)):.3g} %): "
            f"{m.get('host_link_frames_lost', '?')} frames lost on the link, {device} dropped by the device, "
            f"{m.get('host_rx_errors', '?')} bad frames (CRC or framing)")


def _report(args: argparse.Namespace, recording, path, running, plot=None) -> int:
    """After a complete run: the summary line, the loss check, the estimates (and JSON)."""
    from identify import fit
    from motorid.commands.identify import format_estimate
    say = print_to_stderr if args.json else print
    m = recording.metadata
    say(f"wrote {len(recording)} samples to {path}: {_loss_note(m)}")
    loss_pct = 100 * float(m["loss_fraction"])
    if loss_pct > args.max_loss:
        raise CommandError(f"{m['samples_lost']} of the {m['samples_ticked']} samples were lost "
                           f"({loss_pct:.3g} %), above --max-loss {args.max_loss:g} %; {path} is kept but not "
                           f"identified: check the cable and the baud rate, or raise --max-loss")
    from hardware.protocol import DEVICE_INPUT_DELAY
    from identify import method_options
    # the device applies each duty one tick after its sample: a known delay, not one to search for
    options = {"input_delay": DEVICE_INPUT_DELAY} if "input_delay" in method_options(args.method) else {}
    estimate = fit(recording, method=args.method, outliers="keep", **options)
    if plot is not None:
        plot.show_fit(recording, estimate)
    say(format_estimate(estimate))
    run_est = running.estimate()
    if run_est.ready:
        say(f"running     a {run_est.a:.6g} 1/s, b {run_est.b:.6g} ({run_est.model}, {run_est.n_rows} rows, "
              f"the estimate shown during the run)")
    if args.json:
        out = {**estimate.to_dict(), "running_estimate": run_est.to_dict(), "recording": str(path),
               "samples_received": len(recording), "samples_expected": int(m["samples_expected"]),
               "samples_lost": int(m["samples_lost"]), "loss_fraction": float(m["loss_fraction"]),
               "link_frames_lost": int(m["host_link_frames_lost"]),
               "device_samples_dropped": int(m["device_samples_dropped"]),
               "host_rx_errors": int(m["host_rx_errors"])}
        print(json.dumps(out))
    return 0

"""``motorid live``: run an experiment on the bench, record it as it arrives, identify a and b.

The samples go three ways as they arrive: to a :class:`~motorsim.recording.RecordingWriter`
(so a fault or Ctrl-C leaves a valid recording marked ``complete: false``), to a
running RLS estimate (:mod:`identify.recursive`) shown in the progress line, and
to an optional live plot.  After the run the recording is identified with
``identify.fit`` (default: ``identify.DEFAULT_METHOD``).

``--port 'fake://?a=25&b=3'`` runs the emulated Arduino, so this works without a board.
With ``--controller`` the device runs that controller (designed from ``--a/--b`` or
``--model``) against ``--reference`` instead of the excitation.
"""
from __future__ import annotations

import argparse
import json

from motorsim.knobs import knobs_of
from motorsim.sensors import Encoder

from .arguments import CommandError, add_experiment_arguments, add_knob_flag, experiment_from_args, print_to_stderr
from .progress import ProgressBar

__all__ = ["add_live_arguments", "run_live"]


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
                   help="give up after the device is silent this long during a run (default 1 s)")
    parser.set_defaults(counts_per_rev=None)   # default: what the device reports, else 16667
    add_experiment_arguments(parser)
    from .control import add_controller_arguments, add_model_arguments
    add_controller_arguments(parser)
    add_model_arguments(parser)
    parser.add_argument("--out", required=True, metavar="FILE.csv", help="path of the recording to write")
    parser.add_argument("--method", default=DEFAULT_METHOD, choices=available_methods(),
                        help=f"estimator after the run (default {DEFAULT_METHOD})")
    parser.add_argument("--json", action="store_true", help="end the output with one JSON line")
    parser.add_argument("--plot", action="store_true",
                        help="show duty and speed live with the running estimate (matplotlib window; "
                             "without a display, FILE.csv.live.png is updated instead)")
    parser.add_argument("--quiet", action="store_true", help="no progress line")


def _estimate_note(running) -> str:
    """The running estimate as shown after the progress bar."""
    estimate = running.estimate()
    if not estimate.ready:
        return "estimate: waiting for data"
    return f"a ≈ {estimate.a:.4g} 1/s  b ≈ {estimate.b:.4g}  ({estimate.model}, {estimate.n_rows} rows)"


def run_live(args: argparse.Namespace) -> int:
    """Run the experiment on the port, write the recording as it arrives, identify it."""
    from hardware.errors import RigError
    from hardware.serial_rig import SerialRig
    from identify import fit
    from identify.recursive import RunningEstimator
    from motorsim.control import ClosedLoopExperiment
    from motorsim.recording import RecordingWriter, write_recording
    from motorsim.rig import Experiment

    from .identification import format_estimate
    experiment: Experiment | ClosedLoopExperiment = experiment_from_args(args)
    rig = SerialRig(args.port, args.baud, counts_per_rev=args.counts_per_rev, decoding=args.decoding,
                    watchdog_ms=args.watchdog_ms, timeout=args.timeout)
    try:
        rig.open()   # the handshake: the device may report its encoder's counts per revolution
    except RigError as exc:
        raise CommandError(str(exc)) from None
    args.counts_per_rev = rig.counts_per_rev
    if args.controller:
        from .control import closed_loop_from_args
        try:
            experiment = closed_loop_from_args(args, experiment.sample_period, rig.counts_per_rev)
        except BaseException:
            rig.close()
            raise
    running = RunningEstimator(experiment.sample_period, args.counts_per_rev)
    progress = ProgressBar(experiment.n_samples, "live", unit="samples", interval=0.25,
                           enabled=not args.quiet and experiment.n_samples > 0)
    plot = None
    if args.plot:
        from .plots import LivePlot
        plot = LivePlot(experiment, counts_per_rev=args.counts_per_rev, fallback_path=f"{args.out}.live.png")
    writer = RecordingWriter(args.out, experiment.sample_period, args.counts_per_rev,
                             metadata={"source": "SerialRig", **experiment.metadata(), "port": args.port})

    def on_sample(s) -> None:
        writer.append(s.seq, s.time_s, s.duty, s.counts)
        running.add(s.seq, s.time_s, s.duty, s.counts)
        progress.set(s.seq + 1, lambda: _estimate_note(running))
        if plot is not None:
            plot.add(s, running)

    try:
        with rig:
            recording = rig.run(experiment, on_sample=on_sample)
    except RigError as exc:
        progress.close()
        meta = exc.recording.metadata if exc.recording is not None else None
        path = writer.close(False, f"{type(exc).__name__}: {exc}", metadata=meta)
        kept = f"; the {writer.n_rows} samples received are in {path} (complete: false)" if path else ""
        raise CommandError(f"{exc}{kept}") from None
    except BaseException as exc:   # Ctrl-C, a protocol version mismatch, ...: keep what arrived
        progress.close()
        reason = "interrupted (Ctrl-C)" if isinstance(exc, KeyboardInterrupt) else f"{type(exc).__name__}: {exc}"
        path = writer.close(False, reason)
        if path is not None:
            print_to_stderr(f"motorid: the {writer.n_rows} samples received are in {path} (complete: false)")
        raise
    finally:
        if plot is not None:
            plot.close()
    progress.set(experiment.n_samples, lambda: _estimate_note(running), force=True)
    progress.close()
    path = writer.close(True, metadata=recording.metadata)
    if recording.reference is not None and path is not None:
        write_recording(recording, path)   # again, with the reference column the rows did not carry
    estimate = fit(recording, method=args.method)
    m = recording.metadata
    print(f"wrote {len(recording)} samples to {path}: {m['samples_received']} received of "
          f"{m['samples_expected']}, {m['host_link_frames_lost']} lost on the link, "
          f"{m['device_samples_dropped']} dropped by the device, {m['host_rx_errors']} bad frames")
    print(format_estimate(estimate))
    run_est = running.estimate()
    if run_est.ready:
        print(f"running     a {run_est.a:.6g} 1/s, b {run_est.b:.6g} ({run_est.model}, {run_est.n_rows} rows, "
              f"the estimate shown during the run)")
    if args.json:
        out = {**estimate.to_dict(), "running_estimate": run_est.to_dict(), "recording": str(path),
               "samples_received": len(recording), "samples_expected": experiment.n_samples,
               "link_frames_lost": int(m["host_link_frames_lost"]),
               "device_samples_dropped": int(m["device_samples_dropped"]),
               "host_rx_errors": int(m["host_rx_errors"])}
        print(json.dumps(out))
    return 0

"""``motorid simulate``: run an experiment on the simulated bench and write the recording.

With ``--controller`` the run is closed loop: the controller, designed from the bench's
own motor flags (or ``--model FILE``), tracks ``--reference`` and the recording gains
the ``reference`` column.
"""
from __future__ import annotations

import argparse

from motorid.arguments import (
    EXCITATION_FLAGS,
    CommandError,
    add_bench_arguments,
    add_experiment_arguments,
    experiment_from_args,
    sim_rig_from_args,
)
from motorid.budget import SIMULATE_BYTES_PER_SAMPLE, add_max_memory_flag, check_memory
from motorid.ranges import BENCH_RULES, check_bench_flags
from motorsim.writing import write_recording

__all__ = ["add_simulate_arguments", "run_simulate"]


def add_simulate_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags of ``motorid simulate``: the bench, the experiment, a controller and ``--out``."""
    from motorid.commands.control import add_controller_arguments
    add_bench_arguments(parser, BENCH_RULES)
    add_experiment_arguments(parser, BENCH_RULES)
    add_controller_arguments(parser)
    parser.add_argument("--out", required=True, metavar="FILE.csv", help="path of the recording to write")
    add_max_memory_flag(parser)


def run_simulate(args: argparse.Namespace) -> int:
    """Simulate the experiment (or the closed loop) and write the recording (format v1)."""
    check_bench_flags(args)        # the bench's ranges first: the memory a run needs follows from its length
    n = args.duration / args.sample_period
    check_memory(f"simulating {n:,.0f} samples", n * SIMULATE_BYTES_PER_SAMPLE, args.max_memory)
    if getattr(args, "controller", None):
        return _run_closed_loop(args)
    from motorid.commands.control import refuse_controller_flags
    refuse_controller_flags(args)      # --a/--b, --friction, ... are the bench's here
    rec = sim_rig_from_args(args).run(experiment_from_args(args))
    path = write_recording(rec, args.out)
    print(f"wrote {len(rec)} samples ({rec.metadata['excitation']}) to {path}")
    return 0


def _run_closed_loop(args: argparse.Namespace) -> int:
    from motorid.commands.control import (
        controller_from_args,
        load_model_file,
        model_from_args,
        reference_from_args,
        require_duty_model,
    )
    from motorsim.control import ClosedLoopExperiment, tracking_error
    given = [f"--{name}" for name in (*EXCITATION_FLAGS, "excitation") if getattr(args, name.replace("-", "_"), None)]
    if given:
        raise CommandError(f"{', '.join(given)} and --controller exclude each other: the controller sets the duty")
    require_duty_model(args)
    controller = controller_from_args(args, model_from_args(args))
    speed_unit = load_model_file(args.model).speed_unit if args.model else "rad/s"
    reference = reference_from_args(args, controller, speed_unit, float(args.duty_limit))
    rec = sim_rig_from_args(args).run(ClosedLoopExperiment(controller, reference, args.duration, args.duty_limit))
    path = write_recording(rec, args.out)
    measured = float((tracking_error(rec) ** 2).mean() ** 0.5)
    predicted = controller.predict(reference, args.duration).tracking_rms
    print(f"wrote {len(rec)} samples ({controller.kind} tracking {reference.describe()}) to {path}")
    print(f"tracking RMS: measured {measured:.4g}, predicted {predicted:.4g} {controller.reference_unit}")
    return 0

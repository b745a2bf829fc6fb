"""``motorid simulate``: run an experiment on the simulated bench and write the recording."""
from __future__ import annotations

import argparse

from motorsim.recording import write_recording

from .arguments import add_bench_arguments, add_experiment_arguments, experiment_from_args, sim_rig_from_args
from .budget import SIMULATE_BYTES_PER_SAMPLE, add_max_memory_flag, check_memory

__all__ = ["add_simulate_arguments", "run_simulate"]


def add_simulate_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags of ``motorid simulate``: the bench, the experiment and ``--out``."""
    add_bench_arguments(parser)
    add_experiment_arguments(parser)
    parser.add_argument("--out", required=True, metavar="FILE.csv", help="path of the recording to write")
    add_max_memory_flag(parser)


def run_simulate(args: argparse.Namespace) -> int:
    """Simulate the experiment and write the recording (format v1)."""
    if args.sample_period > 0 and args.duration > 0:    # before the Experiment computes its duty
        n = args.duration / args.sample_period
        check_memory(f"simulating {n:,.0f} samples", n * SIMULATE_BYTES_PER_SAMPLE, args.max_memory)
    rec = sim_rig_from_args(args).run(experiment_from_args(args))
    path = write_recording(rec, args.out)
    print(f"wrote {len(rec)} samples ({rec.metadata['excitation']}) to {path}")
    return 0

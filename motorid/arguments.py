"""Command-line pieces every ``motorid`` command shares: bench and experiment flags, errors, messages on stderr.

The flags of the simulated bench and of an experiment are derived from the bench knobs
(:func:`motorsim.rig.bench_knobs`): each knob ``name`` is the flag ``--name`` with its unit
and default in the help text, so a knob added to ``Motor``, ``Encoder``, ``SimRig`` or
``Experiment`` is a flag of ``motorid simulate`` and ``motorid demo`` without a change here.
"""
from __future__ import annotations

import argparse
import sys
from typing import Any, Callable, Mapping

import numpy as np

from motorsim.excitation import parse_excitation
from motorsim.knobs import Knob, knobs_of
from motorsim.plant import Motor
from motorsim.rig import Experiment, SimRig
from motorsim.sensors import Encoder

__all__ = ["CommandError", "print_to_stderr", "add_knob_flag", "add_bench_arguments", "sim_rig_from_args",
           "add_experiment_arguments", "experiment_from_args", "warn_if_clipped", "UNCLIPPED_LIMIT", "EXCITATION_FLAGS"]


class CommandError(Exception):
    """A user-facing error: printed as ``motorid: error: ...``, exit status 2."""


def print_to_stderr(*parts: Any, end: str = "\n") -> None:
    """Print to standard error and flush (progress lines, warnings): control characters escaped, newlines kept."""
    from motorsim.text import printable
    print(printable(" ".join(map(str, parts)), newlines=True), end=end, file=sys.stderr, flush=True)


def _flag_type(k: Knob) -> Callable[[str], Any]:
    def parse(text: str) -> Any:
        try:
            return k.parse(text)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None
    parse.__name__ = k.name
    return parse


def _seed(text: str) -> int:
    """``--seed``: an integer >= 0 (numpy's generators take no negative seed)."""
    try:
        value = int(text) if text.strip().isascii() else -1
    except ValueError:
        value = -1
    if value < 0:
        raise argparse.ArgumentTypeError(f"--seed must be an integer >= 0, got {text!r}")
    return value


def add_knob_flag(group: Any, k: Knob, default: Any = None, rule: str | None = None) -> None:
    """Add the flag ``--name`` of knob ``k`` (``default`` overrides the knob's own; ``rule``, the range a command
    holds it to, is said after its own help)."""
    value = k.default if default is None else default
    help_ = k.describe() if default is None else f"{k.help}{f' [{k.unit}]' if k.unit else ''} (default {value!r})"
    if rule:
        help_ = f"{help_}; {rule}"
    if k.kind is bool:
        group.add_argument(k.flag, dest=k.name, action="store_true", help=k.describe())
    elif k.required and default is None:
        group.add_argument(k.flag, dest=k.name, type=_flag_type(k), required=True, help=help_)
    else:
        group.add_argument(k.flag, dest=k.name, type=_flag_type(k), default=value, help=help_)


def _values(args: argparse.Namespace, cls: type) -> dict[str, Any]:
    return {k.name: getattr(args, k.name) for k in knobs_of(cls)}


def add_bench_arguments(parser: argparse.ArgumentParser, rules: Mapping[str, str] | None = None,
                        **defaults: Any) -> None:
    """Flags of the simulated bench: every knob of Motor, Encoder and SimRig, and ``--seed``.

    ``defaults`` give defaults to knobs by name (``a=25.0`` makes ``--a`` optional); ``rules``, the ranges the
    command holds knobs to by name (:data:`motorid.ranges.BENCH_RULES`), are said in their help.
    """
    g = parser.add_argument_group("simulated bench")
    for cls in (Motor, Encoder, SimRig):
        for k in knobs_of(cls):
            add_knob_flag(g, k, defaults.get(k.name), (rules or {}).get(k.name))
    g.add_argument("--seed", type=_seed, default=0, help="seed of the noise, jitter and drops (default 0)")


def sim_rig_from_args(args: argparse.Namespace) -> SimRig:
    """The SimRig the bench flags describe (a rule they break is a :class:`CommandError`)."""
    try:
        return SimRig(Motor(**_values(args, Motor)), Encoder(**_values(args, Encoder)), **_values(args, SimRig),
                      rng=np.random.default_rng(args.seed))
    except (ValueError, TypeError) as exc:
        raise CommandError(f"bench flags: {exc}") from exc


#: Excitation flags: ``--NAME ARGS`` is the same as ``--excitation NAME:ARGS``.
EXCITATION_FLAGS = {
    "sine": "FREQ[,AMP[,PHASE]]: the article's A sin(omega t + alpha); FREQ in rad/s, AMP in duty "
            "(default 200), PHASE in rad",
    "multisine": "F,A,P;F,A,P...: up to 4 sines (rad/s, duty, rad)",
    "chirp": "F0,F1[,AMP]: linear chirp from F0 to F1 rad/s, AMP in duty",
    "prbs": "HIGH,LOW[,ORDER[,HOLD[,SEED]]]: maximal-length PRBS between two duties, each bit held HOLD samples",
    "step": "AFTER[,AT_TIME[,BEFORE]]: step of the duty at AT_TIME s",
    "constant": "LEVEL: constant duty",
    "odd-multisine": "PERIOD,MAX_HARMONIC,AMP[,SEED[,GROUP]]: odd random-phase multisine for the frequency "
                     "response, a period of PERIOD samples (a power of two), odd harmonics up to MAX_HARMONIC of "
                     "AMP duty each, one of every GROUP (default 3) left out; SEED picks the phases (0: Schroeder)",
}


def add_experiment_arguments(parser: argparse.ArgumentParser, rules: Mapping[str, str] | None = None,
                             **defaults: Any) -> None:
    """Flags of an :class:`~motorsim.rig.Experiment`: its knobs and the excitation.

    ``defaults`` give defaults to knobs by name (``duration=60.0``); ``rules``, as for :func:`add_bench_arguments`.
    """
    g = parser.add_argument_group("experiment")
    for k in knobs_of(Experiment):
        add_knob_flag(g, k, defaults.get(k.name), (rules or {}).get(k.name))
    ex = g.add_mutually_exclusive_group()
    for name, help_ in EXCITATION_FLAGS.items():
        ex.add_argument(f"--{name}", metavar="ARGS", help=help_)
    ex.add_argument("--excitation", metavar="KIND:ARGS",
                    help="any excitation as KIND:ARGS, e.g. sine:10,200 (default sine:10,200,0)")


#: Duty limit used to see what an excitation asks for before the bench clips it.
UNCLIPPED_LIMIT = 32767


def experiment_from_args(args: argparse.Namespace) -> Experiment:
    """The Experiment the flags describe (default: the article's 200 sin(10 t)); a broken rule is a CommandError.

    When the excitation asks for more duty than ``--duty-limit``, says so on stderr (the duty
    is clipped, as the firmware clips it).
    """
    spec, given = args.excitation, f"--excitation {args.excitation}"
    for name in EXCITATION_FLAGS:
        value = getattr(args, name.replace("-", "_"), None)
        if value is not None:
            if not value.strip():
                raise CommandError(f"--{name} needs {EXCITATION_FLAGS[name].split(':')[0]}, got {value!r}")
            spec, given = f"{name}:{value}", f"--{name} {value}"
    if spec is not None and not spec.strip():
        raise CommandError(f"--excitation needs KIND:ARGS (e.g. sine:10,200), got {spec!r}")
    try:
        experiment = Experiment(parse_excitation("sine:10,200,0" if spec is None else spec),
                                **_values(args, Experiment))
    except (ValueError, TypeError) as exc:
        raise CommandError(f"experiment flags: {exc}") from exc
    warn_if_clipped(experiment, given)
    return experiment


def warn_if_clipped(experiment: Experiment, given: str) -> int:
    """Say on stderr when ``experiment``'s excitation asks for more than its duty limit.

    ``given`` names the excitation as the user wrote it (``"--sine 10,300"``).

    Returns
    -------
    int
        The largest duty magnitude the excitation asks for before clipping.
    """
    wanted = int(np.max(np.abs(experiment.excitation.duty(experiment.n_samples, experiment.sample_period,
                                                          UNCLIPPED_LIMIT)), initial=0))
    if wanted > experiment.duty_limit:
        print_to_stderr(f"motorid: {given} asks for duty up to {wanted}; clipped to the duty limit "
                        f"±{experiment.duty_limit}")
    return wanted

"""``motorid sweep``: a scenario swept from the command line, its table and its figures.

The sweep itself (grid points, estimators, executors, the tidy CSV and ``summary.json``)
is the engine :func:`scenarios.sweep.run_scenario`; this module is its flags, the
progress bar, the Dask executor of ``--dask``, the printed table and the PNGs.
"""
from __future__ import annotations

import argparse
import concurrent.futures
import contextlib
import math
import os
import sys
from pathlib import Path
from typing import Iterator, Sequence

from motorid.arguments import CommandError, print_to_stderr
from motorid.progress import ProgressBar
from motorsim.files import safe_file_name, staged_path
from scenarios.executors import usable_workers
from scenarios.scenario import Scenario
from scenarios.sweep import axis_column, read_sweep_csv, run_scenario

__all__ = ["add_sweep_arguments", "run_sweep", "make_plots", "format_sweep_table", "DASK_CONNECT_TIMEOUT"]


def make_plots(scenario: Scenario, csv_path: str | os.PathLike, out_dir: str | os.PathLike) -> list[Path]:
    """The PNGs of a sweep: bias and spread against frequency and heatmaps of the absolute bias of a and b.

    The bias plot is against frequency, or when frequency is not a grid axis, against the
    first numeric axis; the heatmaps span the first two numeric grid axes (other axes held
    at their first value).
    """
    from motorid import plots
    out = Path(out_dir)
    rows = read_sweep_csv(csv_path)
    columns = list(dict.fromkeys(axis_column(a) for a in scenario.axes))
    numeric = [c for c in columns if c != "excitation"]
    paths = []
    if numeric:
        x = "frequency" if "frequency" in numeric else numeric[0]
        others = [c for c in columns if c != x]
        paths.append(out / f"bias_vs_{x}.png")
        plots.plot_sweep_frequency(rows, paths[-1], others=others, x=x,
                                   title=f"{scenario.name}: bias and spread against {x}")
    if len(numeric) >= 2:
        x, y = numeric[0], numeric[1]
        fixed = {c: rows[0][c] for c in columns if c not in (x, y)}
        sub = [r for r in rows if all(r[c] == v for c, v in fixed.items())]
        note = ("; " + ", ".join(f"{c}={v:g}" if isinstance(v, float) else f"{c}={v}" for c, v in fixed.items())
                if fixed else "")
        for name in ("a", "b"):
            paths.append(out / f"heatmap_bias_{name}.png")
            plots.plot_sweep_heatmap(sub, x, y, paths[-1], value=f"bias_{name}_pct",
                                     value_label=f"|bias of {name}| [% of the true {name}]",
                                     title=f"{scenario.name}: |bias of {name}| in %{note}")
    return paths


def format_sweep_table(scenario: Scenario, rows: Sequence[dict]) -> str:
    """The sweep as a table: grid values, method, mean +- std and bias of a and b, the CRB, failures."""
    cols = list(dict.fromkeys(axis_column(a) for a in scenario.axes))
    def cell(v):
        return f"{v:g}" if isinstance(v, float) else str(v)
    widths = [max(len(c), *(len(cell(r[c])) for r in rows)) for c in cols]
    head = " ".join(f"{c:>{w}}" for c, w in zip(cols, widths)) + (
        f" {'method':<10} {'a mean ± std':>22} {'a bias %':>9} {'CRB a':>8} "
        f"{'b mean ± std':>22} {'b bias %':>9} {'CRB b':>8} {'fail':>5}")
    lines = [head, "-" * len(head)]

    def num(v, spec):
        return "-" if math.isnan(v) else format(v, spec)
    for r in rows:
        lines.append(" ".join(f"{cell(r[c]):>{w}}" for c, w in zip(cols, widths))
                     + f" {r['method']:<10} {num(r['mean_a'], '.4f'):>11} ± {num(r['std_a'], '.2g'):<8}"
                     f" {num(r['bias_a_pct'], '+.3f'):>9} {num(r['crb_a'], '.2g'):>8}"
                     f" {num(r['mean_b'], '.5f'):>11} ± {num(r['std_b'], '.2g'):<8}"
                     f" {num(r['bias_b_pct'], '+.3f'):>9} {num(r['crb_b'], '.2g'):>8} {int(r['failures']):>5d}")
    return "\n".join(lines)


def add_sweep_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags of ``motorid sweep``."""
    parser.add_argument("scenario", nargs="?", metavar="NAME|FILE.toml",
                        help="a built-in scenario (see --list) or a scenario file")
    from motorid.budget import add_max_memory_flag
    add_max_memory_flag(parser)
    parser.add_argument("--list", action="store_true", help="list the built-in scenarios and exit")
    parser.add_argument("--out", default=None, metavar="DIR",
                        help="folder for sweep.csv, summary.json and the PNGs (default sweep-output/NAME)")
    parser.add_argument("--workers", type=int, default=None, metavar="N",
                        help="worker processes (default: all cores; more are clamped to the cores; "
                             "1 runs in this process)")
    parser.add_argument("--repetitions", type=int, default=None, metavar="N",
                        help="Monte Carlo repetitions per grid point (default: the scenario's)")
    parser.add_argument("--methods", default=None, metavar="all|M,M,...",
                        help="estimators to compare instead of the scenario's (e.g. all, or oe,oe-friction)")
    parser.add_argument("--dask", default=None, metavar="ADDRESS",
                        help="run on a Dask cluster (scheduler address, or 'local' for a LocalCluster of "
                             "--workers processes; gives up after 10 s without a scheduler); the scheduler "
                             "runs code of its choosing here: use only one you trust; needs motorid[dask]")
    parser.add_argument("--quiet", action="store_true", help="no progress bar, no table")
    parser.add_argument("--no-plots", action="store_true", help="skip the PNG figures")


def run_sweep(args: argparse.Namespace) -> int:
    """``motorid sweep``: the CLI glue around :func:`run_scenario`."""
    from scenarios.scenario import builtin_scenarios
    if args.list:
        for name, description in builtin_scenarios().items():
            print(f"{name:<16} {description}")
        return 0
    scenario = _scenario_from_args(args)
    from motorid.budget import check_sweep
    check_sweep(scenario, args.max_memory)
    out = Path(args.out or Path("sweep-output") / safe_file_name(scenario.name, "scenario"))
    if args.workers and not args.dask and args.workers > usable_workers(args.workers):
        print(f"--workers {args.workers}: using {usable_workers(args.workers)}, the cores available "
              "(more processes than cores only slow a sweep down)", file=sys.stderr)
    if not args.quiet:
        from scenarios.sweep_time import estimate_sweep_time
        print_to_stderr(estimate_sweep_time(scenario, args.workers).describe(scenario))
    with _dask_executor(args.dask, args.workers) as executor, \
            ProgressBar(scenario.n_points, f"sweep {scenario.name}", enabled=False if args.quiet else None) as bar:
        summary = run_scenario(scenario, out, workers=args.workers, executor=executor, progress=bar.set)
    if not args.quiet:
        print(f"{scenario.name}: {scenario.description}")
        print(f"{summary.n_points} points x {len(scenario.methods)} methods x {scenario.repetitions} repetitions, "
              f"{summary.samples_simulated:,} samples simulated in {summary.elapsed:.2f} s\n")
        rows = read_sweep_csv(staged_path(summary.csv_path))
        print(format_sweep_table(scenario, rows) if len(rows) <= 200 else f"({len(rows)} rows: see the CSV)")
    paths = [] if args.no_plots else make_plots(scenario, staged_path(summary.csv_path), out)
    print(f"\nwrote {summary.csv_path}, {summary.json_path}" + "".join(f", {p}" for p in paths))
    return 0


def _scenario_from_args(args: argparse.Namespace) -> Scenario:
    """The scenario the flags name, with ``--repetitions`` and ``--methods`` applied."""
    from scenarios.scenario import load_scenario
    if not args.scenario:
        raise CommandError("sweep needs a scenario NAME or FILE.toml (see motorid sweep --list)")
    if args.workers is not None and args.workers < 1:
        raise CommandError(f"--workers must be >= 1, got {args.workers}")
    scenario = load_scenario(args.scenario)
    if args.repetitions is not None:
        scenario = scenario.with_repetitions(args.repetitions)
    if args.methods is not None:
        scenario = scenario.with_methods("all" if args.methods == "all"
                                         else [m.strip() for m in args.methods.split(",") if m.strip()])
    return scenario


#: Seconds ``--dask ADDRESS`` waits for the scheduler before giving up.
DASK_CONNECT_TIMEOUT = 10.0


def _connect_dask(client_class, address: str):
    """A Dask client on ``address``, or a one-line :class:`CommandError` within :data:`DASK_CONNECT_TIMEOUT` s."""
    _check_dask_address(address)
    try:
        return client_class(address, timeout=DASK_CONNECT_TIMEOUT)
    except (OSError, TimeoutError) as exc:
        raise CommandError(f"--dask {address}: no Dask scheduler answered within {DASK_CONNECT_TIMEOUT:g} s "
                           f"({type(exc).__name__}: {exc}); check the address (tcp://HOST:8786, tls://...) "
                           f"and that the scheduler runs") from None
    except Exception as exc:    # whatever a server that is not a Dask scheduler makes the client raise
        raise CommandError(f"--dask {address}: the server there does not speak Dask's protocol "
                           f"({type(exc).__name__}: {str(exc)[:200]})") from None


def _check_dask_address(address: str) -> None:
    """Refuse, before any connection, an ``--dask`` that is no scheduler address (``[SCHEME://]HOST:PORT``)."""
    from urllib.parse import urlsplit
    parts = urlsplit(address if "://" in address else f"tcp://{address}")
    try:
        port = parts.port
    except ValueError:
        port = None
    if not parts.hostname or port is None:
        raise CommandError(f"--dask must be 'local' or a scheduler address [SCHEME://]HOST:PORT (e.g. "
                           f"tcp://10.0.0.5:8786), got {address!r}")


@contextlib.contextmanager
def _dask_executor(address: str | None, workers: int | None) -> Iterator[concurrent.futures.Executor | None]:
    """A Dask client's executor for ``--dask ADDRESS`` (``local``: a LocalCluster), else None."""
    if not address:
        yield None
        return
    try:
        from dask.distributed import Client, LocalCluster
    except ImportError:
        raise CommandError("--dask needs Dask: pip install 'motorid[dask]'") from None
    cluster = None
    if address == "local":
        cluster = LocalCluster(n_workers=workers or os.cpu_count() or 1, threads_per_worker=1,
                               processes=True, dashboard_address=None)
        client = Client(cluster)
    else:
        client = _connect_dask(Client, address)
    try:
        yield client.get_executor()
    finally:
        client.close()
        if cluster is not None:
            cluster.close()

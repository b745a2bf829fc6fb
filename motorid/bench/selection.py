"""``motorid bench selection``: what choosing the model by evidence costs, against one fit and a CSV read.

Two goals, each a ratio measured in one run:

* on 10 000 samples the default (``identify.fit(rec)``: input delay and structure chosen) within
  10 times one ``oe`` fit at a fixed delay of the same recording (a multisine on a 16667-count
  encoder, the linear motor the default meets most); the same ratio on a Coulomb-friction run is
  printed too, with the ratio to one fit of the chosen ``oe-friction`` at its delay (there the
  friction candidates are fitted, each several ``oe`` fits: no goal, the figures are what it costs);
* end to end on a 10^6-row recording file, ``motorid identify FILE``'s work (read, screen, the
  default fit, the outlier check: :func:`motorid.screening.read_and_fit`) within 4 times
  ``pandas.read_csv`` of the same file.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path
from typing import Sequence

from motorid.bench.flags import integer
from motorid.bench.timing import interleaved_times

__all__ = ["bench_selection", "FIT_GOAL", "FILE_GOAL"]

#: Largest time of the default fit on 10 000 samples, in single ``oe`` fits at a fixed delay.
FIT_GOAL = 10.0
#: Largest time of ``identify FILE`` on 10^6 rows, in ``pandas.read_csv`` of the same file.
FILE_GOAL = 4.0


def _recording(samples: int, friction: float = 0.0, seed: int = 0):
    import numpy as np

    from motorsim import Encoder, Experiment, Motor, Multisine, SimRig, Sine
    excitation = Sine(10.0, 200) if friction else Multisine((5.0, 17.0, 41.0, 90.0), (60, 60, 50, 40), (0, 1, 2, 3))
    rig = SimRig(Motor(25.0, 3.0, friction=friction), Encoder(angle_noise=1e-4), rng=np.random.default_rng(seed))
    return rig.run(Experiment(excitation, 0.005, samples * 0.005))


def bench_selection(argv: Sequence[str]) -> int:
    """The default's fit time against one ``oe`` fit, and ``identify FILE`` against ``pandas.read_csv``."""
    from identify import fit
    p = argparse.ArgumentParser(prog="motorid bench selection", description=__doc__.splitlines()[0])
    p.add_argument("--samples", type=integer(), default=10_000, help="samples of the fit comparison (default 10000)")
    p.add_argument("--rows", type=integer(0), default=10**6,
                   help="rows of the file comparison (default 1000000; 0 skips)")
    p.add_argument("--repeats", type=integer(), default=5, help="timings to take the median of (default 5)")
    args = p.parse_args(list(argv))
    missed = []
    for label, friction in (("linear multisine", 0.0), ("Coulomb friction 20 %", 120.0)):
        rec = _recording(args.samples, friction)
        default = fit(rec)
        chosen = default.selection["chosen"] if default.selection else {}

        def chosen_fit(r=rec):
            return fit(r)

        def oe_fit(r=rec):
            return fit(r, "oe", input_delay=0)

        def own_fit(r=rec, method=default.method, delay=default.input_delay):
            return fit(r, method, input_delay=delay)
        t_default, t_oe, t_own = interleaved_times([chosen_fit, oe_fit, own_fit], args.repeats)
        ratio = t_default / t_oe
        goal = "" if friction else f"   goal <= {FIT_GOAL:g} x: {'met' if ratio <= FIT_GOAL else 'MISSED'}"
        if not friction and ratio > FIT_GOAL:
            missed.append("fit")
        own = "" if default.method == "oe" else f"; {t_default / t_own:4.1f} x one {default.method} fit"
        print(f"{label:24s} {args.samples} samples: default {1e3 * t_default:7.1f} ms "
              f"({chosen.get('structure')}, delay {chosen.get('input_delay')}), one oe fit {1e3 * t_oe:6.2f} ms, "
              f"ratio {ratio:5.1f} x{own}{goal}")
    if args.rows:
        try:
            import pandas
        except ImportError:
            print("the file comparison needs pandas (pip install 'motorid[bench]')", file=sys.stderr)
            return 2
        from motorid.screening import read_and_fit
        from motorsim.writing import write_recording
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "long.csv"
            write_recording(_recording(args.rows), path)
            t_identify, t_pandas = interleaved_times([lambda: read_and_fit([str(path)], "auto", {}),
                                                      lambda: pandas.read_csv(path, comment="#")], args.repeats)
        ratio = t_identify / t_pandas
        if ratio > FILE_GOAL:
            missed.append("file")
        print(f"identify FILE, {args.rows} rows: {t_identify:6.2f} s (read, screen, default fit, outlier check); "
              f"pandas.read_csv {t_pandas:6.2f} s; ratio {ratio:4.1f} x   goal <= {FILE_GOAL:g} x: "
              f"{'met' if ratio <= FILE_GOAL else 'MISSED'}")
    return 1 if missed else 0

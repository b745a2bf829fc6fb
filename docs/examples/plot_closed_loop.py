"""
A controller designed from each model, run on the bench
=======================================================

A one-step MPC tracking ``10 sin(30 t)`` rad/s, designed from the true motor and from the
``euler-ls`` and ``oe`` estimates of the article's first run. The top panel shows the speeds (they
overlap), the middle one each run's tracking error, where the designs part, the bottom the input.
"""
from identify import fit
from motorid import plots
from motorid.commands.control import compare_designs, format_closed_loop_table
from motorsim import Experiment, Motor, SimRig, Sine
from motorsim.control import parse_reference

truth = Motor(25.0, 3.0)
rig = SimRig(truth)
rec = rig.run(Experiment(Sine(10, 200), sample_period=0.005, duration=10.0))
designs = [("truth", truth), ("euler-ls", fit(rec, method="euler-ls")), ("oe", fit(rec, method="oe"))]
rows = compare_designs(rig, designs, "mpc", parse_reference("sine:30,10"), 2.0, 0.005, 16667,
                       duty_weight=1e-4)
print(format_closed_loop_table(rows))
fig = plots.plot_tracking(rows, title="one-step MPC from each model")

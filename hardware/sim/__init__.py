"""The bench firmware under simavr: the C harness (``motorid_avr_sim.c``), the ``avr-sim://`` launcher,
a frame-level device driver for tests and the firmware benchmarks."""

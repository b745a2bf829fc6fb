"""scenarios: the CLI, the article demo, sweeps, plots and benchmarks."""

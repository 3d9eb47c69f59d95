"""Entry points: the `kosmap` CLI, the log simulator, converters and benchmarks."""

"""The developers' benchmarks (outside the wheel): run them with `python -m benchmarks TARGET`."""

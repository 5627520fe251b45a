"""Benchmarks (bench/), hostile runs (hostile/), diagnostics (diag/) and their support: each run as a module from the checkout, `python -m benchmarks.bench.fixation`."""

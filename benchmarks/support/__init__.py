"""What the benchmarks share: a daemon in a child process."""

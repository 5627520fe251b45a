"""What the benchmarks share: a daemon in a child process, image errors split about the image
centre, YAML text a YAML library would refuse to write, saccade cases the simulated cameras
make."""

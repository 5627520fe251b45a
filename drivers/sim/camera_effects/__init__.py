"""What a real camera adds to the simulated eye's render: its lens's differences, its sensor
and auto exposure, its shutter, its frame timing (docs/sim-world.md)."""

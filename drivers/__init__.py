"""Hardware drivers: servo buses and cameras, real, emulated and simulated.

This package knows nothing above it (no `calib_free`, no `headctl`). Each device kind has
one abstract interface; each backend lives in its own module and is chosen by name
(see `drivers.backends`).
"""

"""Helpers the tests share that are not fixtures (those are in tests/conftest.py), and paths."""
from __future__ import annotations

import pathlib

ROOT = pathlib.Path(__file__).resolve().parents[2]  # the repository
CONFIGS = ROOT / "configs"  # the example configs (a link to the packaged headctl/configs)
TLS = ROOT / "tests" / "data" / "tls"  # test-only: a certificate naming head.example, and keys
# The kind simulated world (configs/sim.yaml is the realistic one): for tests of the method's
# logic whose figures are those of an exact head and identical, synchronised cameras.
SIM_IDEAL = CONFIGS / "sim-ideal.yaml"

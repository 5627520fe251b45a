"""Subcommands of `headctl` for the servos (filled in by the servos work)."""
from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    """Add this module's subcommands to `sub`."""

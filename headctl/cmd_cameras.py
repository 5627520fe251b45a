"""Subcommands of `headctl` for the cameras (filled in by the cameras work)."""
from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    """Add this module's subcommands to `sub`."""

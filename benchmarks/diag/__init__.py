"""Diagnostics of the online experiments and summaries of sweeps."""

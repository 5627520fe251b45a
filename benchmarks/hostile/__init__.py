"""Hostile runs: a service attacked through its API, its config, its faults and kills."""

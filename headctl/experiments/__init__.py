"""Experiments on the simulated head: the online experiments, pursuit, sweeps over seeds and settings, their summaries and plots."""

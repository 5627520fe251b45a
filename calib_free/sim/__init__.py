"""The geometric model of the stereo head and the paper's simulated experiments on it."""

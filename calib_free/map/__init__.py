"""The gaze map W(x, y, d): its fit, its compiled kernels, its file format and the adapter thread that teaches it."""

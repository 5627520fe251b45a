"""Image positions' errors split about the image centre into radial and tangential parts, for
the figures of a bias that grows with eccentricity (`benchmarks.bench.fixation --bias`,
`benchmarks.diag.online_samples`)."""
from __future__ import annotations

import numpy as np


def radial_tangential_error(measured_xy: np.ndarray, true_xy: np.ndarray,
                            centre: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Image positions' errors split about the image centre: (the truth's eccentricity, the
    error along the radius, positive outwards, and across it), each (n,) for (n, 2) inputs."""
    offset = np.atleast_2d(true_xy) - centre
    eccentricity = np.hypot(*offset.T)
    unit = offset / np.maximum(eccentricity, 1e-9)[:, None]
    error = np.atleast_2d(measured_xy) - np.atleast_2d(true_xy)
    radial = np.sum(error * unit, axis=1)
    tangential = error[:, 1] * unit[:, 0] - error[:, 0] * unit[:, 1]
    return eccentricity, radial, tangential

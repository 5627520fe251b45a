"""The paper's figures the experiments are compared with.

Fig. 5 is the geometric simulation after 2,000 fixations (`learn` and the other experiments on
(r, m) pairs); fig. 7 is the online system on the robot after 1,700 fixations, the reference of
the experiments on rendered images (`online*`). The retinal error is a fraction of the image
width.
"""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class PaperFigures:
    """One figure's final errors."""

    figure: str
    fixations: int
    pan_deg: float
    tilt_deg: float
    vergence_deg: float
    retinal_error: float

    @property
    def label(self) -> str:
        return f"paper, {self.figure} at {self.fixations:,}"

    def plot_values(self) -> dict[str, float]:
        """The figures as the learning-curve plots draw them (retinal error in %)."""
        return {"pan": self.pan_deg, "tilt": self.tilt_deg, "vergence": self.vergence_deg,
                "retinal": 100.0 * self.retinal_error}


GEOMETRIC = PaperFigures("fig. 5", 2000, 1.3, 1.07, 0.5, 0.0368)
ONLINE = PaperFigures("fig. 7", 1700, 1.7, 1.0, 0.34, 0.026)


def reference_for(online: bool) -> PaperFigures:
    """The figure an experiment is compared with: fig. 7 on rendered images, else fig. 5."""
    return ONLINE if online else GEOMETRIC


__all__ = ["GEOMETRIC", "ONLINE", "PaperFigures", "reference_for"]

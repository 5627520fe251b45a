"""What defines a gaze map (`GazeMapParams`): its image and disparity ranges, grid, learning
rule and profile, and the parameters' JSON (as a map file stores them). Table I's values
are the defaults; `PROFILES` names the two rules (`calib_free.map.gaze_map`'s doc).
"""
from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from typing import Any

PROFILES = ("default", "paper")


@dataclass(frozen=True)
class GazeMapParams:
    """Everything that defines a map. Table I's values are the defaults."""

    image_size: tuple[int, int] = (320, 240)  # (width, height) of the left image, pixels
    disparity_range: tuple[float, float] = (-60.0, 60.0)  # pixels; an application choice (II-A)
    grid_shape: tuple[int, int, int] = (100, 75, 21)  # Table I: input size s_in
    output_resolution: tuple[int, int, int] = (50, 50, 50)  # Table I: output size s_out
    # Relative command ranges (deg) the output resolution divides; also the random init range.
    command_range: tuple[tuple[float, float], ...] = ((-50.0, 50.0), (-35.0, 35.0), (-17.0, 17.0))
    adaptation_rate: float = 0.6  # Table I: alpha (eq. 10)
    sigma_max_fraction: float = 0.2  # Table I: sigma_max, fraction of each input dimension (eq. 9)
    adaptation_slope: float = 5.0  # Table I: s (eq. 9)
    adaptation_threshold: float = 0.2  # Table I: t (eq. 9)
    error_window: int = 10  # Table I: w (eq. 9, "averaged over the last ten errors")
    retinal_error_max_fraction: float = 0.5  # E_max = 50 % of each dimension (eq. 8)
    gaussian_cutoff: float = 1e-2  # G below this is negligible (< 0.6 % of a step): nodes there are not touched
    profile: str = "default"
    # Improvements of the default profile (all off in `paper`):
    interpolate: bool = True  # trilinear readout of W and sub-node inverse lookup
    global_degree: int = 3  # > 0: W = polynomial of this degree (RLS) + the grid as its residual
    global_memory: float = 400.0  # fixations the polynomial remembers while the head is unchanged
    global_memory_min: float = 30.0  # ... and right after it changed (the error jumped)
    surprise_threshold: float = 3.0  # median E of the window over its long-run level, lasting: the head changed
    robust_scale: float = 3.0  # > 0: samples this many median residuals off weigh half (Cauchy)
    # Pose inputs (beyond the paper; need global_degree > 0): P also fitted on (x, y, d, tilt,
    # vergence), used when a command or sample comes with the head's pose.
    pose_degree: int = 2  # > 0: terms in (tilt, vergence) up to this degree; 0: no pose inputs
    pose_position_degree: int = 5  # degree in (x, y, d) of the pose-aware P (at least global_degree)
    pose_cross_degree: int = 2  # degree in (x, y, d) of the terms that multiply tilt and vergence

    @classmethod
    def profile_values(cls, profile: str, **overrides: Any) -> "GazeMapParams":
        base: dict[str, Any]
        if profile == "paper":
            base = dict(profile="paper", interpolate=False, global_degree=0, robust_scale=0.0, pose_degree=0)
        elif profile == "default":
            base = dict(profile="default", interpolate=True, global_degree=3, pose_degree=2)
        else:
            raise ValueError(f"unknown gaze map profile {profile!r}: expected one of {', '.join(PROFILES)}")
        base.update(overrides)
        return cls(**base)

    def __post_init__(self) -> None:
        w, h = self.image_size
        if w < 2 or h < 2:
            raise ValueError(f"image_size must be at least (2, 2) pixels, got {self.image_size}")
        lo, hi = self.disparity_range
        if not hi > lo:
            raise ValueError(f"disparity_range must be (low, high) with low < high, got {self.disparity_range}")
        if len(self.grid_shape) != 3 or min(self.grid_shape) < 2:
            raise ValueError(f"grid_shape must be 3 sizes >= 2, got {self.grid_shape}")
        if len(self.command_range) != 3 or any(not b > a for a, b in self.command_range):
            raise ValueError(f"command_range must be 3 (low, high) pairs, got {self.command_range}")
        if not 0 < self.adaptation_rate <= 1:
            raise ValueError(f"adaptation_rate must be in (0, 1], got {self.adaptation_rate}")
        if self.error_window < 1:
            raise ValueError(f"error_window must be >= 1, got {self.error_window}")
        if self.profile not in PROFILES:
            raise ValueError(f"profile must be one of {', '.join(PROFILES)}, got {self.profile!r}")
        # What a map needs to be built and adapted; a saved map's file is refused on the same
        # grounds (calib_free.map.file), so a config can never make a map it cannot load again.
        if len(self.output_resolution) != 3 or min(self.output_resolution) < 1:
            raise ValueError(f"output_resolution must be 3 sizes >= 1, got {self.output_resolution}")
        if self.global_degree < 0:
            raise ValueError(f"global_degree must be >= 0, got {self.global_degree}")
        if not (self.global_memory >= 1 and self.global_memory_min >= 1):
            raise ValueError(f"global_memory must be >= 1 fixation (and global_memory_min too), got "
                             f"{self.global_memory}, {self.global_memory_min}")
        if not 0 < self.gaussian_cutoff < 1:
            raise ValueError(f"gaussian_cutoff must be in (0, 1), got {self.gaussian_cutoff}")
        for name in ("sigma_max_fraction", "retinal_error_max_fraction", "surprise_threshold"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be above 0, got {getattr(self, name)}")
        if self.robust_scale < 0:
            raise ValueError(f"robust_scale must be >= 0, got {self.robust_scale}")
        # Bounded so that the pose-aware fit stays small (at most 776 terms, a 4.8 MB covariance).
        for name, top in (("pose_degree", 4), ("pose_position_degree", 10), ("pose_cross_degree", 4)):
            value = getattr(self, name)
            if not 0 <= value <= top:
                raise ValueError(f"{name} must be an integer in [0, {top}], got {value!r}")

    def to_json(self) -> str:
        return json.dumps(dataclasses.asdict(self), sort_keys=True)

    @property
    def uses_pose(self) -> bool:
        """Whether the map fits P on the head's pose too (pose_degree and global_degree > 0)."""
        return self.pose_degree > 0 and self.global_degree > 0

    @classmethod
    def from_json(cls, text: str) -> "GazeMapParams":
        """Parameters saved by `to_json`; a field missing (saved before it existed) takes its
        profile's value."""
        data = json.loads(text)
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f"unknown gaze map parameters {unknown}")
        for key in ("image_size", "disparity_range", "grid_shape", "output_resolution"):
            data[key] = tuple(data[key])
        data["command_range"] = tuple(tuple(r) for r in data["command_range"])
        return cls.profile_values(data.pop("profile"), **data)

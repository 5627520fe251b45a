"""The config's `tracking:` section (smooth pursuit, `calib_free.gaze.pursuit.PursuitParams`) and the
bounds of its keys; the simulated room's moving objects (`sim_objects:`) are
`drivers.sim.motion.MovingObject`s, checked by their own declarations."""
from __future__ import annotations

from dataclasses import dataclass

from calib_free.gaze.pursuit import PursuitParams
from drivers.cameras.config import MAX_IMAGE_SIDE
from drivers.config.reader import check_settings, config_meta, declare_settings, setting

declare_settings(
    PursuitParams,
    patch_size_px=config_meta(lo=5, hi=MAX_IMAGE_SIDE, expected="a square patch side of at least 5 px"),
    search_radius_px=config_meta(lo=1, hi=MAX_IMAGE_SIDE),
    min_ncc=config_meta(lo=-1.0, hi=1.0),
    row_band_px=config_meta(lo=0, hi=MAX_IMAGE_SIDE),
    refresh_ncc=config_meta(lo=-1.0, hi=1.0),
    disparity_search_px=config_meta(above=0.0, hi=float(MAX_IMAGE_SIDE)),
    lost_after_frames=config_meta(lo=1, hi=10_000),
    alpha=config_meta(above=0.0, hi=1.0),
    beta=config_meta(lo=0.0, hi=2.0),
    lead_s=config_meta(lo=0.0, hi=1.0, expected="a time in [0, 1] s"),
    max_speed_deg_s=config_meta(above=0.0, hi=3600.0),
    jacobian_step_px=config_meta(above=0.0, hi=100.0),
    linear_radius_px=config_meta(lo=0.0, hi=float(MAX_IMAGE_SIDE)),
    frame_timeout_s=config_meta(above=0.0, hi=60.0, expected="a positive time, at most 60 s"),
)


@dataclass(frozen=True)
class TrackingConfig:
    """The `tracking:` section: `PursuitParams` (its fields are keys of the section itself)."""

    params: PursuitParams = setting(default_factory=PursuitParams, inline=PursuitParams)

    def __post_init__(self) -> None:
        check_settings(self)

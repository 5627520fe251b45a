"""Benchmark: correspondence on rendered saccades whose images the simulated cameras make, each
of a real webcam's effects alone and all together.

The saccades of `benchmarks.bench.photometric` (random, up to +-15 deg, in the photo room; the
same for a seed), their pre- and post-fixation images taken by two simulated cameras with
their own image pipeline (`benchmarks.support.camera_saccades`: `SimulatedCamera.render`
through the unit's lens, the room's light, the exposure, the sensor, MJPEG), at 320 x 240 by
default (configs/sim.yaml's cameras). Conditions:

- ideal: configs/sim-ideal.yaml's camera (`sensor: {model: ideal}`, `noise_std: 2`);
- each effect alone on it, with the `uvc_webcam` preset's values (docs/sim-world.md):
  vignetting; lens differences; auto exposure running between the two images (the view's
  brightness changes with the saccade and the exposure follows it); the same, locked from the
  frame before the pre image (`exposure_control: lock_per_fixation`); per-unit photometric
  differences (gain, offset, gamma of each eye); shot and read noise (instead of the 2 grey
  levels); MJPEG at quality 80; the room's mains flicker and its lamp switched between the two
  images (`home`'s depth and step, daylight steady), with a manual exposure of 5 ms at 6 dB
  (half a flicker period: the most flicker a frame shows; at the ideal camera's 10 ms, one whole
  period, it shows none);
- all together: the `uvc_webcam` preset in the `home` light, its lamp switched between the two
  images, the exposure locked (configs/sim.yaml) and running.

Per condition and variant (the default profile, the paper's eqs. 1-7, the default on plain
NCC): of the textured foveal patches, the share matched within 1 px; of the matches accepted
(per-eye confidence >= 0.3), the share wrong by more than 3 px; of the right ones, the share
accepted; median [IQR] over `--seeds` scene seeds. Also the foveal brightness change between
the two images the pipeline made (the post fovea's mean over the pre image's at the truth).

A second table (`--gains`): the ideal camera whose post image's exposure differs from the pre
image's by a factor drawn per image log-uniformly within +-5 %, +-10 %, +-20 %, and
1/1.4-1.4 with vignetting and MJPEG at quality 70; within 1 px and accepted (of the textured
patches) for the default profile and plain NCC.

    .venv/bin/python -m benchmarks.bench.realistic_saccades [--saccades 80] [--seeds 5] [--width 320]
        [--gains | --no-gains] [--only NAME]
"""
from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from benchmarks.bench.fixation import scored
from benchmarks.bench.photometric import TARGETS, quartiles
from benchmarks.support.camera_saccades import CameraSetup, Exposure, camera_cases
from calib_free.correspondence import search as correspondence
from calib_free.sim.head_model import HeadModel, JointLimits
from drivers.sim.room_light import LIGHT_PRESETS
from drivers.sim.camera_effects.sensor_config import SENSOR_PRESETS
from headctl.experiments.saccades import SaccadeCase, accuracy

WEBCAM = SENSOR_PRESETS["uvc_webcam"]
HOME = LIGHT_PRESETS["home"]
# Each effect's keys of the `uvc_webcam` preset.
EFFECT_KEYS: Mapping[str, tuple[str, ...]] = {
    "vignetting": ("vignetting",),
    "lens differences": ("focal_error", "centre_error_px", "roll_error_deg"),
    "auto exposure": ("auto_exposure", "ae_target", "ae_speed", "ae_max_step_ev", "min_exposure_us",
                      "max_exposure_us", "max_gain_db"),
    "unit photometry": ("gain_spread", "offset_spread", "gamma_spread"),
    "shot + read noise": ("full_well_e", "read_noise_e"),
    "MJPEG q80": ("jpeg_quality",),
}
FLICKER_EXPOSURE_US = 5000.0  # half a 100 Hz flicker period
FLICKER_GAIN_DB = 20.0 * np.log10(2.0)  # the light of the reference exposure (10 ms) at half the time


def webcam(effect: str, **more: Any) -> dict[str, Any]:
    """The ideal sensor with one effect of the `uvc_webcam` preset."""
    return {"model": "ideal", **{k: getattr(WEBCAM, k) for k in EFFECT_KEYS[effect]}, **more}


def conditions() -> dict[str, CameraSetup]:
    flicker = {"model": "constant", "flicker_depth": HOME.flicker_depth, "lamp_step": HOME.lamp_step}
    return {
        "ideal": CameraSetup(),
        "vignetting": CameraSetup(webcam("vignetting")),
        "lens differences": CameraSetup(webcam("lens differences")),
        "auto exposure, running": CameraSetup(webcam("auto exposure")),
        "auto exposure, locked": CameraSetup(webcam("auto exposure"), exposure=Exposure.LOCKED),
        "unit photometry": CameraSetup(webcam("unit photometry")),
        "shot + read noise": CameraSetup(webcam("shot + read noise"), noise_std=0.0),
        "MJPEG q80": CameraSetup(webcam("MJPEG q80")),
        "flicker + lamp step": CameraSetup(light=flicker, lamp_steps=True, exposure_us=FLICKER_EXPOSURE_US,
                                           gain_db=FLICKER_GAIN_DB),
        "all, locked": CameraSetup({"model": "uvc_webcam"}, noise_std=0.0, exposure=Exposure.LOCKED,
                                   light={"model": "home"}, lamp_steps=True),
        "all, running": CameraSetup({"model": "uvc_webcam"}, noise_std=0.0, light={"model": "home"},
                                    lamp_steps=True),
    }


def gain_rows() -> dict[str, CameraSetup]:
    """The ideal camera, its post image's exposure changed (the reference exposure, 10 ms, before)."""
    def changed(low: float, high: float, **sensor: Any) -> CameraSetup:
        return CameraSetup({"model": "ideal", **sensor}, exposure_us=WEBCAM.reference_exposure_us,
                           exposure_change=(low, high))
    return {
        "clean": CameraSetup(),
        "gain within +-5 %": changed(0.95, 1.05),
        "gain within +-10 %": changed(0.9, 1.1),
        "gain within +-20 %": changed(0.8, 1.2),
        "gain x1.4 to /1.4, vignetting, MJPEG q70": changed(1 / 1.4, 1.4, vignetting=WEBCAM.vignetting,
                                                            jpeg_quality=70),
    }


def variants() -> dict[str, tuple[Callable[..., Any], Any]]:
    params = correspondence.CorrespondenceParams
    return {"default": (correspondence.match_eye, params()),
            "paper": (correspondence.match_eye, params.profile_values("paper")),
            "plain NCC": (correspondence.match_eye, params(use_factors=False))}


@dataclass
class Figures:
    """One condition's figures, per variant a list over seeds."""

    within: dict[str, list[float]]
    wrong: dict[str, list[float]]
    right: dict[str, list[float]]
    accepted: dict[str, list[float]]
    change: list[float]  # the foveal brightness change of every textured case (post / pre)
    cases: list[int]  # textured cases per seed


def foveal_change(case: SaccadeCase, half: int = 10) -> float:
    """The post image's foveal mean over the pre image's at the truth (20 x 20 patches)."""
    h, w = case.post.shape
    post = case.post[h // 2 - half:h // 2 + half, w // 2 - half:w // 2 + half]
    x, y = int(round(case.truth[0])), int(round(case.truth[1]))
    pre = case.pre[max(0, y - half):y + half, max(0, x - half):x + half]
    return float(post.mean()) / max(float(pre.mean()), 1.0)


def measure(setups: Mapping[str, CameraSetup], timed: Mapping[str, tuple[Callable[..., Any], Any]],
            model: HeadModel, saccades: int, seeds: int) -> dict[str, Figures]:
    out: dict[str, Figures] = {}
    for name, setup in setups.items():
        figures = Figures({v: [] for v in timed}, {v: [] for v in timed}, {v: [] for v in timed},
                          {v: [] for v in timed}, [], [])
        for seed in range(seeds):
            cases = camera_cases(setup, model, seed, saccades)
            figures.cases.append(sum(c.textured for c in cases))
            figures.change += [foveal_change(c) for c in cases if c.textured]
            for variant, (match_eye, params) in timed.items():
                a = accuracy(list(scored(cases, match_eye, params)))
                figures.within[variant].append(a.within_1px)
                figures.wrong[variant].append(a.wrong_accepted)
                figures.right[variant].append(a.right_accepted)
                figures.accepted[variant].append(a.accepted)
        out[name] = figures
    return out


def print_conditions(figures: Mapping[str, Figures], timed: Mapping[str, Any]) -> None:
    name_width = max(len(n) for n in figures)
    variant_width = max(len(v) for v in timed)
    print(f"{'condition':<{name_width}}  {'variant':<{variant_width}}  {'within 1 px':>19}  "
          f"{'accepted, wrong > 3 px':>22}  {'right, accepted':>19}  foveal brightness post/pre p10/p50/p90")
    for name, f in figures.items():
        p10, p50, p90 = np.percentile(f.change, [10, 50, 90])
        for k, variant in enumerate(timed):
            change = f"{p10:.3f} / {p50:.3f} / {p90:.3f} ({min(f.cases)}-{max(f.cases)} a seed)" if k == 0 else ""
            print(f"{name:<{name_width}}  {variant:<{variant_width}}  {quartiles(f.within[variant]):>19}  "
                  f"{quartiles(f.wrong[variant]):>22}  {quartiles(f.right[variant]):>19}  {change}")


def print_gains(figures: Mapping[str, Figures], timed: Mapping[str, Any]) -> None:
    name_width = max(len(n) for n in figures)
    print(f"{'post image':<{name_width}}  " + "  ".join(f"{v + ': within 1 px / accepted':>42}" for v in timed))
    for name, f in figures.items():
        cells = [f"{quartiles(f.within[v])} / {quartiles(f.accepted[v])}" for v in timed]
        print(f"{name:<{name_width}}  " + "  ".join(f"{c:>42}" for c in cells))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--saccades", type=int, default=80, help="saccades per seed and condition (two eyes each)")
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--width", type=int, default=320, choices=(320, 640))
    parser.add_argument("--gains", action=argparse.BooleanOptionalAction, default=True,
                        help="also the table of exposure changes on the ideal camera")
    parser.add_argument("--only", metavar="NAME", action="append", default=None,
                        help="only this condition (repeatable)")
    args = parser.parse_args()
    model = HeadModel.default(args.width, args.width * 3 // 4, limits=JointLimits(vergence=(1.0, 20.0)))
    setups = {n: s for n, s in conditions().items() if args.only is None or n in args.only}
    started = time.perf_counter()
    print(f"load average at start: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    print(f"photo room, {model.width}x{model.height}, {args.saccades} saccades x {args.seeds} seeds a condition, "
          "images from the simulated cameras; median [IQR] over the seeds, %")
    timed = variants()
    figures = measure(setups, timed, model, args.saccades, args.seeds)
    print_conditions(figures, timed)
    print(TARGETS)
    if args.gains:
        pair = {v: timed[v] for v in ("default", "plain NCC")}
        rows = gain_rows()
        # the clean row is the ideal condition: the same cameras, the same cases
        gains = measure({n: s for n, s in rows.items() if not (n == "clean" and "ideal" in figures)},
                        pair, model, args.saccades, args.seeds)
        if "ideal" in figures:
            gains = {"clean": figures["ideal"], **gains}
        print("the ideal camera, the post image's exposure changed by a factor drawn log-uniformly per image:")
        print_gains(gains, pair)
    print(f"load average at end: {' '.join(f'{x:.2f}' for x in os.getloadavg())}; "
          f"{time.perf_counter() - started:.0f} s")


if __name__ == "__main__":
    main()

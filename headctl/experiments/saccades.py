"""Rendered pre/post-fixation images of random saccades, with the true answer of correspondence.

For each saccade (pan and tilt within +-`max_step_deg`, vergence kept) and each eye: the
pre- and post-fixation images of that eye with sensor noise, and where the world point on
that eye's post-fixation fovea (its optical axis' first surface) was in the pre-fixation
image. Saccades whose foveal point was out of view or hidden before are skipped: they have
no right answer. The correspondence tests and `benchmarks.bench.fixation` judge the
correspondence search on these cases.

By default the images are the renderer's, through the head model's lenses; a `SaccadeShots`
makes them otherwise (the simulated cameras' whole image pipeline,
`benchmarks.support.camera_saccades`), through its own lenses: the truth is then where the
point on the post-fixation image's centre, seen through that eye's lens, was in the
pre-fixation image. Which patches count as textured is read on the renderer's image in either
case, so that every source is judged on the same patches.
"""
from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from calib_free.correspondence.search import CorrespondenceParams, EyeMatch, foveal_patch, match_eye
from headctl.service.head import joints_of
from calib_free.sim.head_model import HeadModel
from drivers.sim.scene import Lens, Scene, StereoRenderer
from drivers.sim.truth import axis_point, centre_point, hidden_from, texture_at

Images = tuple[np.ndarray, np.ndarray]  # (left, right)


@dataclass(frozen=True)
class SaccadeCase:
    pre: np.ndarray  # one eye's pre-fixation image, grey uint8 with noise
    post: np.ndarray  # its post-fixation image
    truth: np.ndarray  # (x, y): where the post-fixation fovea's point was in `pre`
    eye: int  # 0 left, 1 right
    texture: str  # the texture kind of the surface on the fovea
    patch_std: float  # grey-level spread of the noise-free foveal patch (20 x 20)

    @property
    def textured(self) -> bool:
        """A foveal patch with structure to match (not a nearly uniform surface)."""
        return self.texture != "uniform" and self.patch_std >= 8.0


class SaccadeShots(Protocol):
    """Where a saccade's images come from: both eyes' pre- and post-fixation images."""

    @property
    def lenses(self) -> tuple[Lens, Lens]:
        """The lenses the left and right images are seen through."""

    def shoot(self, index: int, pre: Mapping[str, float], post: Mapping[str, float]) -> tuple[Images, Images]:
        """Saccade `index`'s (pre, post) images at these joint angles (degrees)."""


def saccade_cases(scene: Scene, model: HeadModel, count: int, seed: int = 11, noise_std: float = 2.0,
                  max_step_deg: float = 15.0, shots: SaccadeShots | None = None) -> list[SaccadeCase]:
    """`count` saccades' cases (up to two per saccade: one per eye whose answer exists).

    `noise_std` grey levels of noise are added to every image (`shots`' too); the saccades and
    the noise drawn are the same whatever `noise_std` and `shots` are."""
    rng = np.random.default_rng(seed)
    cases: list[SaccadeCase] = []
    lenses = shots.lenses if shots is not None else (model.lens_left, model.lens_right)
    with StereoRenderer(model, scene, parallel=False) as renderer:
        for n in range(count):
            pre = rng.uniform(model.limits.low, model.limits.high)
            post = model.limits.clamp(pre + np.r_[rng.uniform(-max_step_deg, max_step_deg, 2), 0.0])
            rendered = [renderer.render(joints_of(p)) for p in (pre, post)]
            images = rendered if shots is None else list(shots.shoot(n, joints_of(pre), joints_of(post)))
            noise = [noise_std * rng.standard_normal(images[0][0].shape, dtype=np.float32) for _ in range(4)]
            for eye in (0, 1):
                foveal = axis_point(scene, *model.eye_frames(post)[eye])
                target = foveal if shots is None else centre_point(scene, lenses[eye], *model.eye_frames(post)[eye])
                r_pre, c_pre = model.eye_frames(pre)[eye]
                uv, seen = lenses[eye].project((target[None, :] - c_pre) @ r_pre.T)
                if not seen[0] or hidden_from(scene, c_pre, target, 0.01):
                    continue  # out of view or occluded before the saccade: no right answer
                noisy = [np.clip(images[k][eye] + noise[2 * k + eye], 0, 255).astype(np.uint8) for k in (0, 1)]
                std = float(foveal_patch(rendered[1][eye].astype(np.float32), (20, 20)).std())
                cases.append(SaccadeCase(noisy[0], noisy[1], uv[0], eye, texture_at(scene, foveal), std))
    return cases


@dataclass(frozen=True)
class Scored:
    case: SaccadeCase
    match: EyeMatch
    error_px: float


def scored(cases: list[SaccadeCase], params: CorrespondenceParams) -> Iterator[Scored]:
    for case in cases:
        m = match_eye(case.pre, case.post, params)
        yield Scored(case, m, float(np.hypot(m.x - case.truth[0], m.y - case.truth[1])))


@dataclass(frozen=True)
class Accuracy:
    """The figures of issue 14 over textured foveal patches: within 1 px; of the accepted, wrong
    by more than 3 px; of the right (within 1 px), accepted."""

    cases: int
    within_1px: float
    accepted: float
    wrong_accepted: float  # of the accepted, the fraction wrong by > 3 px
    right_accepted: float  # of those within 1 px, the fraction accepted
    median_confidence_wrong: float  # of the accepted wrong ones

    def line(self) -> str:
        return (f"{self.cases} textured cases: {self.within_1px:.1%} within 1 px; accepted {self.accepted:.1%}; "
                f"of the accepted, {self.wrong_accepted:.2%} wrong by > 3 px (median confidence "
                f"{self.median_confidence_wrong:.2f}); of the right, {self.right_accepted:.1%} accepted")


def accuracy(results: list[Scored], floor: float = 0.3) -> Accuracy:
    textured = [r for r in results if r.case.textured]
    errors = np.array([r.error_px for r in textured])
    confidence = np.array([r.match.confidence for r in textured])
    accepted = confidence >= floor
    right, wrong = errors <= 1.0, errors > 3.0
    return Accuracy(
        cases=len(textured),
        within_1px=float(right.mean()),
        accepted=float(accepted.mean()),
        wrong_accepted=float((wrong & accepted).sum() / max(1, accepted.sum())),
        right_accepted=float((right & accepted).sum() / max(1, right.sum())),
        median_confidence_wrong=float(np.median(confidence[wrong & accepted])) if (wrong & accepted).any()
        else float("nan"),
    )

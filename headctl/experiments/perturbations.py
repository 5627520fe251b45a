"""The re-adaptation experiments' perturbations, as wrappers of the head's parts.

The production `Head` knows nothing of them: an experiment wraps the head's servo bus
(`JointBus`) or its pair source (`PairSource`) at the fixation its change happens
(`perturb`), and the head goes on with the same interfaces.

- `PanReadingOffset`: the paper's fig. 9 defect, a constant added to the pan angle read from
  the encoder and not to the goals written, so every pan goal computed from a reading lands
  that much further;
- `TransformedPairs`: both images of every pair transformed, e.g. the vertical prism of
  fig. 8 (`np.flipud`: the images upside down).
"""
from __future__ import annotations

import dataclasses
import logging
from typing import Callable, Mapping

import numpy as np

from calib_free.sim.experiments import Change
from drivers.servo.bus import BusState
from headctl.service.head import Head, JointBus, PairSource

log = logging.getLogger(__name__)

ImageTransform = Callable[[np.ndarray], np.ndarray]


class PanReadingOffset:
    """A `JointBus` whose pan reading is `offset_deg` more than the servo's.

    Goals are written as given; the goals returned are the positions this bus reads once the
    servos reach them (pan plus the offset), so that "at goal" compares like with like."""

    def __init__(self, bus: JointBus, offset_deg: float) -> None:
        self.bus = bus
        self.offset_deg = offset_deg

    def read_state(self) -> BusState:
        state = self.bus.read_state()
        pan = state.joints["pan"]
        joints = {**state.joints, "pan": dataclasses.replace(pan, position=pan.position + self.offset_deg)}
        return dataclasses.replace(state, joints=joints)

    def write_goals(self, goals: Mapping[str, float]) -> dict[str, float]:
        sent = self.bus.write_goals(goals)
        if "pan" in sent:
            sent = {**sent, "pan": sent["pan"] + self.offset_deg}
        return sent


class TransformedPairs:
    """A `PairSource` whose pairs have both images passed through `transform`."""

    def __init__(self, pairs: PairSource, transform: ImageTransform) -> None:
        self.pairs = pairs
        self.transform = transform

    @property
    def last_exposure_s(self) -> float | None:
        return self.pairs.last_exposure_s

    def wait_pair(self, after_s: float, timeout_s: float) -> tuple[np.ndarray, np.ndarray]:
        left, right = self.pairs.wait_pair(after_s, timeout_s)
        return self.transform(left), self.transform(right)


def perturb(head: Head, change: Change) -> None:
    """Switch the perturbations of `change` on in `head` by wrapping its bus or its pairs.

    Only the prism and the pan part of a motor offset are modelled on a head; ValueError for
    the rest."""
    if change.swap_eyes or change.baseline_delta_m or change.motor_gain:
        raise ValueError(f"the online experiments do not model {change}")
    if change.vertical_prism:
        head.pairs = TransformedPairs(head.pairs, np.flipud)
    if change.motor_offset_deg is not None:
        head.bus = PanReadingOffset(head.bus, change.motor_offset_deg[0])


__all__ = ["ImageTransform", "PanReadingOffset", "TransformedPairs", "perturb"]

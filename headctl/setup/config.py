"""From identified servos to a head's `servo_bus.joints`: zeros, limits, jogs, and the YAML.

* Zero of the neck (pan, tilt): where it is when the assistant starts; the person points
  the head straight first (and can jog it).
* Zero of the eyes: parallel, from the images: both eyes turned symmetrically until the
  structure in view (far structure dominates the central part of a room) has zero
  horizontal disparity; nearer structure biases it by baseline / distance (1.1 deg of
  vergence for a wall 3 m away with a 60 mm baseline).
* Limits: conservative spans around the zero (`DEFAULT_SPAN_DEG`), always containing where
  the joint is, never beyond the servo's own position limits; `--jog JOINT DEG` moves the
  joint there (safely, and back) and widens its limit to where it got.

`joints_yaml` writes the section with a comment per value saying how it was found;
`write_config` puts it into the partial config's document.
"""
from __future__ import annotations

import datetime
import logging
import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path

import yaml

from drivers.dynamixel.tables.x_series import X_MODELS
from drivers.servo.joints import JOINTS
from headctl.json_types import JSONObject
from headctl.setup.identify import PairSource, SafeProbing, ServoFinding, image_shift, pair_after

log = logging.getLogger(__name__)

DEFAULT_SPAN_DEG: Mapping[str, float] = {"pan": 30.0, "tilt": 20.0, "left_eye": 15.0, "right_eye": 15.0}
PRESENT_MARGIN_DEG = 2.0
MAX_EYE_CORRECTION_DEG = 15.0  # the furthest either eye is turned while nulling disparity
DISPARITY_TOLERANCE_PX = 0.5


@dataclass
class JointProposal:
    """One joint as it will be written, servo frame for the zero, joint frame for limits."""

    finding: ServoFinding
    zero_offset: float
    min_angle: float
    max_angle: float
    zero_how: str
    limits_how: str

    @property
    def servo_id(self) -> int:
        return self.finding.servo.servo_id

    @property
    def direction(self) -> int:
        assert self.finding.direction is not None
        return self.finding.direction

    def joint_angle(self, servo_deg: float) -> float:
        return self.direction * (servo_deg - self.zero_offset)

    def servo_angle(self, joint_deg: float) -> float:
        return self.zero_offset + self.direction * joint_deg

    def own_limits(self) -> tuple[float, float]:
        """The servo's own position limits in the joint frame."""
        a, b = (self.joint_angle(x) for x in (self.finding.start.min_deg, self.finding.start.max_deg))
        return min(a, b), max(a, b)


def eye_zeros(probing: SafeProbing, pairs: PairSource, left: ServoFinding, right: ServoFinding, *,
              frame_timeout_s: float = 2.0, say: Callable[[str], None] = lambda text: None) -> tuple[float, float, str]:
    """The eyes' servo angles at which they are parallel (see the module docstring), found by
    turning them symmetrically and measuring the disparity again; they go back after."""
    # Disparity px per vergence degree: each eye turns half of it, its image shifting px_per_deg a degree.
    gain = ((left.px_per_deg or 0.0) + (right.px_per_deg or 0.0)) / 2
    l0, r0 = left.start.position_deg, right.start.position_deg
    assert left.direction is not None and right.direction is not None
    if gain <= 0:
        return l0, r0, "where the eye was (its image motion gave no gain)"
    vergence_change = 0.0
    disparity = 0.0
    probing.take(left.servo.servo_id)
    probing.take(right.servo.servo_id)
    try:
        for _ in range(3):
            image_l, image_r = pair_after(pairs, probing.clock, frame_timeout_s)
            disparity = image_shift(image_l, image_r).dx  # x_right - x_left of the dominant structure
            if abs(disparity) <= DISPARITY_TOLERANCE_PX:
                break
            # + vergence turns the left image's scene left and the right's right: disparity grows by gain.
            vergence_change -= disparity / gain
            half = max(-MAX_EYE_CORRECTION_DEG, min(MAX_EYE_CORRECTION_DEG, vergence_change / 2))
            vergence_change = 2 * half
            say(f"  eyes: disparity {disparity:+.1f} px; turning them {vergence_change:+.2f} deg of vergence")
            probing.move(left.servo.servo_id, l0 + left.direction * half)
            probing.move(right.servo.servo_id, r0 - right.direction * half)
        probing.move(left.servo.servo_id, l0)
        probing.move(right.servo.servo_id, r0)
    finally:
        probing.release(left.servo.servo_id)
        probing.release(right.servo.servo_id)
    half = vergence_change / 2
    how = (f"eyes parallel: far structure at zero disparity ({disparity:+.1f} px left) "
           f"{vergence_change:+.2f} deg of vergence from where they were")
    return l0 + left.direction * half, r0 - right.direction * half, how


def propose(joints: Mapping[str, ServoFinding], eye_zero: tuple[float, float, str] | None) -> dict[str, JointProposal]:
    """Zeros and conservative limits for the four identified joints."""
    proposals: dict[str, JointProposal] = {}
    for joint in JOINTS:
        finding = joints[joint]
        zero, how = finding.start.position_deg, "where it was when setup started (the head pointed straight)"
        if eye_zero is not None and joint in ("left_eye", "right_eye"):
            zero = eye_zero[0] if joint == "left_eye" else eye_zero[1]
            how = eye_zero[2]
        p = JointProposal(finding, round(zero, 2), 0.0, 0.0, how, "")
        span = DEFAULT_SPAN_DEG[joint]
        present = p.joint_angle(finding.start.position_deg)
        own_lo, own_hi = p.own_limits()
        p.min_angle = round(max(own_lo, min(-span, present - PRESENT_MARGIN_DEG)), 2)
        p.max_angle = round(min(own_hi, max(span, present + PRESENT_MARGIN_DEG)), 2)
        clipped = " (clipped to the servo's own limits)" if (p.min_angle, p.max_angle) != (
            min(-span, present - PRESENT_MARGIN_DEG), max(span, present + PRESENT_MARGIN_DEG)) else ""
        p.limits_how = f"conservative: +-{span:g} deg around the zero, with where it is{clipped}"
        proposals[joint] = p
    return proposals


def jog(probing: SafeProbing, proposal: JointProposal, joint_deg: float,
        say: Callable[[str], None] = lambda text: None) -> float:
    """Move the joint to `joint_deg` (never past the servo's own limits), widen its limit to
    where it got, and bring it back; returns where it got (joint frame)."""
    own_lo, own_hi = proposal.own_limits()
    target = min(max(joint_deg, own_lo), own_hi)
    if target != joint_deg:
        say(f"  jog {proposal.finding.joint} {joint_deg:+g}: beyond the servo's own limits; going to {target:+.1f}")
    servo_id = proposal.servo_id
    start = probing.take(servo_id)
    reached = target
    try:
        try:
            status = probing.move(servo_id, proposal.servo_angle(target))
            reached = proposal.joint_angle(status.position_deg)
        except Exception as err:  # held where it stopped: the limit is where it got
            if probing.interrupt.is_set():
                raise
            reached = proposal.joint_angle(probing.probe.status(servo_id).position_deg)
            say(f"  jog {proposal.finding.joint}: stopped at {reached:+.1f} deg ({err})")
        probing.move(servo_id, start.position_deg)
    finally:
        probing.release(servo_id)
    if reached < proposal.min_angle:
        proposal.min_angle = round(reached, 2)
        proposal.limits_how += f"; min widened by jogging to {reached:+.1f}"
    elif reached > proposal.max_angle:
        proposal.max_angle = round(reached, 2)
        proposal.limits_how += f"; max widened by jogging to {reached:+.1f}"
    return reached


def _finding_note(p: JointProposal) -> str:
    f = p.finding
    assert f.left is not None and f.right is not None
    return (f"{f.step_deg:+.1f} deg moved the left image ({f.left.dx * f.step_deg:+.1f}, {f.left.dy * f.step_deg:+.1f}) "
            f"px and the right ({f.right.dx * f.step_deg:+.1f}, {f.right.dy * f.step_deg:+.1f}) px")


# What a + servo step did, by joint and the direction found: the scene's motion in the images,
# and the joint's turn it means (the head's conventions: docs/architecture.md).
_SEEN = {("pan", 1): "the scene moved right in both images: the head turned left (+ pan)",
         ("pan", -1): "the scene moved left in both images: the head turned right (- pan)",
         ("tilt", 1): "the scene moved down in both images: the head turned up (+ tilt)",
         ("tilt", -1): "the scene moved up in both images: the head turned down (- tilt)",
         ("left_eye", 1): "the scene moved left in the left image: the eye turned right (+, inward)",
         ("left_eye", -1): "the scene moved right in the left image: the eye turned left (-, outward)",
         ("right_eye", 1): "the scene moved left in the right image: the eye turned right (+, outward)",
         ("right_eye", -1): "the scene moved right in the right image: the eye turned left (-, inward)"}


def joints_yaml(proposals: Mapping[str, JointProposal], indent: str = "  ", models: bool = True) -> str:
    """The `joints:` block (under `servo_bus:`), a comment per value; `models`: with each
    servo's model (not for the simulated bus, which has none)."""
    lines = [f"{indent}joints:"]
    for joint in JOINTS:
        p = proposals[joint]
        f = p.finding
        model = f.servo.model_name
        lines.append(f"{indent * 2}{joint}:")
        lines.append(f"{indent * 3}id: {p.servo_id}  # {_finding_note(p)}")
        if models and model in X_MODELS:
            lines.append(f"{indent * 3}model: {model}  # its answer to a ping (firmware {f.servo.firmware})")
        lines.append(f"{indent * 3}direction: {p.direction}  # a + servo step: {_SEEN[(joint, p.direction)]}")
        lines.append(f"{indent * 3}zero_offset: {p.zero_offset:g}  # {p.zero_how}")
        lines.append(f"{indent * 3}min_angle: {p.min_angle:g}  # {p.limits_how}")
        lines.append(f"{indent * 3}max_angle: {p.max_angle:g}")
    return "\n".join(lines) + "\n"


def write_config(source: JSONObject | None, source_path: Path | None, bus_settings: Mapping[str, str | int | float],
                 proposals: Mapping[str, JointProposal], out: Path) -> None:
    """Write the head's config to `out` (atomically): the partial config's document with
    `servo_bus` set from `bus_settings` (port, baud, ...) and the joints filled in."""
    document = dict(source or {})
    bus = {k: v for k, v in dict(document.get("servo_bus") or {}).items() if k != "joints"}
    bus.update(bus_settings)
    stamp = datetime.date.today().isoformat()
    parts = [f"# Written by `headctl setup` on {stamp}"
             + (f" from {source_path}" if source_path else "") + ". Every key: docs/config.md.\n"]
    bus_text = yaml.safe_dump({"servo_bus": bus}, sort_keys=False, default_flow_style=None)
    parts.append(bus_text + joints_yaml(proposals, models=bus.get("backend") != "sim"))
    rest = {k: v for k, v in document.items() if k != "servo_bus"}
    if rest:
        parts.append(yaml.safe_dump(rest, sort_keys=False, default_flow_style=None))
    text = "".join(parts)
    tmp = out.with_name(f".{out.name}.tmp")
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, out)

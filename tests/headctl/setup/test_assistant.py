"""`headctl.setup.assistant`: the assistant as a function, told and asked through a `Person`."""
from __future__ import annotations

import contextlib
import threading
from collections.abc import Iterator
from pathlib import Path

import yaml

from headctl.setup.assistant import SetupOutcome, SetupRequest, assist, read_partial
from tests.headctl.setup.test_setup import camera_section

WIRING = {9: {"joint": "right_eye", "direction": -1, "zero_offset": 14.0},
          4: {"joint": "pan", "direction": 1, "zero_offset": -11.0},
          21: {"joint": "left_eye", "direction": -1, "zero_offset": -6.5},
          2: {"joint": "tilt", "direction": -1, "zero_offset": 19.0}}


class Answering:
    """A person who answers every question alike and records what was said."""

    def __init__(self, answer: bool) -> None:
        self.answer = answer
        self.said: list[str] = []
        self.asked: list[str] = []
        self.stopped_by: list[threading.Event] = []

    def say(self, text: str) -> None:
        self.said.append(text)

    def confirm(self, question: str) -> bool:
        self.asked.append(question)
        return self.answer

    @contextlib.contextmanager
    def stopping(self, stop: threading.Event) -> Iterator[None]:
        self.stopped_by.append(stop)
        yield


def partial_config(tmp_path: Path) -> Path:
    path = tmp_path / "partial.yaml"
    path.write_text(yaml.safe_dump({"servo_bus": {"backend": "sim", "port": "sim:assistant", "wiring": WIRING},
                                    "cameras": camera_section()}))
    return path


def test_nothing_moves_when_the_person_declines(tmp_path):
    request = SetupRequest(partial_config(tmp_path), write=tmp_path / "head.yaml")
    person = Answering(False)
    result = assist(request, read_partial(request.config), person)
    assert result.outcome is SetupOutcome.DECLINED and len(result.found) == 4
    assert person.asked and person.said[-1] == "nothing moved" and not person.stopped_by
    assert not (tmp_path / "head.yaml").exists()


def test_the_joints_are_proposed_and_a_jog_of_no_joint_is_refused_before_anything_is_written(tmp_path):
    request = SetupRequest(partial_config(tmp_path), write=tmp_path / "head.yaml", yes=True, jogs=(("nose", 3.0),))
    person = Answering(False)
    result = assist(request, read_partial(request.config), person)
    assert result.outcome is SetupOutcome.UNKNOWN_JOG and "--jog nose" in result.detail
    assert not person.asked and len(person.stopped_by) == 1  # --yes: nothing asked; the probing was stoppable
    assert {joint: p.servo_id for joint, p in result.proposals.items()} == {
        w["joint"]: i for i, w in WIRING.items()}
    assert result.written is None and not (tmp_path / "head.yaml").exists()

"""What the look benchmarks count of the looks' steps and attempts."""
from __future__ import annotations

from benchmarks.bench.looks import finishing_steps, second_attempts


def rows(*looks: tuple[int, int, bool]) -> list[dict]:
    return [{"corrective_steps": steps, "attempts": attempts, "on_target": on} for steps, attempts, on in looks]


def test_finishing_steps_counts_the_looks_past_the_corrective_steps_and_those_on_target():
    looks = rows((0, 1, True), (3, 1, False), (4, 1, True), (5, 1, False), (5, 2, True))
    assert finishing_steps(looks, max_corrective_steps=3) == {"looks": 3, "on_target": 2}
    assert finishing_steps(looks, max_corrective_steps=4) == {"looks": 2, "on_target": 1}


def test_second_attempts_counts_the_looks_that_tried_again():
    looks = rows((0, 1, True), (3, 2, False), (1, 2, True), (2, None, True))
    assert second_attempts(looks) == {"looks": 2, "on_target": 1}

"""The look-time diagnostic: its timer counts the fixation thread alone, and its summary."""
from __future__ import annotations

import logging
import threading

from benchmarks.diag import look_time
from benchmarks.diag.look_time import REST, PartTimer, summary
from headctl.service.head import Head


def test_the_timer_wraps_the_parts_for_its_block_and_counts_the_fixation_thread_only():
    original = Head.wait_settled
    timer = PartTimer()
    with timer.installed():
        assert Head.wait_settled is not original
        timed = timer._timed(lambda: "done", "coming to rest")
        assert timed() == "done"  # called here, on the main thread: not counted
        assert timer.take() == {}
        results: list[str] = []
        worker = threading.Thread(target=lambda: results.append(timed()), name=look_time.FIXATION_THREAD)
        worker.start()
        worker.join()
        spent = timer.take()
        assert results == ["done"] and set(spent) == {"coming to rest"} and spent["coming to rest"] >= 0.0
        assert timer.take() == {}  # taken: counting starts again
    assert Head.wait_settled is original


def test_the_summary_groups_the_looks_on_target_by_corrective_steps():
    def row(steps, duration_s, rest_s, searches_s, on_target=True):
        return {"on_target": on_target, "corrective_steps": steps, "duration_s": duration_s,
                "parts_s": {"coming to rest": rest_s, "target searches": searches_s}}

    looks = [row(0, 0.30, 0.24, 0.01), row(0, 0.40, 0.30, 0.03), row(0, 0.35, 0.26, 0.02),
             row(1, 0.50, 0.40, 0.02), row(3, 0.90, 0.70, 0.05), row(2, 0.80, 0.60, 0.04),
             row(0, 2.0, 1.5, 0.1, on_target=False)]  # failed: not counted
    out = summary(looks)
    assert set(out) == {"corrective steps 0", "corrective steps 1", "corrective steps 2+"}
    none = out["corrective steps 0"]
    assert none["looks"] == 3 and none["duration_s"] == 0.35
    assert none["coming to rest"] == 0.26 and none["target searches"] == 0.02
    assert none["correspondence"] == 0.0  # a part none of them spent time in
    assert none[REST] == 0.07  # the looks' own time outside every part: 0.05, 0.07, 0.07
    assert out["corrective steps 2+"]["looks"] == 2 and out["corrective steps 2+"]["duration_s"] == 0.85


def test_the_rest_log_splits_each_rest_the_head_logs_on_the_fixation_thread():
    from benchmarks.diag.look_time import RestLog

    log = logging.getLogger(look_time.HEAD_LOGGER)
    with RestLog().installed() as rests:
        def rest(waited, still, kind):  # as `Head.wait_settled` logs one
            log.debug("at rest after %.3f s (still from %.3f s), %s (off %s deg)", waited, still, kind, [0.0, 0.1, 0.0])
        rest(0.2, 0.15, "at goal")  # the main thread's: not counted
        worker = threading.Thread(target=lambda: (rest(0.2, 0.15, "at goal"), rest(0.3, 0.1, "short of goal")),
                                  name=look_time.FIXATION_THREAD)
        worker.start()
        worker.join()
        taken = rests.take()
    assert taken == {"rests": 2, "short of goal": 1, "motion_s": 0.25, "hold_s": 0.25}
    assert logging.getLogger(look_time.HEAD_LOGGER).propagate  # as it was

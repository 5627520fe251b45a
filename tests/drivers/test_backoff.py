"""The bounded exponential back-off that loops waiting on a failed part share."""
from __future__ import annotations

import pytest

from drivers.clock import Backoff


def test_waits_double_up_to_the_bound_and_reset_after_a_success():
    backoff = Backoff(0.05, 1.0)
    assert [backoff.failed() for _ in range(8)] == [0.05, 0.1, 0.2, 0.4, 0.8, 1.0, 1.0, 1.0]
    assert backoff.failures == 8 and backoff.delay_s == 1.0
    backoff.reset()
    assert backoff.failures == 0 and backoff.failed() == 0.05


@pytest.mark.parametrize("first_s, max_s, factor", [(0.0, 1.0, 2.0), (2.0, 1.0, 2.0), (0.1, 1.0, 0.5)])
def test_bounds_that_make_no_back_off_are_refused(first_s, max_s, factor):
    with pytest.raises(ValueError, match="back-off"):
        Backoff(first_s, max_s, factor)

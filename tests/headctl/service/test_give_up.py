"""Giving up: a real `headctl run` on the simulated head whose servo process is killed more
often than `service.restart_limit` allows within `service.restart_window_s` stops petting the
watchdog, stops and exits `EXIT_GAVE_UP` (3), for systemd to restart the unit."""
from __future__ import annotations

import os
import signal

import pytest
import yaml

from headctl.service.supervision.restarts import EXIT_GAVE_UP
from tests.support.daemon_proc import SIM

pytestmark = [pytest.mark.timeout(180), pytest.mark.slow]


def test_more_servo_process_deaths_than_the_limit_make_headctl_run_exit_non_zero(tmp_path, service_process):
    config = yaml.safe_load(SIM.read_text())
    config["service"].update(restart_limit=1, restart_window_s=300)
    path = tmp_path / "head.yaml"
    path.write_text(yaml.safe_dump(config))
    d = service_process(tmp_path / "state", path)
    first = d.wait(lambda s: s["state"] == "running" and s["servo_loop"]["pid"], 60, "running")["servo_loop"]["pid"]
    os.kill(first, signal.SIGKILL)  # failure 1 of 1: restarted
    # The new child's pid shows as soon as it is spawned; the restart is counted once it is ready.
    s = d.wait(lambda s: s["state"] == "running" and s["servo_loop"]["pid"] not in (first, None)
               and s["restarts"], 30, "running again with a new servo process, the restart counted")
    assert s["servo_loop"]["restarts"] == 1 and s["restarts"] == {"servo-io": 1}
    os.kill(s["servo_loop"]["pid"], signal.SIGKILL)  # failure 2: more than the limit
    code = d.proc.wait(30)
    assert code == EXIT_GAVE_UP != 0
    log = d.tail(60)
    assert "giving up: 2 failures within 300 s (service.restart_limit: 1; servo-io)" in log
    assert f"exit code {EXIT_GAVE_UP}" in log

"""A USB camera unplugged and plugged back, on the simulated head in this process: the
service is degraded naming the camera while its device node is gone, and running again
once the camera reopened with its config."""
from __future__ import annotations

import pytest

from headctl.service.control import SimFault
from headctl.service.daemon import Daemon
from headctl.service.parts import ServicePhase
from tests.conftest import sim_head_config, wait_until

pytestmark = pytest.mark.timeout(120)


def test_an_unplugged_camera_degrades_the_service_and_is_picked_up_when_plugged_back(tmp_path):
    with Daemon(sim_head_config(tmp_path / "state")) as daemon:
        control = daemon.control
        wait_until(lambda: control.snapshot().state is ServicePhase.RUNNING, 30, "running")
        left = daemon.parts.devices.cameras["left"]
        opens = left.opens
        control.inject_fault(SimFault.CAMERA_UNPLUG, camera="left")
        s = wait_until(lambda: (snap := control.snapshot()).faults.get("camera:left") and snap, 10,
                       "the camera:left fault")
        assert s.state is ServicePhase.DEGRADED
        assert "camera left: reconnecting" in s.faults["camera:left"]
        assert "device node is gone (unplugged)" in s.faults["camera:left"]
        assert "camera:right" not in s.faults and s.cameras["left"].health == "reconnecting"
        assert left.opens == opens  # no reopen succeeds while it is gone

        def told():
            return [(e["type"], e.get("key")) for e in daemon.parts.hub.recent(512)]

        # The supervisor tells faults on its rounds: the fault is told before it is healed.
        wait_until(lambda: ("fault", "camera:left") in told(), 5, "the fault event")
        control.inject_fault(SimFault.CAMERA_REPLUG, camera="left")
        s = wait_until(lambda: (snap := control.snapshot()).state is ServicePhase.RUNNING and snap, 15,
                       "running again")
        assert s.cameras["left"].health == "streaming" and s.cameras["left"].stats["reconnects"] == 1
        assert left.opens == opens + 1
        wait_until(lambda: ("fault_cleared", "camera:left") in told(), 5, "the fault_cleared event")
        assert told().index(("fault", "camera:left")) < told().index(("fault_cleared", "camera:left"))

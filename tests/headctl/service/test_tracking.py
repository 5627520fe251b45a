"""Tracking in the service (headctl.service.tracking): a daemon on the simulated head with a cube
sweeping in its room follows it through the API, stops when told, and gives way to a look; on
the manual clock, a track whose target outruns the head says it lost it."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from calib_free.gaze.pursuit import DEFAULT_JACOBIAN
from drivers.sim.motion import MovingObject
from headctl.api.client import ApiClient
from headctl.experiments.pursuit import run_speed
from headctl.api.compose import serve
from headctl.config.head import load_config
from tests.conftest import sim_head_config, wait_until
from tests.support import SIM_IDEAL

pytestmark = pytest.mark.timeout(120)

CUBE = MovingObject(speed_deg_s=8.0, sweep_deg=30.0)


@pytest.fixture(scope="module")
def head(tmp_path_factory):
    config = sim_head_config(tmp_path_factory.mktemp("track-state"))
    config = dataclasses.replace(config, sim_objects=(CUBE,),
                                 fixation=dataclasses.replace(config.fixation, explore=False))
    with serve(config) as daemon:
        yield daemon, ApiClient(daemon.api_url, timeout_s=10.0)


def cube_in_left_image(daemon) -> tuple[float, float]:
    """Where the cube's front-face centre is in the left image now (ground truth)."""
    world = daemon.parts.devices.world
    motion = world.scene.motion
    point = CUBE.centre(motion.elapsed_s()) - np.array([CUBE.size_m / 2, 0.0, 0.0])
    j = world.true_joints()
    (rotation, centre), _ = world.model.eye_frames_from_joints(j["pan"], j["tilt"], j["left_eye"], j["right_eye"])
    uv, seen = world.model.lens_left.project((rotation @ (point - centre))[None])
    assert seen[0]
    return float(uv[0, 0]), float(uv[0, 1])


def track_events(client, seq, job_id, last_type):
    events = []
    for event in client.events(after=seq, timeout_s=20):
        if event["type"].startswith("track_") and event.get("id") == job_id:
            events.append(event)
            if event["type"] == last_type:
                return events


def test_a_track_keeps_the_moving_cube_on_the_fovea_until_stopped(head):
    daemon, client = head
    seq = client.state()["events_seq"]
    job = client.track(*cube_in_left_image(daemon))
    assert job["request"]["kind"] == "track"
    # A second of pursuit: the cube (8 deg/s, about 33 px/s) stays near the fovea.
    live = wait_until(lambda: (t := client.get_track())["state"] == "running"
                      and (t["result"].get("stats") or {}).get("found", 0) >= 20 and t, timeout_s=20,
                      what="20 pairs of pursuit")
    x, y = cube_in_left_image(daemon)
    assert np.hypot(x - 159.5, y - 119.5) < 8.0, (x, y)
    stats = live["result"]["stats"]
    assert stats["retinal_error_px"]["last"] < 8.0 and stats["frame_to_command_ms"]["p50"] < 200
    assert client.state()["fixation"]["tracking"]["found"] >= 20  # the status shows the track too
    stopped = client.stop_track(wait_s=5)
    assert stopped["state"] == "done" and stopped["outcome"] == "stopped", stopped
    events = track_events(client, seq, job["id"], "track_stopped")
    assert [e["type"] for e in events] == ["track_started", "track_stopped"]
    assert events[-1]["outcome"] == "stopped"
    assert client.state()["fixation"]["tracking"] is None
    with pytest.raises(Exception, match="no track is queued or running"):
        client.stop_track()


def test_a_look_preempts_a_track(head):
    daemon, client = head
    seq = client.state()["events_seq"]
    job = client.track(*cube_in_left_image(daemon))
    wait_until(lambda: client.get_track()["state"] == "running", timeout_s=20, what="the track running")
    look = client.look_angles(0.0, 0.0, 8.0)
    track = client.look(job["id"], wait_s=10)
    assert track["state"] == "cancelled" and track["outcome"] == "preempted", track
    assert client.look(look["id"], wait_s=20)["state"] == "done"
    events = track_events(client, seq, job["id"], "track_stopped")
    assert events[-1]["outcome"] == "preempted"


def test_a_target_that_outruns_the_head_is_lost_and_said_so():
    """On the manual clock: the cube reverses at once at 300 deg/s; the patch leaves the
    search window and is not found for lost_after_frames pairs: track_lost, and no command
    is sent meanwhile."""

    class DefaultMap:
        class params:  # noqa: N801 (what Tracking reads of a map)
            disparity_range = (-60.0, 60.0)

        def command(self, r):
            return DEFAULT_JACOBIAN @ (np.asarray(r) - [159.5, 119.5, 0.0])

    events = []
    run = run_speed(300.0, DefaultMap(), duration_s=1.2, settle_s=0.0, base=load_config(SIM_IDEAL),
                    obj=MovingObject(turn_deg_s2=1e5, sweep_deg=40.0),
                    publish=lambda type_, **fields: events.append((type_, fields)))
    assert run.lost >= 1 and run.outcomes[0] == "lost"
    assert events[0][0] == "track_started" and events[1][0] == "track_lost"
    assert "not found in 10 pairs in a row" in events[1][1]["detail"]

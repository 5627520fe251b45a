"""Recordings: a bag of the simulated head read back by rosbags and mcap, split by duration,
its fixations replayed by relearn as the service ran them, a full disk that ends the recording
with a fault (cleared by the next recording) and not the service, the routes' refusals."""
from __future__ import annotations

import collections
import dataclasses
import errno
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from tests.headctl.ros2.support import need

need("rosbags")
need("mcap")

from mcap.reader import make_reader  # noqa: E402
from rosbags.rosbag2 import Reader, Writer  # noqa: E402
from rosbags.typesys import Stores, get_typestore  # noqa: E402

from headctl.api.client import ApiClient, ApiError  # noqa: E402
from headctl.api.compose import serve  # noqa: E402
from headctl.config.head import HeadConfig  # noqa: E402
from headctl.config.ros2 import Ros2Config, Ros2Recording  # noqa: E402
from headctl.experiments.relearn import RelearnRequest, relearn  # noqa: E402
from headctl.ros2.bag import mcap_writer  # noqa: E402
from headctl.ros2.recorder import Recordings, RecordState  # noqa: E402
from headctl.service.daemon import Daemon  # noqa: E402
from tests.conftest import sim_head_config, wait_until  # noqa: E402

STORE = get_typestore(Stores.ROS2_HUMBLE)


def config_for(tmp_path: Path, **recording: Any) -> HeadConfig:
    config = sim_head_config(tmp_path / "state")
    return dataclasses.replace(config, ros2=Ros2Config(recording=Ros2Recording(**recording)))


@pytest.fixture
def daemon(tmp_path: Path) -> Iterator[Daemon]:
    with serve(config_for(tmp_path)) as d:
        yield d


def record(daemon: Daemon, config: HeadConfig, seconds: float, **kw: Any) -> dict[str, Any]:
    with Recordings(daemon.control, config, **kw) as recordings:
        started = recordings.start(seconds=seconds)
        assert started["state"] == "recording"
        assert recordings.current is not None
        recordings.current.join(seconds + 10)
        return recordings.status()


def test_a_bag_of_the_simulated_head_reads_back_in_rosbags_and_mcap(tmp_path: Path) -> None:
    config = config_for(tmp_path)
    with serve(config) as daemon:
        wait_until(lambda: daemon.control.latest_frame("left") is not None, 20.0, "a first frame")
        status = record(daemon, config, 2.0)
    assert status["state"] == "stopped", status
    bag = Path(status["path"])
    assert (bag / "metadata.yaml").exists()
    with Reader(bag) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        types = {c.topic: c.msgtype for c in reader.connections}
        assert types["/joint_states"] == "sensor_msgs/msg/JointState"
        assert types["/head/left/image_raw/compressed"] == "sensor_msgs/msg/CompressedImage"
        assert types["/head/events"] == "diagnostic_msgs/msg/DiagnosticStatus"
        rate = config.service.servo_rate_hz
        assert 0.5 * 2 * rate <= counts["/joint_states"] <= 1.2 * 2 * rate + 5, counts
        assert counts["/head/left/image_raw/compressed"] >= 10, counts
        assert counts["/head/right/camera_info"] == counts["/head/right/image_raw/compressed"]
        assert counts["/tf_static"] == 1 and counts["/diagnostics"] >= 2, counts
        seen: dict[str, Any] = {}
        events: list[str] = []
        for conn, _, raw in reader.messages():
            if conn.topic not in seen:
                seen[conn.topic] = STORE.deserialize_cdr(raw, conn.msgtype)
            if conn.topic == "/head/events":
                events.append(STORE.deserialize_cdr(raw, conn.msgtype).name)
    assert any(e.startswith("fixation_") for e in events), events
    assert "learning" in events, events
    joints = seen["/joint_states"]
    assert list(joints.name) == ["pan", "tilt", "left_eye", "right_eye"]
    assert np.all(np.abs(joints.position) < 2.0)
    jpeg = seen["/head/left/image_raw/compressed"]
    assert jpeg.header.frame_id == "left_camera_optical_frame" and bytes(jpeg.data[:2]) == b"\xff\xd8"
    import cv2
    image = cv2.imdecode(np.asarray(jpeg.data, np.uint8), cv2.IMREAD_UNCHANGED)
    assert image.shape[:2] == (config.cameras.left.height, config.cameras.left.width)
    files = sorted(bag.glob("*.mcap"))
    assert len(files) == 1
    with files[0].open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    channels = {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}
    assert channels["/joint_states"] == "sensor_msgs/msg/JointState"
    assert channels["/tf"] == "tf2_msgs/msg/TFMessage"
    assert all(s.encoding == "ros2msg" for s in summary.schemas.values())


def test_a_bag_is_split_by_duration_into_files_of_one_metadata(tmp_path: Path, daemon: Daemon) -> None:
    config = config_for(tmp_path, max_bag_duration_s=0.5)
    status = record(daemon, config, 2.2)
    bag = Path(status["path"])
    files = sorted(p.name for p in bag.glob("*.mcap"))
    assert len(files) >= 4, files
    listed = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert sorted(listed["relative_file_paths"]) == files == sorted(f["path"] for f in listed["files"])
    with Reader(bag) as reader:
        total = sum(c.msgcount for c in reader.connections if c.topic == "/joint_states")
        assert total == sum(1 for c, _, _ in reader.messages() if c.topic == "/joint_states") > 0
        assert sum(1 for c, _, _ in reader.messages() if c.topic == "/tf_static") == len(files)
    assert status["state"] == "stopped", status


def test_a_flood_of_events_does_not_keep_a_recording_from_its_end(tmp_path: Path, daemon: Daemon) -> None:
    """Events published faster than they are written: the recording still ends at its deadline,
    with what it could write, and says how many it dropped."""
    config = config_for(tmp_path, max_bag_duration_s=0.2)
    flooding = threading.Event()
    flooding.set()

    def flood() -> None:
        while flooding.is_set():
            daemon.control.events.publish("flood_test", n=1)

    flooder = threading.Thread(target=flood, name="event-flood", daemon=True)
    with Recordings(daemon.control, config) as recordings:
        recordings.start(seconds=1.0)
        recording = recordings.current
        assert recording is not None
        flooder.start()
        try:
            recording.join(30.0)
            status = recordings.status()
        finally:
            flooding.clear()
            flooder.join(5.0)
    assert not recording.is_alive() and status["state"] == "stopped", status
    assert status["messages"]["head/events"] > 0 and status["messages"]["joint_states"] > 0, status


class FullDisk(Writer):
    writes = 0

    def write(self, connection: Any, timestamp: int, data: bytes | memoryview) -> None:
        FullDisk.writes += 1
        if FullDisk.writes > 200:
            raise OSError(errno.ENOSPC, "No space left on device")
        super().write(connection, timestamp, data)


def test_a_full_disk_stops_the_recording_with_a_fault_not_the_service(tmp_path: Path, daemon: Daemon) -> None:
    config = config_for(tmp_path)
    events: list[Any] = []
    unsubscribe = daemon.control.events.subscribe(events.append)

    def full_disk(path: Path) -> Writer:
        return FullDisk(path, version=9, storage_plugin=mcap_writer(path).storage_plugin)

    try:
        status = record(daemon, config, 30.0, writer=full_disk)
        snapshot = daemon.control.snapshot()
        assert "No space left on device" in snapshot.faults["recording"], snapshot.faults
        assert snapshot.state == "degraded"
        done = snapshot.fixation.done
        wait_until(lambda: daemon.control.snapshot().fixation.done > done, 20.0, "a fixation after the failure")
        wait_until(lambda: any(e["type"] == "fault" and e["key"] == "recording" for e in events), 5.0,
                   "the recording's fault event")
        with Recordings(daemon.control, config) as recordings:  # a disk with room again
            recordings.start()
            assert "recording" not in daemon.control.snapshot().faults
            wait_until(lambda: any(e["type"] == "fault_cleared" and e["key"] == "recording" for e in events), 5.0,
                       "the recording's fault cleared")
            assert recordings.stop()["state"] == "stopped"
    finally:
        unsubscribe()
    assert status["state"] == str(RecordState.FAILED)
    assert "No space left on device" in status["error"]
    assert any(e["type"] == "recording_failed" for e in events)
    assert daemon.control.snapshot().state == "running"


def test_relearn_replays_a_recording_of_the_service_as_it_ran(tmp_path: Path, daemon: Daemon) -> None:
    config = config_for(tmp_path)
    live: dict[int, str] = {}

    def fixation_event(event: Any) -> None:
        if event["type"] == "fixation_converged":
            live[event["index"]] = event["outcome"]
        elif event["type"] == "fixation_refused":
            live[event["index"]] = event["reason"]

    unsubscribe = daemon.control.events.subscribe(fixation_event)
    try:
        with Recordings(daemon.control, config) as recordings:
            recordings.start()
            current = recordings.current
            assert current is not None
            wait_until(lambda: current.counts["head/fixations"] >= 4, 60.0, "four fixations recorded")
            status = recordings.stop()
    finally:
        unsubscribe()
    report = relearn(RelearnRequest(Path(status["path"]), every=2))
    assert report.config_source == "the bag's recorded config"
    assert report.recorded.fixations >= 4 and status["fixations_dropped"] == 0
    assert report.replayed.fixations + sum(report.skipped.values()) == report.recorded.fixations
    assert report.agree == report.replayed.fixations, report.differences
    # The outcomes the service told as events, of the fixations the bag holds, are the replay's.
    told = collections.Counter(live[i] for i in _recorded_indices(Path(status["path"])))
    assert report.replayed.taught == told.pop("taught", 0)
    assert report.replayed.refused == dict(told)
    assert len(report.curve_recorded) == len(report.curve_replayed) >= 2


def _recorded_indices(bag: Path) -> set[int]:
    """The indices of the fixations the bag records (from its fixation records)."""
    from headctl.ros2.bag_reader import BagReader
    from headctl.ros2.fixation_log import FixationReader

    return {f.index for f in FixationReader().fixations(BagReader(bag).messages())}


def refusal(call: Any) -> ApiError:
    with pytest.raises(ApiError) as err:
        call()
    return err.value


def test_the_routes_start_stop_and_refuse_clearly(tmp_path: Path, daemon: Daemon) -> None:
    api = ApiClient(daemon.front_end.url if daemon.front_end else "", timeout_s=10.0)
    assert api.record_status() == {"state": "idle"}
    assert refusal(lambda: api.record_start(seconds=-1)).status == 422
    relative = refusal(lambda: api.record_start(directory="here"))
    assert relative.status == 422 and "absolute" in str(relative)
    assert refusal(api.record_stop).status == 409
    missing = refusal(lambda: api.record_start(directory=str(tmp_path / "missing")))
    assert missing.status == 422 and missing.field == "directory" and "existing directory" in str(missing)
    (tmp_path / "bags").mkdir()
    started = api.record_start(directory=str(tmp_path / "bags"))
    assert started["state"] == "recording"
    again = refusal(api.record_start)
    assert again.status == 409 and "already recording" in str(again)
    stopped = api.record_stop()
    assert stopped["state"] == "stopped"
    assert (Path(str(stopped["path"])) / "metadata.yaml").exists()


def test_headctl_record_seconds_prints_the_bag(tmp_path: Path, daemon: Daemon,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    from headctl.cli.main import main

    url = daemon.front_end.url if daemon.front_end else ""
    assert main(["record", "--seconds", "2", "--out", str(tmp_path / "out"), "--url", url]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    bag = Path(lines[-1])
    assert bag.parent == tmp_path / "out" and lines[0].startswith("stopped: ")
    with Reader(bag) as reader:
        assert reader.duration > 1.5e9
        assert {c.topic for c in reader.connections} >= {"/joint_states", "/head/right/image_raw/compressed"}
    assert main(["record", "stop", "--url", url]) == 1  # nothing recording: the daemon's reason
    assert "not recording" in capsys.readouterr().err

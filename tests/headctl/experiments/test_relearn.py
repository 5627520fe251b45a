"""Relearn: a recorded session of the simulated head replayed on a fresh map gives the live
run's figures; a bag cut short replays what reads; a bag without fixation records says what
is missing; the command line prints the report and its JSON."""
from __future__ import annotations

import collections
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from tests.headctl.ros2.support import need

need("rosbags")
need("mcap")

from rosbags.rosbag2 import Reader  # noqa: E402

from headctl.cli.main import main  # noqa: E402
from headctl.experiments.relearn import RelearnError, RelearnRequest, relearn  # noqa: E402
from headctl.ros2.bag import METADATA, SplitBag  # noqa: E402
from headctl.ros2.recorder import bag_topics, cdr  # noqa: E402
from headctl.ros2 import bagtypes  # noqa: E402
from tests.support.sim_bag import LiveRun, record_sim_bag  # noqa: E402

FIXATIONS = 40
EVERY = 10


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, LiveRun]:
    bag = tmp_path_factory.mktemp("relearn") / "session"
    return bag, record_sim_bag(bag, FIXATIONS)


def live_curve(live: LiveRun, every: int) -> list[float | None]:
    """The live run's mean retinal error per `every` fixations, from its adapter's results."""
    by_fixation = collections.defaultdict(list)
    for tag, result in live.adaptations:
        if result.accepted:
            by_fixation[tag].append(result.retinal_error)
    indices = [r.index for r in live.records]
    out: list[float | None] = []
    for start in range(0, len(indices), every):
        errors = [e for i in indices[start:start + every] for e in by_fixation[i]]
        out.append(float(np.mean(errors)) if errors else None)
    return out


def test_relearn_gives_the_live_runs_figures(recorded: tuple[Path, LiveRun]) -> None:
    bag, live = recorded
    report = relearn(RelearnRequest(bag, every=EVERY))
    outcomes = collections.Counter(str(r.outcome) for r in live.records)
    taught = outcomes.pop("taught", 0)
    assert 0 < taught < FIXATIONS, outcomes  # the run teaches and refuses: there is something to reproduce
    assert report.recorded.fixations == report.replayed.fixations == FIXATIONS
    assert report.recorded.taught == report.replayed.taught == taught
    assert report.replayed.refused == dict(outcomes)
    assert report.agree == FIXATIONS and not report.differences and not report.skipped
    assert report.config_source == "the bag's recorded config" and not report.truncated
    replayed = [p.retinal_error for p in report.curve_replayed]
    assert len(replayed) == FIXATIONS // EVERY
    expected = live_curve(live, EVERY)
    assert [e is None for e in expected] == [r is None for r in replayed]
    np.testing.assert_allclose([e for e in expected if e is not None], [r for r in replayed if r is not None],
                               rtol=1e-6)
    assert sum(p.adaptations for p in report.curve_replayed) == taught


def test_the_bag_stays_readable_by_rosbags(recorded: tuple[Path, LiveRun]) -> None:
    bag, _ = recorded
    with Reader(bag) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        counts = {c.topic: c.msgcount for c in reader.connections}
        assert types["/head/fixations"] == "diagnostic_msgs/msg/DiagnosticStatus"
        assert types["/head/fixation/left/image/compressed"] == "sensor_msgs/msg/CompressedImage"
        assert types["/head/fixation/config"] == "std_msgs/msg/String"
        assert counts["/head/fixations"] == FIXATIONS
        assert counts["/head/fixation/left/image/compressed"] == counts["/head/fixation/right/image/compressed"]
        # at least a pre-saccade pair and a post-saccade pair a fixation, a shared one written once
        assert counts["/head/fixation/left/image/compressed"] >= FIXATIONS
        for conn, _, raw in reader.messages():
            if conn.topic == "/head/fixation/left/image/compressed":
                msg = bagtypes.typestore().deserialize_cdr(raw, conn.msgtype)
                assert msg.format == "mono8; png compressed mono8" and bytes(msg.data[:4]) == b"\x89PNG"
                break


def cut_short(bag: Path, into: Path, fraction: float) -> Path:
    """`bag` as a killed recording leaves it: its file unlisted, in the folder it was being
    written in, ending `fraction` of the way through, without its summary."""
    shutil.copytree(bag, into)
    (mcap,) = into.glob("*.mcap")
    folder = into / mcap.stem
    folder.mkdir()
    data = mcap.read_bytes()
    (folder / mcap.name).write_bytes(data[:int(len(data) * fraction)])
    mcap.unlink()
    meta = yaml.safe_load((into / METADATA).read_text())
    meta["rosbag2_bagfile_information"]["relative_file_paths"] = []
    (into / METADATA).write_text(yaml.safe_dump(meta))
    return into


def test_a_bag_cut_short_replays_what_reads(recorded: tuple[Path, LiveRun], tmp_path: Path) -> None:
    bag, live = recorded
    report = relearn(RelearnRequest(cut_short(bag, tmp_path / "killed", 0.6), every=EVERY))
    assert report.truncated and "cut short" in report.problems[0]
    assert 0 < report.recorded.fixations < FIXATIONS
    assert report.agree == report.replayed.fixations == report.recorded.fixations - sum(report.skipped.values())
    first = collections.Counter(str(r.outcome) for r in live.records[:report.recorded.fixations])
    assert report.recorded.taught == first["taught"]


def test_a_bag_without_fixation_records_says_what_is_missing(tmp_path: Path, recorded: tuple[Path, LiveRun]) -> None:
    _, live = recorded
    bag = SplitBag(tmp_path / "old", bag_topics(live.config), 1_000_000, 10_000_000_000)
    joints = bagtypes.JointState(name=["pan"], position=[0.0], velocity=[0.0], effort=[])
    for i in range(5):
        bag.write("/joint_states", 1_000_000_000 + i, cdr(joints))
    bag.close()
    with pytest.raises(RelearnError, match=r"no fixation records.*/head/fixations.*/head/fixation/left/image"):
        relearn(RelearnRequest(tmp_path / "old"))


def test_the_command_prints_the_figures_and_their_json(recorded: tuple[Path, LiveRun], tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    bag, live = recorded
    assert main(["experiment", "relearn", str(bag), "--every", "20"]) == 0
    text = capsys.readouterr().out
    taught = sum(r.taught for r in live.records)
    assert f"{FIXATIONS} fixations recorded, {FIXATIONS} replayed" in text
    assert any(line.split()[:1] == ["taught"] and line.split()[1:] == [str(taught)] * 2 for line in text.splitlines())
    assert "1-20" in text and "21-40" in text
    assert main(["experiment", "relearn", str(bag), "--json"]) == 0
    answer = json.loads(capsys.readouterr().out)
    assert answer["replayed"]["taught"] == taught and answer["truncated"] is False
    assert main(["experiment", "relearn", str(tmp_path / "nothing")]) == 1
    assert "no such bag" in capsys.readouterr().err

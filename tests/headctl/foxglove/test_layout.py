"""docs/foxglove-layout.json against what the view publishes: two Image panels on the eyes'
images with their annotations, a 3D panel on the frames, Plot panels on the joint states and
the learning curve; every topic one the view advertises with the schema the panel draws, every
message path a field of that schema, every panel setting one Foxglove's layout model names
(foxglove-sdk's `foxglove.layouts`)."""
from __future__ import annotations

import dataclasses
import json
import re
from collections.abc import Iterator
from typing import Any

import pytest

from tests.headctl.foxglove.support import need_foxglove

need_foxglove()

import foxglove.layouts as fl  # noqa: E402

from drivers.clock import SYSTEM_CLOCK  # noqa: E402
from headctl.config.head import load_config  # noqa: E402
from headctl.foxglove.convert import LEARNING_SCHEMA  # noqa: E402
from headctl.foxglove.server import Publisher  # noqa: E402
from tests.support.daemon_proc import ROOT  # noqa: E402

LAYOUT = ROOT / "docs" / "foxglove-layout.json"
TITLE = "foxglovePanelTitle"  # a layout file's panel title, beside the panel's own settings
JOINTS = ("pan", "tilt", "left_eye", "right_eye")


class _Idle:
    """A service with nothing yet: enough for the publisher to advertise its channels."""

    def learning_since(self, since: int = 0, limit: int = 5000) -> dict[str, Any]:
        return {"next": 0, "points": []}


@pytest.fixture(scope="module")
def advertised(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, str]]:
    config = load_config().with_state_dir(tmp_path_factory.mktemp("layout"))
    config = dataclasses.replace(config, foxglove=dataclasses.replace(config.foxglove, enabled=True, port=0))
    publisher = Publisher(_Idle(), config, SYSTEM_CLOCK)  # type: ignore[arg-type]
    try:
        yield publisher.channels()
    finally:
        publisher.stop()


def keys_of(model: type) -> set[str]:
    required = {f.name: None for f in dataclasses.fields(model)
                if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING}
    return set(model(**required)._to_dict())


def panels() -> dict[str, dict[str, Any]]:
    return json.loads(LAYOUT.read_text())["configById"]


def leaves(node: Any) -> Iterator[str]:
    if isinstance(node, str):
        yield node
    else:
        yield from leaves(node["first"])
        yield from leaves(node["second"])


def test_the_arrangement_holds_every_panel_once() -> None:
    layout = json.loads(LAYOUT.read_text())
    shown = list(leaves(layout["layout"]))
    assert sorted(shown) == sorted(layout["configById"]), "panels configured and panels placed differ"
    kinds = [panel_id.split("!")[0] for panel_id in shown]
    assert (kinds.count("Image"), kinds.count("3D")) == (2, 1) and kinds.count("Plot") >= 1, kinds


def test_every_setting_is_one_foxglove_s_layout_model_names() -> None:
    models = {"Image": fl.ImageConfig, "3D": fl.ThreeDeeConfig, "Plot": fl.PlotConfig}
    for panel_id, config in panels().items():
        kind = panel_id.split("!")[0]
        assert set(config) - {TITLE} <= keys_of(models[kind]), (panel_id, set(config) - keys_of(models[kind]))
        if kind == "Image":
            assert set(config["imageMode"]) <= keys_of(fl.ImageModeConfig), panel_id
        if kind == "3D":
            assert set(config["cameraState"]) <= keys_of(fl.ThreeDeeCameraState), panel_id
            for layer in config["layers"].values():
                assert set(layer) <= keys_of(fl.BaseRendererGridLayerSettings), layer
        if kind == "Plot":
            for series in config["paths"]:
                assert set(series) <= keys_of(fl.PlotSeries), series


def test_the_images_and_their_annotations_are_the_eyes(advertised: dict[str, str]) -> None:
    images = {pid: c["imageMode"] for pid, c in panels().items() if pid.startswith("Image!")}
    assert sorted(m["imageTopic"] for m in images.values()) == ["/head/left/image", "/head/right/image"]
    for mode in images.values():
        assert advertised[mode["imageTopic"]] == "foxglove.CompressedImage"
        (notes, settings), = mode["annotations"].items()
        assert advertised[notes] == "foxglove.ImageAnnotations" and settings["visible"] is True
        assert notes.split("/")[2] == mode["imageTopic"].split("/")[2]  # the same eye


def test_the_3d_panel_shows_the_frames_from_the_base(advertised: dict[str, str]) -> None:
    (config,) = [c for pid, c in panels().items() if pid.startswith("3D!")]
    assert config["followTf"] == load_config().ros2.base_frame
    for topic in config["topics"]:
        assert advertised[topic] == "foxglove.FrameTransforms", topic


PATH = re.compile(r"(/[^.{\[]+)((?:\.joints\[:\]\{name==\"(\w+)\"\})?)\.([\w.]+)")


def test_the_plots_are_of_the_joint_states_and_the_learning_curve(advertised: dict[str, str]) -> None:
    joints, fields = set(), set()
    for pid, config in panels().items():
        if not pid.startswith("Plot!"):
            continue
        for series in config["paths"]:
            match = PATH.fullmatch(series["value"])
            assert match is not None, series["value"]
            topic, _, joint, field = match.groups()
            if advertised[topic] == "foxglove.JointStates":
                assert joint in JOINTS and field == "position", series["value"]
                joints.add(joint)
            else:
                assert advertised[topic] == "headctl.Learning", series["value"]
                node: dict[str, Any] = LEARNING_SCHEMA
                for part in field.split("."):
                    node = node["properties"][part]  # KeyError: no such field
                fields.add(field)
    assert joints == set(JOINTS)
    assert {"retinal_error", "confidence"} <= fields, fields

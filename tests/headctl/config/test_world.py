"""`headctl.config.world`: which simulated world a config puts its head in."""
from __future__ import annotations

import copy

from headctl.cli.service import format_status
from headctl.config.head import DEFAULT_CONFIG, load_config, parse_config, read_yaml
from headctl.config.world import WorldKind, simulated_world

IDEAL = DEFAULT_CONFIG.with_name("sim-ideal.yaml")


def test_the_default_config_is_the_realistic_world_and_sim_ideal_the_kind_one():
    realistic = simulated_world(load_config())
    ideal = simulated_world(load_config(IDEAL))
    assert realistic is not None and ideal is not None
    assert realistic.kind is WorldKind.REALISTIC and ideal.kind is WorldKind.IDEAL
    assert realistic.parts["servos"].preset == "xm430_head" and realistic.parts["camera sensor"].preset == "uvc_webcam"
    assert "frame timing free_running" in realistic.describe() and "light home" in realistic.describe()
    assert all(part.ideal for part in ideal.parts.values())


def test_one_changed_value_makes_a_mixed_world_and_says_which():
    data = read_yaml(IDEAL)
    edited = copy.deepcopy(data)
    edited["cameras"]["left"]["sensor"] = {"model": "ideal", "vignetting": 0.3}
    world = simulated_world(parse_config(edited, IDEAL))
    assert world is not None and world.kind is WorldKind.MIXED
    assert world.parts["left camera sensor"].describe() == "ideal (vignetting changed)"
    assert world.parts["right camera sensor"].ideal


def test_a_real_head_is_in_no_simulated_world():
    assert simulated_world(load_config(DEFAULT_CONFIG.with_name("usb-webcams.yaml"))) is None


def test_headctl_status_names_the_world():
    world = simulated_world(load_config())
    assert world is not None
    status = {"state": "running", "pid": 1, "uptime_s": 3.0, "config": "sim.yaml", "faults": [], "joints": {},
              "servo_loop": {}, "fixation": {"state": "idle", "explore": True, "done": 0, "taught": 0, "refused": {}},
              "learning": {}, "map": {"path": "m", "restored_from": "new", "checkpoints": 0, "problems": []},
              "cameras": {}, "world": world.as_dict()}
    assert "  simulated world: realistic: camera sensor uvc_webcam" in format_status(status)

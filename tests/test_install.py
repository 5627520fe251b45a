"""The udev rules and the systemd unit parse, and name what the example configs use."""
from __future__ import annotations

import configparser
import pathlib
import re
import shutil
import subprocess

import pytest

from headctl.config.head import load_config
from tests.support import ROOT

RULES = sorted((ROOT / "udev").glob("*.rules"))
UNIT = ROOT / "systemd" / "headctl@.service"
EXAMPLES = ["sim.yaml", "xm430-u2d2-aravis.yaml", "usb-webcams.yaml"]

MATCH_KEYS = {"ACTION", "SUBSYSTEM", "SUBSYSTEMS", "KERNEL", "KERNELS", "ATTR", "ATTRS", "ENV", "DRIVERS", "TAG"}
ASSIGN_KEYS = {"SYMLINK", "MODE", "GROUP", "OWNER", "ATTR", "ENV", "RUN", "TAG"}
TOKEN = re.compile(r'\s*([A-Z]+)(\{[^}]+\})?\s*(==|!=|\+=|-=|:=|=)\s*"([^"]*)"\s*(,|$)')


def parse_rules(path: pathlib.Path) -> list[list[tuple[str, str, str, str]]]:
    """Each rule as (key, {attr}, operator, value) tokens; asserts udev's syntax and keys."""
    rules = []
    for n, line in enumerate(path.read_text().splitlines(), 1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        tokens, pos = [], 0
        while pos < len(line):
            m = TOKEN.match(line, pos)
            assert m, f"{path.name}:{n}: cannot parse from column {pos}: {line[pos:]!r}"
            key, attr, op, value, _ = m.groups()
            if op in ("==", "!="):
                assert key in MATCH_KEYS, f"{path.name}:{n}: {key} is not a match key"
            else:
                assert key in ASSIGN_KEYS, f"{path.name}:{n}: {key} cannot be assigned"
            if key in ("ATTR", "ATTRS", "ENV"):
                assert attr, f"{path.name}:{n}: {key} needs {{name}}"
            tokens.append((key, attr or "", op, value))
            pos = m.end()
        assert any(op in ("==", "!=") for _, _, op, _ in tokens), f"{path.name}:{n}: a rule without a match"
        rules.append(tokens)
    return rules


def all_rules():
    return [rule for path in RULES for rule in parse_rules(path)]


def _assigned(rule, key):
    return [v for k, _, op, v in rule if k == key and op in ("=", "+=", ":=")]


def test_every_rule_file_parses():
    assert {p.name for p in RULES} >= {"99-headctl-servos.rules", "99-headctl-cameras.rules"}
    for path in RULES:
        assert parse_rules(path), f"{path.name} has no rules"


@pytest.mark.parametrize("name", EXAMPLES)
def test_the_rules_name_every_device_an_example_config_uses(name):
    config = load_config(ROOT / "configs" / name)
    rules = all_rules()
    links = {link: rule for rule in rules for link in _assigned(rule, "SYMLINK")}
    devices = []
    if config.servo_bus.backend == "dynamixel":
        devices.append((config.servo_bus.port, "dialout"))
    for side in ("left", "right"):
        cam = getattr(config.cameras, side)
        if cam.backend == "opencv" and str(cam.device).startswith("/dev/"):
            devices.append((str(cam.device), "video"))
        if cam.backend == "aravis":  # USB3 Vision: access to the USB device for the video group
            assert any(("SUBSYSTEM", "", "==", "usb") in r and _assigned(r, "GROUP") == ["video"] for r in rules)
    for device, group in devices:
        link = device.removeprefix("/dev/")
        assert link in links, f"{name}: no udev rule names {device}"
        assert _assigned(links[link], "GROUP") == [group] and _assigned(links[link], "MODE") == ["0660"]


def test_the_servo_adapter_rule_sets_the_latency_timer():
    (rule,) = [r for r in parse_rules(ROOT / "udev" / "99-headctl-servos.rules")]
    assert ("ATTR", "{device/latency_timer}", "=", "1") in rule
    assert ("ATTRS", "{idProduct}", "==", "6014") in rule


def test_the_unit_is_type_notify_with_watchdog_restart_and_an_unprivileged_user():
    unit = configparser.ConfigParser(interpolation=None, strict=False)
    unit.optionxform = str
    unit.read(UNIT)
    service = unit["Service"]
    assert service["Type"] == "notify" and service["Restart"] == "on-failure"
    assert int(service["WatchdogSec"]) > 0 and service["User"] not in ("", "root")
    assert set(service["SupplementaryGroups"].split()) == {"dialout", "video"}
    assert service["ExecStart"].split()[1:4] == ["run", "--config", "/etc/headctl/%i.yaml"]
    assert service["StateDirectory"] == "headctl/%i"
    # systemd restarts a unit that gave up (exit 3) or failed, after a pause, within its own rate limit
    assert float(service["RestartSec"]) >= 1
    assert int(unit["Unit"]["StartLimitBurst"]) >= 2 and int(unit["Unit"]["StartLimitIntervalSec"]) > 0
    assert int(unit["Unit"]["StartLimitIntervalSec"]) > int(unit["Unit"]["StartLimitBurst"]) * float(
        service["RestartSec"])  # the burst fits in the interval: the limit can trip
    for name in EXAMPLES[1:]:  # the real heads keep their state where the unit's StateDirectory is
        assert load_config(ROOT / "configs" / name).state_dir == pathlib.Path("/var/lib/headctl") / name[:-5]
    if shutil.which("systemd-analyze"):  # systemd's own parser, where systemd is installed
        out = subprocess.run(["systemd-analyze", "verify", str(UNIT)], capture_output=True, text=True)
        problems = [line for line in (out.stdout + out.stderr).splitlines()
                    if line.strip() and "is not executable" not in line]
        assert not problems, problems

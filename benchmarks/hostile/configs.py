"""Hostile head configs against `headctl check` and `headctl run`: does any config give a
traceback, an unlocated error, a leaked API token, or a `check` that passes where `run`
refuses?

Every config starts from configs/sim-ideal.yaml with an API token added (so that every case also
checks that the token never shows). Two sets:

1. By hand, about 150: files that are not UTF-8, not YAML or not files; nesting, aliases and
   duplicate keys; backends unknown, not importable, of the wrong kind or abstract, and keys
   or servo models a backend does not take; a wrong type at many key paths; every bound on
   what sizes an allocation, a loop or a wait; state directories, log files, token files and
   TLS files that cannot be used; the token in every place an error could show it.
2. `--random` more, from a seeded generator: keys deleted, renamed and duplicated, values
   replaced by random scalars, lists and mappings of random depth, huge numbers, raw YAML
   oddities, and random bytes spliced in or for the whole file.

Each config goes through `load_config`, `headctl check --no-connect` and `headctl run` in this
process (`run` as far as starting the service: the `Daemon` is replaced by a stand-in that
records it was reached). A config passes when all three accept it, or all three refuse it:
`load_config` with a `ConfigError`, `check` and `run` with exit 2 and a message naming the
file and then a key path or the line and column. Figures: configs tried, accepted, refused
with a located error, tracebacks (any other exception), unlocated errors, check/run
disagreements, token leaks.

    .venv/bin/python -m benchmarks.hostile.configs [--random 1000] [--seed 1] [--max-seconds 300]

Bounded: no network, files only under a temporary directory, at most --max-seconds. Exits 1
on any traceback, unlocated error, disagreement or leak.
"""
from __future__ import annotations

import argparse
import contextlib
import io
import logging
import math
import random
import re
import sys
import tempfile
import time
import traceback
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

import yaml

from benchmarks.support.yaml_text import Map, Raw, emit, tree
import headctl.service.daemon
from headctl.cli.main import main
from headctl.config.head import load_config
from headctl.errors import ConfigError

ROOT = Path(__file__).resolve().parents[2]
TOKEN = "hostile-bench-token-8d41c2"
TLS = ROOT / "tests" / "data" / "tls"
SIM_TEXT = (ROOT / "configs" / "sim-ideal.yaml").read_text()  # no simulation-only sections


def base() -> dict:
    data = yaml.safe_load(SIM_TEXT)
    data["api"]["token"] = TOKEN
    return data


def base_text() -> str:
    return SIM_TEXT.replace("  port: 8765", f"  port: 8765\n  token: {TOKEN}")


# --- the hand-made configs -------------------------------------------------------------------------
# A case makes the file's content (bytes) in the scratch folder, or returns a path to use as is.
Case = Callable[[Path], "bytes | Path"]
VALID: set[str] = set()  # cases that must be accepted


def edit(change: Callable[[dict, Path], Any]) -> Case:
    def make(folder: Path) -> bytes:
        data = base()
        change(data, folder)
        return yaml.safe_dump(data).encode()
    return make


def text(change: Callable[[str], str]) -> Case:
    return lambda folder: change(base_text()).encode()


def cam(key: str, value: Any) -> Case:
    return edit(lambda d, f: [d["cameras"][s].update({key: value}) for s in ("left", "right")])


def sect(section: str, **values: Any) -> Case:
    return edit(lambda d, f: d.setdefault(section, {}).update(values))


def joint(name: str, **values: Any) -> Case:
    return edit(lambda d, f: d["servo_bus"]["joints"][name].update(values))


def on_dynamixel(d: dict) -> dict:
    d["servo_bus"].update(backend="dynamixel", port="/dev/null")
    for side in ("left", "right"):
        for key in ("eye", "lens", "seed", "noise_std"):
            d["cameras"][side].pop(key)
        d["cameras"][side].update(backend="opencv", device=0 if side == "left" else 1)
    return d


def write(folder: Path, name: str, content: bytes) -> str:
    (folder / name).write_bytes(content)
    return str(folder / name)


CASES: dict[str, Case] = {}


def case(name: str, make: Case, valid: bool = False) -> None:
    assert name not in CASES, name
    CASES[name] = make
    if valid:
        VALID.add(name)


# Files that are not a config.
case("missing file", lambda f: f / "nowhere.yaml")
case("a directory", lambda f: f)
case("/dev/zero", lambda f: Path("/dev/zero"))
case("empty file", lambda f: b"")
case("only a comment", lambda f: b"# nothing\n")
case("2 MiB of comment", lambda f: b"#" + b"x" * (2 << 20) + b"\n")
case("not UTF-8", lambda f: b"\x80\x81")
case("Latin-1 in a value", lambda f: base_text().replace('"sim:head"', '"t\xeate"').encode("latin-1"))
case("UTF-16 with BOM", lambda f: base_text().encode("utf-16"))
case("UTF-16LE without BOM", lambda f: base_text().encode("utf-16-le"))
case("UTF-32 with BOM", lambda f: base_text().encode("utf-32"))
case("UTF-8 with BOM", lambda f: b"\xef\xbb\xbf" + base_text().encode(), valid=True)
case("CRLF line ends", lambda f: base_text().replace("\n", "\r\n").encode(), valid=True)
case("a NUL byte", lambda f: base_text().replace("fixation:", "fix\0ation:").encode())
case("a control character", lambda f: base_text().replace("sim:head", "sim:\x07head").encode())
case("4 KiB of random bytes", lambda f: random.Random(7).randbytes(4096))
case("an escape sequence in a key", lambda f: base_text().replace("logging:", "logging:\n  \"\\e[2J\": 1").encode())

# YAML that is not a head's config, or not YAML.
case("unclosed bracket", lambda f: b"servo_bus: [\n")
case("tab indentation", lambda f: base_text().replace("  backend: sim", "\tbackend: sim", 1).encode())
case("a list at the top", lambda f: b"- servo_bus\n- cameras\n")
case("a scalar at the top", lambda f: b"head\n")
case("null at the top", lambda f: b"~\n")
case("two documents", lambda f: (base_text() + "---\n" + base_text()).encode())
case("5000-deep lists", lambda f: b"servo_bus: " + b"[" * 5000 + b"]" * 5000)
case("5000-deep mappings", lambda f: b"servo_bus: " + b"{a: " * 5000 + b"1" + b"}" * 5000)
case("40-deep block mappings", lambda f: "".join(f"{'  ' * i}k{i}:\n" for i in range(40)).encode() + b"  " * 40 + b"x")
case("billion laughs", lambda f: ("a: &a [lol, lol, lol, lol, lol, lol, lol, lol, lol]\n" + "".join(
    f"{n}: &{n} [{', '.join([f'*{p}'] * 9)}]\n" for p, n in zip("abcdefgh", "bcdefghi"))).encode())
case("a recursive alias", lambda f: base_text().replace("logging:\n  level: INFO", "logging: &l\n  level: [*l]").encode())
case("an undefined alias", lambda f: base_text().replace("level: INFO", "level: *nowhere").encode())
case("a duplicate top-level key", text(lambda t: t.replace("state_dir:", "state_dir: /tmp\nstate_dir:")))
case("a duplicate joint", text(lambda t: t.replace("    tilt:", "    pan:       {id: 2, min_angle: -25, max_angle: 25}\n"
                                                         "    tilt:", 1)))
case("a duplicate key in a joint", text(lambda t: t.replace("{id: 1, min_angle: -40,", "{id: 1, min_angle: -40, "
                                                                                      "min_angle: -10,")))
case("a duplicate token", text(lambda t: t.replace(f"  token: {TOKEN}", f"  token: {TOKEN}\n  token: {TOKEN}x")))
case("a duplicate section", text(lambda t: t + "fixation:\n  explore: false\n"))
case("joints sharing settings by a merge key", text(lambda t: t.replace(
    "    pan:       {id: 1,", "    pan:       &j {id: 1,").replace(
    "    tilt:      {id: 2, min_angle: -25, max_angle: 25, profile_velocity: 240, profile_acceleration: 2400}",
    "    tilt:      {<<: *j, id: 2, min_angle: -25, max_angle: 25}")), valid=True)
case("a merge key of a scalar", text(lambda t: t.replace("  level: INFO", "  <<: 3\n  level: INFO")))
case("a python tag", text(lambda t: t.replace("level: INFO", "level: !!python/object/apply:os.system [ls]")))
case("a binary port", text(lambda t: t.replace('port: "sim:head"', "port: !!binary aGVhZA==")))
case("a set as joints", text(lambda t: t.replace("  joints:\n", "  joints: !!set {pan, tilt}\n  x:\n")))
case("an impossible date", text(lambda t: t.replace("state_dir: ~/.local/state/headctl/sim", "state_dir: 2026-13-45")))
case("a date as a path", text(lambda t: t.replace("state_dir: ~/.local/state/headctl/sim", "state_dir: 2026-11-30")))
case("a 5000-digit integer", text(lambda t: t.replace("servo_rate_hz: 100", "servo_rate_hz: " + "9" * 5000)))
case("a complex key", lambda f: b"? [servo_bus]\n: 1\n")
case("nan for a rate", text(lambda t: t.replace("servo_rate_hz: 100", "servo_rate_hz: .nan")))
case("inf for a timeout", sect("service", input_timeout_s=math.inf))
case("1.0e+400 for a rate", text(lambda t: t.replace("servo_rate_hz: 100", "servo_rate_hz: 1.0e+400")))

# Backends.
case("unknown camera backend", edit(lambda d, f: d["cameras"]["left"].update(backend="nosuch")))
case("unknown servo backend", edit(lambda d, f: d["servo_bus"].update(backend="canbus")))
case("camera module that does not import", edit(lambda d, f: d["cameras"]["left"].update(backend="no_such_pkg:Cam")))
case("servo module that does not import", edit(lambda d, f: d["servo_bus"].update(backend="no_such_pkg:Bus")))
case("camera backend collections:OrderedDict",
     edit(lambda d, f: d["cameras"]["left"].update(backend="collections:OrderedDict")))
case("servo backend collections:OrderedDict", edit(lambda d, f: d["servo_bus"].update(backend="collections:OrderedDict")))
case("camera backend that is not a class", edit(lambda d, f: d["cameras"]["right"].update(backend="os:sep")))
case("backend ':X'", edit(lambda d, f: d["cameras"]["left"].update(backend=":X")))
case("backend '..x:Y'", edit(lambda d, f: d["cameras"]["left"].update(backend="..x:Y")))
case("a class the module has not", edit(lambda d, f: d["cameras"]["left"].update(backend="drivers.cameras.camera:NoSuch")))
case("the abstract ServoBus", edit(lambda d, f: d["servo_bus"].update(backend="drivers.servo.bus:ServoBus")))
case("the simulated bus by its full name", edit(
    lambda d, f: d["servo_bus"].update(backend="drivers.sim.servos:SimulatedServoBus")))
case("the simulated cameras by their full name", edit(
    lambda d, f: [d["cameras"][s].update(backend="drivers.sim.camera:SimulatedCamera") for s in ("left", "right")]))
case("a camera class as the servo backend", edit(
    lambda d, f: d["servo_bus"].update(backend="drivers.cameras.opencv:OpenCVCamera")))
case("dynamixel with simulated cameras", edit(lambda d, f: d["servo_bus"].update(backend="dynamixel")))
case("one simulated eye", edit(lambda d, f: d["cameras"]["right"].update(backend="opencv")))
for key, value in (("baud", 57600), ("retries", 3), ("protocol", 2.0), ("latency_timer_ms", 1),
                   ("return_delay_us", 0), ("reboot_timeout_s", 2)):
    case(f"sim servo bus with {key}", sect("servo_bus", **{key: value}))
case("sim joint with a model", joint("pan", model="XM430-W350"))
case("dynamixel, unknown model", edit(lambda d, f: on_dynamixel(d)["servo_bus"]["joints"]["pan"].update(model="AX-12A")))
case("dynamixel, model in lower case",
     edit(lambda d, f: on_dynamixel(d)["servo_bus"]["joints"]["tilt"].update(model="xm430-w350")))
case("dynamixel by its full name", edit(
    lambda d, f: on_dynamixel(d)["servo_bus"].update(backend="drivers.dynamixel.bus_v2:DynamixelBus")), valid=True)
case("opencv camera with a seed", edit(lambda d, f: on_dynamixel(d)["cameras"]["left"].update(seed=3)))
case("sim camera with a serial", edit(lambda d, f: d["cameras"]["left"].update(serial="S1")))
case("aravis camera with a device", edit(lambda d, f: on_dynamixel(d)["cameras"]["left"].update(backend="aravis")))
case("sim camera without eye", edit(lambda d, f: d["cameras"]["left"].pop("eye")))
case("sim cameras with swapped eyes", edit(lambda d, f: (d["cameras"]["left"].update(eye="right"),
                                                         d["cameras"]["right"].update(eye="left"))))

# Wrong types.
for name, change in {
    "servo_bus a list": lambda d: d.update(servo_bus=[1, 2]),
    "joints a list": lambda d: d["servo_bus"].update(joints=["pan"]),
    "a joint a string": lambda d: d["servo_bus"]["joints"].update(pan="id 1"),
    "id a string": lambda d: d["servo_bus"]["joints"]["pan"].update(id="1"),
    "id a float": lambda d: d["servo_bus"]["joints"]["pan"].update(id=1.5),
    "id true": lambda d: d["servo_bus"]["joints"]["pan"].update(id=True),
    "min_angle text": lambda d: d["servo_bus"]["joints"]["tilt"].update(min_angle="low"),
    "limit_policy unknown": lambda d: d["servo_bus"].update(limit_policy="loose"),
    "torque_on_close a string": lambda d: d["servo_bus"].update(torque_on_close="yes please"),
    "cameras a string": lambda d: d.update(cameras="two"),
    "a camera null": lambda d: d["cameras"].update(left=None),
    "width a float": lambda d: d["cameras"]["left"].update(width=320.5),
    "fps text": lambda d: d["cameras"]["left"].update(fps="fast"),
    "image color": lambda d: d["cameras"]["left"].update(image="color"),
    "lens fisheye": lambda d: d["cameras"]["left"].update(lens="fisheye"),
    "profile fast": lambda d: d["gaze_map"].update(profile="fast"),
    "grid_shape of 2": lambda d: d["gaze_map"].update(grid_shape=[10, 10]),
    "command_range flat": lambda d: d["gaze_map"].update(command_range=[1, 2, 3]),
    "explore a string": lambda d: d["fixation"].update(explore="yes please"),
    "correspondence a list": lambda d: d["fixation"].update(correspondence=[20, 20]),
    "service a list": lambda d: d.update(service=[100]),
    "api port a string": lambda d: d["api"].update(port="80"),
    "log level LOUD": lambda d: d["logging"].update(level="LOUD"),
    "state_dir a number": lambda d: d.update(state_dir=3),
    "state_dir empty": lambda d: d.update(state_dir=""),
    "an unknown top-level key": lambda d: d.update(colour=True),
    "an unknown nested key": lambda d: d["fixation"].update(rate=3),
    "servo_bus missing": lambda d: d.pop("servo_bus"),
    "a joint missing": lambda d: d["servo_bus"]["joints"].pop("right_eye"),
    "a fifth joint": lambda d: d["servo_bus"]["joints"].update(roll={"id": 9}),
}.items():
    case(name, edit(lambda d, f, change=change: change(d)))

# Bounds: allocations, loops, waits, physical sense.
case("camera width 1e9", cam("width", 10**9))
case("camera height 1e9", cam("height", 10**9))
case("8192 x 8192 images", edit(lambda d, f: [d["cameras"][s].update(width=8192, height=8192) for s in ("left", "right")]))
case("4096 x 4096 with history 32", edit(lambda d, f: [d["cameras"][s].update(width=4096, height=4096, history=32)
                                                       for s in ("left", "right")]))
case("history 1e6", cam("history", 10**6))
case("buffers 1e6", edit(lambda d, f: on_dynamixel(d)["cameras"]["left"].update(buffers=10**6)))
case("fps 0", cam("fps", 0))
case("fps 1e9", cam("fps", 1e9))
case("fps -1", cam("fps", -1))
case("exposure 1e12 us", edit(lambda d, f: on_dynamixel(d)["cameras"]["left"].update(exposure_us=1e12)))
case("gain 1e6 dB", edit(lambda d, f: on_dynamixel(d)["cameras"]["left"].update(gain_db=1e6)))
case("noise_std 1e6", cam("noise_std", 1e6))
case("grab_timeout_s 1e300", cam("grab_timeout_s", 1e300))
case("reconnect_give_up_s 1e12", edit(lambda d, f: on_dynamixel(d)["cameras"]["left"].update(reconnect_give_up_s=1e12)))
case("camera seed -1", cam("seed", -1))
case("device index -1", edit(lambda d, f: on_dynamixel(d)["cameras"]["left"].update(device=-1)))
case("tolerance_s 1e9", edit(lambda d, f: d["cameras"].update(tolerance_s=1e9)))
case("grid 1e5 x 1e5 x 1e3", sect("gaze_map", grid_shape=[100000, 100000, 1000]))
case("grid 1000 x 1000 x 1000", sect("gaze_map", grid_shape=[1000, 1000, 1000]))
case("grid of 1 node", sect("gaze_map", grid_shape=[1, 1, 1]))
case("output_resolution 0", sect("gaze_map", output_resolution=[0, 50, 50]))
case("output_resolution 1e9", sect("gaze_map", output_resolution=[10**9, 50, 50]))
case("error_window 1e9", sect("gaze_map", error_window=10**9))
case("global_degree 1000", sect("gaze_map", global_degree=1000))
case("global_memory 0", sect("gaze_map", global_memory=0))
case("gaussian_cutoff 0", sect("gaze_map", gaussian_cutoff=0))
case("gaussian_cutoff 1", sect("gaze_map", gaussian_cutoff=1))
case("sigma_max_fraction 0", sect("gaze_map", sigma_max_fraction=0))
case("command_range 1e6 deg", sect("gaze_map", command_range=[[-1e6, 1e6], [-35, 35], [-17, 17]]))
case("disparity_range 1e9 px", sect("gaze_map", disparity_range=[-1e9, 1e9]))
case("gaze_map.seed -1", sect("gaze_map", seed=-1))
case("gaze_map.seed 2**64", sect("gaze_map", seed=2**64))
case("vergence_range [-100, 100]", sect("fixation", vergence_range=[-100, 100]))
case("vergence_range reversed", sect("fixation", vergence_range=[20, 1]))
case("eyes allowing no vergence", edit(lambda d, f: [d["servo_bus"]["joints"][j].update(min_angle=10, max_angle=20)
                                                     for j in ("left_eye", "right_eye")]))
case("settle_timeout_s -1", sect("fixation", settle_timeout_s=-1))
case("frame_timeout_s 1e300", sect("fixation", frame_timeout_s=1e300))
case("max_vergence_steps 1e9", sect("fixation", max_vergence_steps=10**9))
case("vergence patch wider than the image", sect("fixation", vergence_patch_size=[1000, 10]))
case("correspondence patch 2 x 2", sect("fixation", correspondence={"patch_size": [2, 2]}))
case("pyramid_levels 64", sect("fixation", correspondence={"pyramid_levels": 64}))
case("vergence_search_px 1e6", sect("fixation", vergence_search_px=10**6))
case("exploration steps of 0", sect("fixation", exploration_step_deg=[0, 0, 0]))
case("rate_hz 1e9", sect("fixation", rate_hz=1e9))
case("input_timeout_s 1e300", sect("service", input_timeout_s=1e300))
case("checkpoint_every 0", sect("service", checkpoint_every=0))
case("checkpoint_every 1e30", sect("service", checkpoint_every=10**30))
case("camera_stall_s 1e9", sect("service", camera_stall_s=1e9))
case("shutdown_timeout_s 1e9", sect("service", shutdown_timeout_s=1e9))
case("switch_interval_ms 0", sect("service", switch_interval_ms=0))
case("realtime_priority 1000", sect("service", realtime_priority=1000))
case("servo_rate_hz 1e6", sect("service", servo_rate_hz=1e6))
case("api port 70000", sect("api", port=70000))
case("max_queued_looks 1e9", sect("api", max_queued_looks=10**9))
case("stream_fps 0", sect("api", stream_fps=0))
case("jpeg_quality 5", sect("api", jpeg_quality=5))
case("servo id 300", joint("pan", id=300))
case("two joints with one id", joint("tilt", id=1))
case("min_angle above max_angle", joint("pan", min_angle=50, max_angle=40))
case("a limit beyond the servo's turn", joint("pan", zero_offset=170, max_angle=40))
case("zero_offset 1000", joint("pan", zero_offset=1000))
case("profile_velocity -1", joint("pan", profile_velocity=-1))
case("watchdog_ms 13", sect("servo_bus", watchdog_ms=13))
case("dynamixel return_delay_us odd", edit(lambda d, f: on_dynamixel(d)["servo_bus"].update(return_delay_us=3)))
case("dynamixel latency 1e9 ms", edit(lambda d, f: on_dynamixel(d)["servo_bus"].update(latency_timer_ms=1e9)))
case("dynamixel retries 100", edit(lambda d, f: on_dynamixel(d)["servo_bus"].update(retries=100)))
case("dynamixel protocol 1.0 with X-series models", edit(lambda d, f: on_dynamixel(d)["servo_bus"].update(protocol=1.0)))
case("dynamixel baud 12", edit(lambda d, f: on_dynamixel(d)["servo_bus"].update(baud=12)))

# What running needs of this machine, and the files the config names.
case("state_dir is a file", edit(lambda d, f: d.update(state_dir="/etc/passwd")))
case("state_dir under a file", edit(lambda d, f: d.update(state_dir="/etc/passwd/state")))
case("state_dir that cannot be created", edit(lambda d, f: d.update(state_dir="/proc/headctl/state")))
case("state_dir with a NUL", edit(lambda d, f: d.update(state_dir="/tmp/a\0b")))
case("state_dir beside the config", edit(lambda d, f: d.update(state_dir="state")), valid=True)
case("logging.file in a missing directory", sect("logging", file="/nonexistent/x"))
case("logging.file a directory", edit(lambda d, f: d["logging"].update(file=str(f))))
case("logging.file in /proc", sect("logging", file="/proc/headctl.log"))
case("logging.file that can be written", edit(lambda d, f: d["logging"].update(file=str(f / "head.log"))), valid=True)
case("token_file missing", edit(lambda d, f: (d["api"].pop("token"), d["api"].update(token_file="no-such-token"))))
case("token_file a directory", edit(lambda d, f: (d["api"].pop("token"), d["api"].update(token_file="."))))
case("token_file /dev/zero", edit(lambda d, f: (d["api"].pop("token"), d["api"].update(token_file="/dev/zero"))))
case("token_file not UTF-8", edit(lambda d, f: (d["api"].pop("token"), d["api"].update(
    token_file=write(f, "t1", b"\xff\xfe" + TOKEN.encode("utf-16-le"))))))
case("token_file of 1 MiB", edit(lambda d, f: (d["api"].pop("token"), d["api"].update(
    token_file=write(f, "t2", (TOKEN + "\n").encode() * 40000)))))
case("token_file too short", edit(lambda d, f: (d["api"].pop("token"), d["api"].update(
    token_file=write(f, "t3", b"short\n")))))
case("token_file with an escape sequence", edit(lambda d, f: (d["api"].pop("token"), d["api"].update(
    token_file=write(f, "t4", (TOKEN + "\x1b[2J").encode())))))
case("token_file that is fine", edit(lambda d, f: (d["api"].pop("token"), d["api"].update(
    token_file=write(f, "t5", (TOKEN + "\n").encode())))), valid=True)
case("token and token_file", edit(lambda d, f: d["api"].update(token_file=write(f, "t6", TOKEN.encode()))))
case("tls_cert missing", sect("api", tls_cert=str(TLS / "nowhere.pem"), tls_key=str(TLS / "head-key.pem")))
case("tls_cert /dev/zero", sect("api", tls_cert="/dev/zero", tls_key=str(TLS / "head-key.pem")))
case("tls_cert not PEM", sect("api", tls_cert=str(TLS / "README.md"), tls_key=str(TLS / "head-key.pem")))
case("tls_key of another certificate", sect("api", tls_cert=str(TLS / "head-cert.pem"),
                                            tls_key=str(TLS / "other-key.pem")))
case("tls_cert alone", sect("api", tls_cert=str(TLS / "head-cert.pem")))
case("non-loopback without a token", edit(lambda d, f: (d["api"].pop("token"), d["api"].update(host="0.0.0.0"))))
case("api.host not a host", sect("api", host="not a host"))

# The token, wherever an error could show it.
case("token too short", edit(lambda d, f: d["api"].update(token="short")))
case("token in a list", edit(lambda d, f: d["api"].update(token=[TOKEN])))
case("token in a mapping", edit(lambda d, f: d["api"].update(token={"value": TOKEN})))
case("token under a misspelt key", edit(lambda d, f: d["api"].update(tokn=d["api"].pop("token"))))
case("token with a newline", edit(lambda d, f: d["api"].update(token=TOKEN + "\n")))
case("the api section renamed", edit(lambda d, f: d.update(apix=d.pop("api"))))
case("the api section as a list", edit(lambda d, f: d.update(api=[d["api"]])))
case("a whole config as a list", edit(lambda d, f: (lambda copy_: (d.clear(), d.update(head=[copy_])))(dict(d))))
case("the token beside a bad port", edit(lambda d, f: d["api"].update(port="eighty")))


# --- the random configs ------------------------------------------------------------------------------
ODD_YAML = ["~", "yes", "on", "0x1F", "0o17", "1_000", "+.inf", ".nan", "1.0e+400", "2026-13-45", "2026-11-30",
            "!!binary aGVhZA==", "!!set {a, b}", "!!int x", "&a 1", "*undefined", "!!python/name:os.system",
            "'unterminated", "[", "{", "- x", "? [1, 2]", "|", "\"\\ud800\"", "\"\\x00\"", "\"\\e[2J\"", "@x", "%TAG"]


def random_value(rng: random.Random, depth: int = 0) -> Any:
    kind = rng.randrange(10 if depth < 3 else 8)
    if kind == 0:
        return rng.choice([None, True, False, 0, -1, 2**63, 10**30, 10**400, 1e300, -1e-300, 0.5])
    if kind == 1:
        return rng.randint(-2**70, 2**70)
    if kind == 2:
        return rng.uniform(-1e6, 1e6)
    if kind == 3:
        return "".join(chr(rng.randrange(1, 0x3000)) for _ in range(rng.randrange(12)))
    if kind == 4:
        return rng.choice(["sim", "dynamixel", "opencv", "collections:OrderedDict", "no_such_pkg:Cam", "/etc/passwd",
                           "/dev/zero", "/nonexistent/x", "~", "left", "right", TOKEN[:8]])
    if kind in (5, 6, 7):
        return Raw(rng.choice(ODD_YAML))
    if kind == 8:
        return [random_value(rng, depth + 1) for _ in range(rng.randrange(4))]
    return Map((random_value(rng, depth + 1) if rng.random() < 0.2 else rng.choice(["pan", "token", "x", "", "<<"]),
                random_value(rng, depth + 1)) for _ in range(rng.randrange(4)))


def places(node: Any, prefix: tuple = ()) -> list[tuple]:
    found = [prefix]
    items = [v for _, v in node] if isinstance(node, Map) else node if isinstance(node, list) else []
    for i, value in enumerate(items):
        found += places(value, prefix + (i,))
    return found


def random_config(rng: random.Random) -> bytes:
    data = base()
    root = tree(data)
    for _ in range(rng.randint(1, 3)):
        place = rng.choice(places(root)[1:])
        parent = root
        for i in place[:-1]:
            parent = parent[i][1] if isinstance(parent, Map) else parent[i]
        i = place[-1]
        op = rng.choice(["delete", "rename", "duplicate", "replace", "replace", "huge", "wrong type"])
        if isinstance(parent, Map):
            key, value = parent[i]
            if op == "delete":
                del parent[i]
            elif op == "rename" and key != "token":
                parent[i] = (random_value(rng, 2) if rng.random() < 0.3 else key + rng.choice(["s", "_", "X"]), value)
            elif op == "duplicate":
                parent.insert(rng.randrange(len(parent) + 1), (key, value if rng.random() < 0.5 else random_value(rng)))
            elif op == "huge":
                parent[i] = (key, rng.choice([10**400, 2**64, -2**64, 1e308, 10**39]))
            elif op == "wrong type":
                parent[i] = (key, rng.choice([[], Map(), "", "x", True, None, [[[]]], 1.5]))
            else:
                parent[i] = (key, random_value(rng))
        elif op == "delete":
            del parent[i]
        else:
            parent[i] = random_value(rng)
    content = emit(root).encode("utf-8", errors="surrogatepass")
    mangle = rng.randrange(12)
    if mangle == 0:
        return rng.randbytes(rng.randrange(300))
    if mangle == 1:
        at = rng.randrange(len(content) + 1)
        return content[:at] + rng.randbytes(rng.randint(1, 8)) + content[at:]
    if mangle == 2:
        return content[:rng.randrange(len(content) + 1)]
    return content


# --- trying one ------------------------------------------------------------------------------------
RUNTIME_KEYS = ("state_dir", "logging.file")  # what check_runtime refuses in a file load_config accepts


def located(err: ConfigError) -> bool:
    """The error names the file, and a key path (`""`: the top level) or a line and column, or
    the file as a whole cannot be read as text."""
    body = str(err)[len(f"{err.file}: "):] if err.file is not None else ""
    return err.file is not None and str(err).startswith(f"{err.file}: ") and (
        err.key_path is not None or bool(re.search(r"line \d+, column \d+", body))
        or body.startswith(("not UTF-8", "larger than", "cannot read")))


class NotStarted:
    """Stands in for the Daemon: `run` goes as far as starting the service, and no further."""

    reached = 0

    def __init__(self, config: Any, **composed: Any) -> None:
        NotStarted.reached += 1

    def run(self) -> int:
        return 0


def in_process(argv: list[str]) -> tuple[int | str, str]:
    """`headctl <argv>` here: its exit status (or the traceback) and all it printed or logged."""
    out, err = io.StringIO(), io.StringIO()
    logs = io.StringIO()
    handler = logging.StreamHandler(logs)
    root = logging.getLogger()
    before = list(root.handlers)
    root.addHandler(handler)
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            status: int | str = main(argv)
    except BaseException:  # noqa: BLE001 - what is counted: anything escaping the command
        status = "traceback: " + traceback.format_exc()
    finally:
        for extra in set(root.handlers) - set(before):  # the handler above, and run's log file
            root.removeHandler(extra)
            if extra is not handler:
                extra.close()
    return status, out.getvalue() + err.getvalue() + logs.getvalue()


def try_config(path: Path, valid: bool | None) -> dict[str, Any]:
    """`valid`: whether it must be accepted (None: either, for the random ones)."""
    result: dict[str, Any] = {"problems": []}
    error: ConfigError | None = None
    try:
        load_config(path)
        result["loaded"] = True
    except ConfigError as err:
        result["loaded"] = False
        error = err
        if not located(err):
            result["problems"].append(f"load_config: unlocated error: {err}")
        if TOKEN in str(err) or TOKEN in repr(err.args):
            result["problems"].append("load_config: token leaked")
    except BaseException:  # noqa: BLE001
        result["loaded"] = None
        result["problems"].append("load_config traceback: " + traceback.format_exc())
    reached = NotStarted.reached
    check, check_out = in_process(["check", "--no-connect", "--config", str(path)])
    run, run_out = in_process(["run", "--config", str(path)])
    started = NotStarted.reached > reached
    result.update(check=check, run=run, message=(check_out.strip().splitlines() or [""])[0])
    for name, status, output in (("check", check, check_out), ("run", run, run_out)):
        if isinstance(status, str):
            result["problems"].append(f"{name} {status}")
        if TOKEN in output:
            result["problems"].append(f"{name}: token leaked")
        if status == 2:
            # load_config's own error, or check_runtime's naming its key (the file loads).
            said = f"headctl {name}: {error}" if error is not None else None
            runtime = tuple(f"headctl {name}: {path}: {key}: got " for key in RUNTIME_KEYS)
            if not (output.startswith(said) if said is not None else output.startswith(runtime)):
                result["problems"].append(f"{name}: unlocated error: {output.strip()[:300]}")
    if (check, run) not in ((0, 0), (2, 2)) or started != (run == 0):
        result["problems"].append(f"check {check} / run {run}, service started: {started}")
    if result["loaded"] is False and check == 0:
        result["problems"].append("load_config refused it, check accepted it")
    if valid is not None and valid != (check == 0):
        result["problems"].append(f"expected {'accepted' if valid else 'refused'}: {result['message'][:300]}")
    result["located"] = check == 2 and run == 2 and not any("unlocated" in p for p in result["problems"])
    return result


def main_bench() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--random", type=int, default=1000, help="random configs besides the hand-made ones")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--max-seconds", type=float, default=300.0)
    parser.add_argument("--verbose", action="store_true", help="print each hand-made config's first message")
    args = parser.parse_args()
    headctl.service.daemon.Daemon = NotStarted  # type: ignore[misc,assignment]
    logging.disable(logging.CRITICAL)  # run's own logging setup must not reach the console
    logging.disable(logging.NOTSET)
    started = time.monotonic()
    tally: dict[str, Counter] = {"hand-made": Counter(), "random": Counter()}
    problems: list[str] = []
    rng = random.Random(args.seed)
    with tempfile.TemporaryDirectory(prefix="hostile-configs-") as scratch:
        folder = Path(scratch)
        jobs: list[tuple[str, str, Callable[[], bytes | Path], bool | None]] = [
            ("hand-made", name, (lambda make=make: make(folder)), name in VALID) for name, make in CASES.items()]
        jobs += [("random", f"random {n}", (lambda: random_config(rng)), None) for n in range(args.random)]
        for kind, name, make, valid in jobs:
            if time.monotonic() - started > args.max_seconds:
                tally[kind]["skipped (time)"] += 1
                continue
            content = make()
            path = content if isinstance(content, Path) else folder / "head.yaml"
            if not isinstance(content, Path):
                path.write_bytes(content)
            result = try_config(path, valid)
            counts = tally[kind]
            counts["tried"] += 1
            counts["accepted"] += result["check"] == 0 and result["run"] == 0
            counts["refused, located"] += result["located"]
            counts["tracebacks"] += any("traceback" in p for p in result["problems"])
            counts["unlocated"] += any("unlocated" in p for p in result["problems"])
            counts["check/run disagree"] += any(p.startswith("check ") and " / run " in p for p in result["problems"])
            counts["token leaks"] += any("leaked" in p for p in result["problems"])
            counts["with a problem"] += bool(result["problems"])
            problems += [f"{name}: {p}" for p in result["problems"]]
            if args.verbose and kind == "hand-made":
                print(f"{name:45s} {result['check']} {result['message'][:150]}")
    seconds = time.monotonic() - started
    columns = ["tried", "accepted", "refused, located", "tracebacks", "unlocated", "check/run disagree", "token leaks",
               "skipped (time)"]
    print(f"{'':10s}" + "".join(f"{c:>20s}" for c in columns))
    for kind, counts in tally.items():
        print(f"{kind:10s}" + "".join(f"{counts[c]:>20d}" for c in columns))
    print(f"{len(problems)} problems; {seconds:.1f} s")
    for problem in problems[:50]:
        print("  " + problem.replace("\n", "\n    "))
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main_bench())

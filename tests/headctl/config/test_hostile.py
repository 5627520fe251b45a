"""Broken configs, made by hand and generated: `load_config` and `headctl check` accept them or
refuse them with a located `ConfigError` (never another exception), the API token never shows,
and `check --no-connect` refuses exactly the configs `run` refuses.

The generated ones start from the valid configs/sim-ideal.yaml (with an API token added) and delete,
rename and duplicate keys, replace values with random YAML scalars, lists and mappings of
random depth, huge numbers and raw YAML oddities, and replace or splice in random bytes. The
file is written by a small emitter of flow-style YAML, which (unlike a YAML library) can write
a key twice.
"""
from __future__ import annotations

import contextlib
import io
import json
import logging
import re
from pathlib import Path
from typing import Any

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from benchmarks.support.yaml_text import Map, Raw, emit, tree
import headctl.service.daemon
from headctl.cli.main import main
from headctl.config.head import load_config
from headctl.errors import ConfigError
from tests.support import CONFIGS

TOKEN = "hostile-token-5f3a9c1e7b"  # in the api section of every generated config
BASE = yaml.safe_load((CONFIGS / "sim-ideal.yaml").read_text())


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    return tmp_path_factory.mktemp("hostile")




def base_tree() -> Map:
    data = json.loads(json.dumps(BASE))
    data["api"]["token"] = TOKEN
    return tree(data)


def paths(node: Any, prefix: tuple = ()) -> list[tuple]:
    """Every place in the tree: a tuple of indices into Maps (pair index) and lists."""
    found = [prefix]
    if isinstance(node, Map):
        for i, (_, value) in enumerate(node):
            found += paths(value, prefix + (i,))
    elif isinstance(node, list):
        for i, value in enumerate(node):
            found += paths(value, prefix + (i,))
    return found


def parent_of(root: Any, path: tuple) -> tuple[Any, int]:
    node = root
    for i in path[:-1]:
        node = node[i][1] if isinstance(node, Map) else node[i]
    return node, path[-1]


def key_at(root: Any, path: tuple) -> Any:
    parent, i = parent_of(root, path)
    return parent[i][0] if isinstance(parent, Map) else None


# --- what goes in ----------------------------------------------------------------------------------
ODD_YAML = ["~", "yes", "no", "on", "0x1F", "0o17", "1_000", "+.inf", ".nan", "1e400", "-1e400", "2026-13-45",
            "2026-11-30", "12:30:45", "!!binary aGVhZA==", "!!set {a, b}", "!!str 3", "!!int x", "!!float y",
            "&a 1", "*undefined", "<<: 3", "!!python/name:os.system", "'unterminated", "[", "{", "}", "- x",
            "? [1, 2]", "|", ">", "\"\\ud800\"", "\"\\x00\"", "\"\\u001b[2J\"", "@reserved", "`tick", "%TAG"]

scalars = st.one_of(
    st.none(), st.booleans(),
    st.integers(min_value=-2**70, max_value=2**70),
    st.sampled_from([0, -1, 1, 2**31, 2**63, -2**63 - 1, 10**30, 10**100]),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([1e300, -1e300, 1e-300, 0.5, 5e-324]),
    st.text(max_size=40),
    st.text(alphabet=st.characters(codec="utf-8"), max_size=10),
    st.sampled_from(["sim", "dynamixel", "opencv", "aravis", "collections:OrderedDict", "no_such_pkg:Cam",
                     "os:sep", "/etc/passwd", "/dev/zero", "/nonexistent/x", "~", "$NOPE/x", "..", "left", "right"]),
    st.sampled_from(ODD_YAML).map(Raw),
)
keys = st.one_of(st.text(max_size=20), st.integers(-5, 5), st.sampled_from(["", "api", "token", "pan", "<<"]))
values = st.recursive(scalars, lambda inner: st.one_of(st.lists(inner, max_size=4),
                                                        st.lists(st.tuples(keys, inner), max_size=4).map(Map)),
                      max_leaves=12)


@st.composite
def broken_configs(draw: st.DrawFn) -> bytes:
    root = base_tree()
    for _ in range(draw(st.integers(1, 3))):
        places = paths(root)[1:]
        place = draw(st.sampled_from(places))
        parent, i = parent_of(root, place)
        op = draw(st.sampled_from(["delete", "rename", "duplicate", "replace", "replace", "huge", "wrong type"]))
        if isinstance(parent, Map):
            key, value = parent[i]
            if op == "delete":
                del parent[i]
            elif op == "rename" and key != "token":  # a renamed token is a plain value: not tested for hiding
                parent[i] = (draw(keys), value)
            elif op == "duplicate":
                parent.insert(draw(st.integers(0, len(parent))), (key, draw(st.one_of(st.just(value), values))))
            elif op == "huge":
                parent[i] = (key, draw(st.sampled_from([10**400, 2**64, -2**64, 1e308, 10**39])))
            elif op == "wrong type":
                parent[i] = (key, draw(st.sampled_from([[], Map(), "", "x", True, None, [[[]]], 1.5])))
            else:
                parent[i] = (key, draw(values))
        else:
            if op == "delete":
                del parent[i]
            elif op == "duplicate":
                parent.insert(i, parent[i])
            else:
                parent[i] = draw(values)
    text = emit(root).encode("utf-8", errors="surrogatepass")
    mangle = draw(st.sampled_from(["none"] * 8 + ["bytes", "splice", "truncate"]))
    if mangle == "bytes":
        return draw(st.binary(max_size=200))
    if mangle == "splice":
        at = draw(st.integers(0, len(text)))
        return text[:at] + draw(st.binary(min_size=1, max_size=8)) + text[at:]
    if mangle == "truncate":
        return text[:draw(st.integers(0, len(text)))]
    return text


# --- what must hold ----------------------------------------------------------------------------------
def located(err: ConfigError, path: Path) -> bool:
    """The error names the file, and a key path (`""`: the top level) or the line and column
    where the file is wrong, or says the file as a whole is not UTF-8 text."""
    body = str(err).removeprefix(f"{path}: ")
    return err.file == path and str(err).startswith(f"{path}: ") and (
        err.key_path is not None or bool(re.search(r"line \d+, column \d+", body)) or body.startswith("not UTF-8"))


class Records(logging.Handler):
    def __init__(self) -> None:
        super().__init__(logging.DEBUG)
        self.lines: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.lines.append(self.format(record))


def check_in_process(argv: list[str]) -> tuple[int, str]:
    """`headctl <argv>` in this process: its exit status and everything it printed or logged."""
    out, err, records = io.StringIO(), io.StringIO(), Records()
    root = logging.getLogger()
    root.addHandler(records)
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            status = main(argv)
    finally:
        root.removeHandler(records)
    return status, out.getvalue() + err.getvalue() + "\n".join(records.lines)


@settings(max_examples=300, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(content=broken_configs())
def test_a_broken_config_is_accepted_or_refused_with_a_located_error_and_the_token_never_shows(folder, content):
    path = folder / "head.yaml"
    path.write_bytes(content)
    error: ConfigError | None = None
    try:
        load_config(path)
    except ConfigError as err:
        error = err
        assert located(err, path), str(err)
        assert TOKEN not in str(err) and TOKEN not in repr(err.args)
    status, output = check_in_process(["check", "--no-connect", "--config", str(path),
                                       "--state-dir", str(folder / "state")])
    assert TOKEN not in output
    if error is not None:
        assert status == 2 and output.startswith(f"headctl check: {error}\n"), output
    elif status != 0:  # the file is fine, what it names on this machine is not (check_runtime)
        assert status == 2 and output.startswith(f"headctl check: {path}: logging.file: got "), output


# --- check and run agree ---------------------------------------------------------------------------
def _sim() -> dict:
    return json.loads(json.dumps(BASE))


def _edited(edit):
    def make(folder: Path) -> bytes:
        data = _sim()
        edit(data, folder)
        return yaml.safe_dump(data).encode()
    return make


def _on_dynamixel(data: dict) -> dict:
    """The simulated head's config on the dynamixel backend with two USB cameras."""
    data["servo_bus"].update(backend="dynamixel", port="/dev/null")
    for side in ("left", "right"):
        camera = data["cameras"][side]
        for key in ("eye", "lens", "seed", "noise_std"):
            camera.pop(key)
        camera.update(backend="opencv", device=0)
    return data


def _text(replace):
    return lambda folder: replace((CONFIGS / "sim-ideal.yaml").read_text()).encode()


HOSTILE = {
    "valid": _edited(lambda d, f: None),
    "camera backend unknown": _edited(lambda d, f: d["cameras"]["left"].update(backend="nosuch")),
    "camera backend does not import": _edited(lambda d, f: d["cameras"]["left"].update(backend="no_such_pkg:Cam")),
    "camera backend of the wrong kind": _edited(
        lambda d, f: d["cameras"]["left"].update(backend="collections:OrderedDict")),
    "servo backend of the wrong kind": _edited(lambda d, f: d["servo_bus"].update(backend="collections:OrderedDict")),
    "unknown servo model on dynamixel": _edited(
        lambda d, f: _on_dynamixel(d)["servo_bus"]["joints"]["pan"].update(model="AX-12A")),
    "a key the sim servo backend does not use": _edited(lambda d, f: d["servo_bus"].update(protocol=1.0)),
    "a key the sim camera backend does not use": _edited(lambda d, f: d["cameras"]["left"].update(serial="X")),
    "not UTF-8": lambda folder: b"\x80\x81",
    "UTF-16": lambda folder: (CONFIGS / "sim-ideal.yaml").read_text().encode("utf-16"),
    "5000-deep nesting": lambda folder: b"servo_bus: " + b"[" * 5000 + b"]" * 5000,
    "camera width 1e9": _edited(lambda d, f: [d["cameras"][s].update(width=10**9) for s in ("left", "right")]),
    "duplicate key": _text(lambda t: t.replace("state_dir:", "state_dir: /tmp\nstate_dir:")),
    "duplicate joint": _text(lambda t: t.replace("    tilt:", "    pan:       {id: 2, min_angle: -5, max_angle: 5}\n"
                                                         "    tilt:", 1)),
    "gaze_map.seed -1": _edited(lambda d, f: d["gaze_map"].update(seed=-1)),
    "grid 1e5 x 1e5 x 1e3": _edited(lambda d, f: d["gaze_map"].update(grid_shape=[100000, 100000, 1000])),
    "logging.file in a missing directory": _edited(lambda d, f: d["logging"].update(file="/nonexistent/x")),
    "vergence_range [-100, 100]": _edited(lambda d, f: d["fixation"].update(vergence_range=[-100, 100])),
    "settle_timeout_s -1": _edited(lambda d, f: d["fixation"].update(settle_timeout_s=-1)),
    "state_dir is a file": _edited(lambda d, f: d.update(state_dir="/etc/passwd")),
    "state_dir under a file": _edited(lambda d, f: d.update(state_dir="/etc/passwd/state")),
    "state_dir cannot be created": _edited(lambda d, f: d.update(state_dir="/proc/headctl/state")),
    "token too short": _edited(lambda d, f: d["api"].update(token="short")),
    "token file missing": _edited(lambda d, f: d["api"].update(token_file=str(f / "no-token"))),
    "a valid log file": _edited(lambda d, f: d["logging"].update(file=str(f / "head.log"))),
}


@pytest.mark.parametrize("name", sorted(HOSTILE))
def test_check_no_connect_and_run_refuse_the_same_configs(tmp_path, monkeypatch, name):
    path = tmp_path / "head.yaml"
    path.write_bytes(HOSTILE[name](tmp_path))
    started: list[Any] = []

    class NotStarted:  # `run` goes as far as starting the service, and no further
        def __init__(self, config: Any, **composed: Any) -> None:
            started.append(config)

        def run(self) -> int:
            return 0

    monkeypatch.setattr(headctl.service.daemon, "Daemon", NotStarted)
    handlers = list(logging.getLogger().handlers)
    try:
        check, check_output = check_in_process(["check", "--no-connect", "--config", str(path)])
        run, run_output = check_in_process(["run", "--config", str(path)])
    finally:
        for handler in set(logging.getLogger().handlers) - set(handlers):  # run's log file
            logging.getLogger().removeHandler(handler)
            handler.close()
    assert (check, run) == ((0, 0) if name.startswith(("valid", "a valid")) else (2, 2)), check_output + run_output
    assert bool(started) == (run == 0)
    if check == 2:
        assert f"headctl check: {path}: " in check_output and f"headctl run: {path}: " in run_output
        assert check_output.replace("headctl check", "headctl run") == run_output
    assert TOKEN not in check_output + run_output

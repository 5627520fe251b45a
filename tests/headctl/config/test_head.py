"""The head's YAML config (headctl.config.head) and `headctl check`."""
from __future__ import annotations

import subprocess
import sys

import pytest
import yaml

from calib_free.gaze.fixation import FixationParams
from headctl.cli.main import main
from headctl.config.head import DEFAULT_CONFIG, check_runtime, load_config
from headctl.errors import ConfigError
from tests.support import CONFIGS, TLS

EXAMPLES = ["sim.yaml", "sim-ideal.yaml", "xm430-u2d2-aravis.yaml", "usb-webcams.yaml"]



def _write(tmp_path, data, name="head.yaml"):
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data))
    return path


def _sim():
    """The kind simulated head's config: no simulation-only sections, so its edits into real
    heads' configs stay short."""
    return yaml.safe_load((CONFIGS / "sim-ideal.yaml").read_text())


@pytest.mark.parametrize("name", EXAMPLES)
def test_every_example_config_parses_into_typed_objects(name):
    config = load_config(CONFIGS / name)
    assert set(config.servo_bus.joints) == {"pan", "tilt", "left_eye", "right_eye"}
    assert isinstance(config.fixation.params, FixationParams)
    assert config.map_params().image_size == config.image_size
    assert config.service.servo_rate_hz == 100.0
    assert config.state_dir.is_absolute()


def test_the_default_config_is_the_simulated_head():
    config = load_config()
    assert config.path == DEFAULT_CONFIG and config.simulated
    assert config.cameras.left.backend == config.cameras.right.backend == "sim"
    assert config.fixation.explore and config.fixation.vergence_range == (-3.0, 20.0)  # the cameras' centres may differ by 2 deg


def test_the_default_config_is_package_data_found_from_any_directory(tmp_path):
    assert DEFAULT_CONFIG.parent.parent.name == "headctl" and DEFAULT_CONFIG.is_file()
    assert (CONFIGS / "sim.yaml").resolve() == DEFAULT_CONFIG.resolve()  # configs/ links to the package's
    done = subprocess.run([sys.executable, "-m", "headctl", "check", "--no-connect"], cwd=tmp_path,
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert f"{DEFAULT_CONFIG}: valid" in done.stdout


def test_fixation_and_map_keys_reach_their_parameters(tmp_path):
    data = _sim()
    data["fixation"].update(vergence_tolerance_px=0.5, exploration_step_deg=[10, 5, 4], rate_hz=2,
                            correspondence={"patch_size": [16, 16]}, explore=False)
    data["gaze_map"].update(profile="paper", grid_shape=[50, 40, 11], adaptation_rate=0.4,
                            command_range=[[-40, 40], [-30, 30], [-15, 15]])
    data["service"].update(checkpoint_every=7, safe_state="torque_off")
    config = load_config(_write(tmp_path, data))
    assert config.fixation.params.vergence_tolerance_px == 0.5
    assert config.fixation.params.exploration_step_deg == (10.0, 5.0, 4.0)
    assert config.fixation.params.correspondence.patch_size == (16, 16)
    assert (config.fixation.explore, config.fixation.rate_hz) == (False, 2.0)
    params = config.map_params()
    assert (params.profile, params.grid_shape, params.adaptation_rate) == ("paper", (50, 40, 11), 0.4)
    assert params.command_range == ((-40.0, 40.0), (-30.0, 30.0), (-15.0, 15.0))
    assert not params.interpolate  # the paper profile's values, then the overrides
    assert (config.service.checkpoint_every, config.service.safe_state) == (7, "torque_off")


def test_a_relative_state_dir_is_relative_to_the_config_file(tmp_path):
    data = _sim()
    data["state_dir"] = "state"
    assert load_config(_write(tmp_path, data)).state_dir == tmp_path.resolve() / "state"


@pytest.mark.parametrize("edit, message", [
    (lambda d: d.update(colour=True), (": colour: got True, expected a known key (the top level takes servo_bus, "
                                       "cameras, gaze_map, fixation, service, state_dir, logging, api, tracking, ros2, foxglove, sim_objects); "
                                       "'colour' is an unknown key")),
    (lambda d: d["fixation"].update(rate=3), "fixation.rate: got 3, expected a known key (fixation takes vergence_"),
    (lambda d: d["fixation"].update(rate=3), "rate_hz, vergence_range); 'rate' is an unknown key"),
    (lambda d: d["fixation"].update(rate_hz="fast"), "fixation.rate_hz: got 'fast', expected a number"),
    (lambda d: d["fixation"].update(exploration_step_deg=[1, 2]),
     "fixation.exploration_step_deg: got [1, 2], expected a list of 3 (a number, a number, a number)"),
    (lambda d: d["fixation"].update(confidence_floor=2.0), "fixation.confidence_floor: got 2.0, expected in [0, 1]"),
    (lambda d: d["fixation"].update(correspondence={"patch_size": [2, 2]}),
     "fixation.correspondence.patch_size: got (2, 2), expected at least 3 x 3 pixels"),
    (lambda d: d["fixation"].update(vergence_range=[5, 1]),
     "fixation.vergence_range: got (5.0, 1.0), expected [low, high] with low < high (deg)"),
    (lambda d: d["fixation"]["correspondence"] if False else d["fixation"].update(correspondence={"patch": 3}),
     "fixation.correspondence.patch: got 3, expected a known key (fixation.correspondence takes patch_size, "),
    (lambda d: d["gaze_map"].update(profile="fast"), "gaze_map.profile: got 'fast', expected default or paper"),
    (lambda d: d["gaze_map"].update(grid_shape=[10, 10]), "gaze_map.grid_shape: got [10, 10], expected a list of 3"),
    (lambda d: d["gaze_map"].update(image_size=[10, 10]), "gaze_map.image_size: got [10, 10], expected a known key"),
    (lambda d: d["gaze_map"].update(adaptation_rate=2), "gaze_map.adaptation_rate: got 2.0, expected in (0, 1]"),
    (lambda d: d["gaze_map"].update(seed=True), "gaze_map.seed: got True, expected an integer"),
    (lambda d: d["service"].update(servo_rate_hz=5000),
     "service.servo_rate_hz: got 5000.0, expected a rate in [1, 1000] Hz"),
    (lambda d: d["service"].update(safe_state="limp"), "safe_state: got 'limp', expected hold or torque_off"),
    (lambda d: d["logging"].update(level="LOUD"), "logging.level: got 'LOUD', expected DEBUG or INFO"),
    (lambda d: d["servo_bus"]["joints"]["pan"].update(idd=3), "servo_bus.joints.pan.idd: got 3, expected a known key"),
    (lambda d: d["servo_bus"].update(baud=12), "servo_bus.baud: got 12, expected one of"),
    (lambda d: d["cameras"]["left"].update(fps="fast"), "cameras.left.fps: got 'fast', expected a number"),
    (lambda d: d["cameras"]["left"].pop("width"), "cameras.left.width: got None, expected the image size"),
    (lambda d: d["cameras"]["right"].update(seed=3), "cameras.right.seed: got 3, expected 0 like cameras.left"),
    (lambda d: d["servo_bus"].update(backend="dynamixel"),
     "cameras.left.backend: got 'sim', expected a real camera backend"),
    (lambda d: d.pop("cameras"), "cameras: missing, expected a mapping with keys left, right, tolerance_s"),
    (lambda d: d.update(state_dir=3), "state_dir: got 3, expected a path (a non-empty string)"),
    (lambda d: d["cameras"]["right"].update(width=640, height=480),
     "cameras.right.width: got (640, 480), expected the left camera's size 320 x 240"),
    (lambda d: d["cameras"]["right"].update(backend="opencv", device=0),
     "cameras.right.backend: got 'opencv', expected sim: both eyes of the simulated head are simulated, or neither"),
])
def test_errors_name_the_file_the_key_path_the_value_and_what_was_expected(tmp_path, edit, message):
    data = _sim()
    edit(data)
    path = _write(tmp_path, data)
    with pytest.raises(ConfigError) as err:
        load_config(path)
    assert str(err.value).startswith(f"{path}: ")
    assert message in str(err.value)


def test_unreadable_and_invalid_yaml_name_the_file(tmp_path):
    with pytest.raises(ConfigError, match="missing.yaml: cannot read"):
        load_config(tmp_path / "missing.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("servo_bus: [\n")
    with pytest.raises(ConfigError, match="bad.yaml: not valid YAML"):
        load_config(bad)


def test_check_validates_connects_and_reports_each_servo_and_camera(capsys):
    assert main(["check"]) == 0
    out = capsys.readouterr().out
    assert "configs/sim.yaml: valid" in out
    for joint, servo_id in (("pan", 1), ("tilt", 2), ("left_eye", 3), ("right_eye", 4)):
        assert f"joint {joint} (id {servo_id})" in out
    assert "camera left (sim left): 320 x 240" in out and "camera right (sim right): 320 x 240" in out
    assert out.rstrip().endswith("check: OK")


def test_check_reports_a_missing_servo_adapter(tmp_path, capsys):
    path = CONFIGS / "usb-webcams.yaml"
    data = yaml.safe_load(path.read_text())
    data["servo_bus"]["port"] = str(tmp_path / "no-such-adapter")
    assert main(["check", "--config", str(_write(tmp_path, data))]) == 1
    out = capsys.readouterr().out
    assert "servo bus: FAILED" in out and "no-such-adapter" in out


def test_check_refuses_an_invalid_file_with_exit_2(tmp_path, capsys):
    data = _sim()
    data["fixation"]["rate_hz"] = -1
    path = _write(tmp_path, data)
    assert main(["check", "--config", str(path), "--no-connect"]) == 2
    assert f"{path}: fixation.rate_hz: got -1.0, expected a rate >= 0" in capsys.readouterr().err


# --- api ------------------------------------------------------------------------------------------
def test_the_api_defaults_to_loopback_without_a_token():
    api = load_config().api
    assert api.enabled and api.host == "127.0.0.1" and api.token is None
    assert api.url == f"http://127.0.0.1:{api.port}"


@pytest.mark.parametrize("api, words", [
    ({"host": "0.0.0.0"}, "api.token: got None, expected a token (api.token or api.token_file): api.host '0.0.0.0'"),
    ({"host": "192.0.2.7", "port": 80}, "api.host '192.0.2.7' is not a loopback address"),
    ({"port": 70000}, "api.port: got 70000, expected a TCP port, 0 for an ephemeral one"),
    ({"token": "short"}, "api.token: got <hidden>, expected at least 16 characters"),
    ({"token": 12345678901234567890}, "api.token: got <hidden>, expected a non-empty string"),
    ({"token": "x" * 20, "token_file": "t"}, "api.token_file: got 't', expected either api.token or api.token_file"),
    ({"token_file": "missing-token"}, "api.token_file: got 'missing-token', expected a readable file"),
    ({"stream_fps": 500}, "stream_fps"),
    ({"bogus": 1}, "api.bogus"),
    ({"tls_cert": "{tls}/head-cert.pem"}, "api.tls_key: got None, expected both api.tls_cert and api.tls_key"),
    ({"tls_key": "{tls}/head-key.pem"}, "api.tls_cert: got None, expected both"),
    ({"tls_cert": "{tls}/nowhere.pem", "tls_key": "{tls}/head-key.pem"},
     "api.tls_cert: got '{tls}/nowhere.pem', expected a readable PEM file"),
    ({"tls_cert": "{tls}/head-cert.pem", "tls_key": "{tls}/other-key.pem"},
     "api.tls_key: got '{tls}/other-key.pem', expected the PEM private key of the certificate in api.tls_cert"),
    ({"tls_cert": "{tls}/README.md", "tls_key": "{tls}/head-key.pem"},
     "api.tls_cert: got '{tls}/README.md', expected a PEM certificate"),
])
def test_bad_api_settings_name_the_key(tmp_path, api, words):
    data = _sim()
    data["api"] = {key: value.replace("{tls}", str(TLS)) if isinstance(value, str) else value
                   for key, value in api.items()}
    with pytest.raises(ConfigError) as err:
        load_config(_write(tmp_path, data))
    assert words.replace("{tls}", str(TLS)) in str(err.value)


def test_tls_files_beside_the_config_make_the_url_https(tmp_path):
    for name in ("head-cert.pem", "head-key.pem"):
        (tmp_path / name).write_bytes((TLS / name).read_bytes())
    data = _sim()
    data["api"] = {"tls_cert": "head-cert.pem", "tls_key": "head-key.pem", "port": 9443}
    api = load_config(_write(tmp_path, data)).api
    assert (api.tls_cert, api.tls_key) == (str(tmp_path / "head-cert.pem"), str(tmp_path / "head-key.pem"))
    assert api.url == "https://127.0.0.1:9443"


def test_a_token_file_beside_the_config_allows_any_address(tmp_path):
    (tmp_path / "api-token").write_text("  0123456789abcdef0123  \n")
    data = _sim()
    data["api"] = {"host": "0.0.0.0", "token_file": "api-token"}
    api = load_config(_write(tmp_path, data)).api
    assert api.token == "0123456789abcdef0123" and api.token_file == str(tmp_path / "api-token")
    assert "0123456789abcdef" not in repr(api)  # never in a log line


# --- refused when loaded, not when built: backends, resources, physical sense ---------------------
def _dynamixel(data):
    """The simulated head's config on the dynamixel backend with two USB cameras."""
    data["servo_bus"].update(backend="dynamixel", port="/dev/null")
    for side in ("left", "right"):
        camera = data["cameras"][side]
        for key in ("eye", "lens", "seed", "noise_std"):
            camera.pop(key)
        camera.update(backend="opencv", device=0)
    return data


@pytest.mark.parametrize("edit, message", [
    (lambda d: d["cameras"]["left"].update(backend="nosuch"),
     "cameras.left.backend: got 'nosuch', expected one of aravis, opencv, sim, a name registered under the "
     "entry-point group headctl.cameras, or 'package.module:Class'"),
    (lambda d: d["cameras"]["left"].update(backend="no_such_pkg:Cam"),
     "cameras.left.backend: got 'no_such_pkg:Cam', expected a camera backend that imports (camera backend "
     "'no_such_pkg:Cam' failed to import no_such_pkg: No module named 'no_such_pkg')"),
    (lambda d: d["cameras"]["left"].update(backend="collections:OrderedDict"),
     "cameras.left.backend: got 'collections:OrderedDict', expected a Camera backend class "
     "('collections:OrderedDict' is the class collections.OrderedDict, not a Camera)"),
    (lambda d: d["cameras"]["right"].update(backend="os:sep"), "cameras.right.backend: got 'os:sep', expected a "
                                                               "Camera backend class ('os:sep' is a str, not a Camera)"),
    (lambda d: d["cameras"]["left"].update(backend="..x:Y"), "cameras.left.backend: got '..x:Y', expected a "
                                                             "'package.module:Class' that exists"),
    (lambda d: d["servo_bus"].update(backend="collections:OrderedDict"),
     "servo_bus.backend: got 'collections:OrderedDict', expected a ServoBus backend class"),
    (lambda d: d["servo_bus"].update(backend="drivers.servo.bus:ServoBus"),
     "servo_bus.backend: got 'drivers.servo.bus:ServoBus', expected a ServoBus backend class that can be built "
     "(ServoBus is abstract: "),
    (lambda d: d["servo_bus"].update(backend="canbus"), "servo_bus.backend: got 'canbus', expected one of dynamixel, "
                                                        "sim, a name registered under the entry-point group "
                                                        "headctl.servo_buses"),
    (lambda d: [d["cameras"][s].update(backend="drivers.sim.camera:SimulatedCamera") for s in ("left", "right")],
     "cameras.left.backend: got 'drivers.sim.camera:SimulatedCamera', expected sim: SimulatedCamera is the "
     "simulated camera, named sim"),
    (lambda d: d["servo_bus"].update(reboot_timeout_s=5), "servo_bus.reboot_timeout_s: got 5.0, expected nothing: "
                                                          "reboot_timeout_s is not used by the 'sim' backend, which uses "
                                                          "backend, baud, joints, latency_timer_ms, limit_policy, "
                                                          "mechanics, port, power_loss_torque, reboot_on_hardware_error, "
                                                          "return_delay_us, torque_on_close, watchdog_ms, wiring"),
    (lambda d: d["servo_bus"].update(retries=2), "servo_bus.retries: got 2, expected nothing: retries is not used"),
    (lambda d: d["servo_bus"]["joints"]["tilt"].update(model="XM430-W350"),
     "servo_bus.joints.tilt.model: got 'XM430-W350', expected nothing: model is not used by the 'sim' backend"),
    (lambda d: _dynamixel(d)["servo_bus"]["joints"]["pan"].update(model="AX-12A"),
     "servo_bus.joints.pan.model: got 'AX-12A', expected one of XL430-W250, XM430-W350, XM540-W150, XM540-W270 "
     "(the models the 'dynamixel' backend drives)"),
    (lambda d: _dynamixel(d)["cameras"]["left"].update(seed=0),
     "cameras.left.seed: got 0, expected nothing: seed is not used by the 'opencv' backend"),
    (lambda d: d["cameras"]["left"].pop("eye"),
     "cameras.left.eye: missing, expected left or right: which eye of the simulated head the camera is"),
    (lambda d: d["cameras"]["left"].update(eye="right"), "cameras.left.eye: got 'right', expected 'left'"),
])
def test_backends_are_resolved_and_checked_when_the_config_loads(tmp_path, edit, message):
    data = _sim()
    edit(data)
    path = _write(tmp_path, data)
    with pytest.raises(ConfigError) as err:
        load_config(path)
    assert str(err.value).startswith(f"{path}: ") and message in str(err.value)


def test_a_backend_named_in_full_is_the_same_backend(tmp_path):
    data = _sim()
    data["servo_bus"]["backend"] = "drivers.sim.servos:SimulatedServoBus"
    with pytest.raises(ConfigError, match="simulated cameras render the simulated head"):
        load_config(_write(tmp_path, data))  # the simulated cameras need it by its name, sim
    data = _dynamixel(_sim())
    data["servo_bus"]["backend"] = "drivers.dynamixel.bus_v2:DynamixelBus"
    assert load_config(_write(tmp_path, data)).servo_bus.backend == "drivers.dynamixel.bus_v2:DynamixelBus"


def _both(key, value):
    return lambda d: [d["cameras"][side].update({key: value}) for side in ("left", "right")]


@pytest.mark.parametrize("edit, message", [
    (_both("width", 1_000_000_000), "cameras.left.width: got 1000000000, expected at most 16384 pixels"),
    (lambda d: (_both("width", 8192)(d), _both("height", 8192)(d)),
     "cameras.left.height: got 8192, expected an image of at most 16777216 pixels (4096 x 4096); 8192 x 8192 is "
     "67108864"),
    (lambda d: (_both("width", 4096)(d), _both("height", 4096)(d), _both("history", 32)(d)),
     "cameras.left.history: got 32, expected history + buffers (32 + 8) of at most 21 frames of 4096 x 4096"),
    (_both("history", 10**6), "cameras.left.history: got 1000000, expected at least 2 frames, at most 64"),
    (_both("fps", 0), "cameras.left.fps: got 0.0, expected a positive rate, from 0.01 to 10000 frames a second"),
    (_both("seed", -1), "cameras.left.seed: got -1, expected a seed >= 0"),
    (_both("grab_timeout_s", 1e300), "cameras.left.grab_timeout_s: got 1e+300, expected a positive time, at most 60"),
    (lambda d: d["cameras"].update(tolerance_s=1e9), "cameras.tolerance_s: got 1000000000.0, expected at most 10 s"),
    (lambda d: d["gaze_map"].update(grid_shape=[100000, 100000, 1000]),
     "gaze_map.grid_shape: got (100000, 100000, 1000), expected [nx, ny, nd], 2 to 1024 nodes each"),
    (lambda d: d["gaze_map"].update(grid_shape=[1000, 1000, 1000]),
     "gaze_map.grid_shape: got (1000, 1000, 1000), expected at most 4194304 nodes in all (1000000000 asked)"),
    (lambda d: d["gaze_map"].update(global_degree=1000), "gaze_map.global_degree: got 1000, expected an integer in "
                                                         "[0, 8]"),
    (lambda d: d["gaze_map"].update(error_window=10**9), "gaze_map.error_window: got 1000000000, expected an integer "
                                                         "in [1, 10000]"),
    (lambda d: d["gaze_map"].update(gaussian_cutoff=0), "gaze_map.gaussian_cutoff: got 0.0, expected a number in "
                                                        "(0, 1)"),
    (lambda d: d["gaze_map"].update(global_memory=0.5), "gaze_map.global_memory: got 0.5, expected a number in "
                                                        "[1, 1e+06]"),
    (lambda d: d["gaze_map"].update(seed=-1), "gaze_map.seed: got -1, expected a seed >= 0"),
    (lambda d: d["gaze_map"].update(seed=2**64), "gaze_map.seed: got 18446744073709551616, expected an integer "
                                                 "within +-2**63"),
    (lambda d: d["fixation"].update(vergence_range=[-100, 100]),
     "fixation.vergence_range: got (-100.0, 100.0), expected [low, high] within [-30, 30] deg, the vergence the eye "
     "joints' limits allow"),
    (lambda d: [d["servo_bus"]["joints"][j].update(min_angle=10, max_angle=20) for j in ("left_eye", "right_eye")],
     "servo_bus.joints.right_eye: got (10.0, 20.0), expected limits that with left_eye's (10, 20) allow some "
     "vergence"),
    (lambda d: d["fixation"].update(settle_timeout_s=-1), "fixation.settle_timeout_s: got -1.0, expected a positive "
                                                          "time, at most 60 s"),
    (lambda d: d["fixation"].update(frame_timeout_s=1e300), "fixation.frame_timeout_s: got 1e+300, expected a "
                                                            "positive time, at most 60 s"),
    (lambda d: d["fixation"].update(max_vergence_steps=10**9), "fixation.max_vergence_steps: got 1000000000, "
                                                               "expected an integer in [0, 100]"),
    (lambda d: d["fixation"].update(vergence_patch_size=[400, 20]),
     "fixation.vergence_patch_size: got (400, 20), expected a patch within the 320 x 240 image"),
    (lambda d: d["fixation"].update(correspondence={"pyramid_levels": 64}),
     "fixation.correspondence.pyramid_levels: got 64, expected an integer in [0, 8]"),
    (lambda d: d["fixation"].update(correspondence={"alignment_warp": "projective"}),
     "fixation.correspondence.alignment_warp: got 'projective', expected affine or quadratic"),
    (lambda d: d["fixation"].update(rate_hz=1e9), "fixation.rate_hz: got 1000000000.0, expected a rate >= 0"),
    (lambda d: d["service"].update(input_timeout_s=1e300), "service.input_timeout_s: got 1e+300, expected a positive "
                                                           "time, at most 60 s"),
    (lambda d: d["service"].update(checkpoint_every=10**30), "service.checkpoint_every: got "
                                                             "1000000000000000000000000000000, expected an integer "
                                                             "within +-2**63"),
    (lambda d: d["service"].update(camera_stall_s=1e9), "service.camera_stall_s: got 1000000000.0, expected a "
                                                        "positive time, at most 3600 s"),
    (lambda d: d["api"].update(host="not a host"), "api.host: got 'not a host', expected an IP address or a host "
                                                   "name"),
    (lambda d: d["servo_bus"].update(port="a\0b"), "servo_bus.port: got 'a\\x00b', expected a non-empty string of "
                                                   "text (no NUL character, no lone surrogate)"),
])
def test_allocations_waits_and_physical_ranges_are_bounded_when_the_config_loads(tmp_path, edit, message):
    data = _sim()
    edit(data)
    path = _write(tmp_path, data)
    with pytest.raises(ConfigError) as err:
        load_config(path)
    assert str(err.value).startswith(f"{path}: ") and message in str(err.value)


def test_duplicate_keys_and_broken_files_are_refused_where_they_are(tmp_path):
    text = (CONFIGS / "sim-ideal.yaml").read_text()
    path = tmp_path / "head.yaml"
    path.write_text(text.replace("    tilt:", "    pan:       {id: 9, min_angle: -5, max_angle: 5}\n    tilt:", 1))
    first = next(n for n, line in enumerate(text.splitlines(), 1) if line.startswith("    pan:"))
    with pytest.raises(ConfigError, match=rf"head\.yaml: servo_bus\.joints\.pan: got a second 'pan' key at line {first + 1}, "
                                          rf"column 5 \(the first is at line {first}, column 5\)"):
        load_config(path)
    path.write_bytes(b"\x80\x81")
    with pytest.raises(ConfigError, match=r"head\.yaml: not UTF-8: byte 0x80 at line 1, column 1"):
        load_config(path)
    path.write_text(text, encoding="utf-16")
    with pytest.raises(ConfigError, match=r"head\.yaml: not UTF-8: UTF-16 text"):
        load_config(path)
    path.write_text("servo_bus: " + "[" * 5000 + "]" * 5000)
    with pytest.raises(ConfigError, match=r"head\.yaml: .*(nested deeper than 32|nesting depth).* at line 1, col"):
        load_config(path)


SECRET = "hostile-secret-0123456789"


@pytest.mark.parametrize("api", [
    {"token": SECRET, "bogus": 1},
    {"tokn": SECRET},
    {"token": SECRET, "port": "x"},
    {"token": [SECRET]},
    {"token": {"nested": SECRET}},
    {"token": SECRET + "\n"},
    {"token": SECRET, "token_file": "also"},
])
def test_the_token_is_never_shown_whatever_is_wrong(tmp_path, api):
    data = _sim()
    data["api"] = api
    with pytest.raises(ConfigError) as err:
        load_config(_write(tmp_path, data))
    assert SECRET not in str(err.value) and SECRET not in repr(err.value)


@pytest.mark.parametrize("section", [lambda d: d.update(api=[{"token": SECRET}]),
                                     lambda d: d.update(apix={"token": SECRET}),
                                     lambda d: d.update(api={"host": "0.0.0.0", "tokens": [{"token": SECRET}]})])
def test_the_token_is_hidden_where_a_whole_section_is_shown(tmp_path, section):
    data = _sim()
    section(data)
    with pytest.raises(ConfigError) as err:
        load_config(_write(tmp_path, data))
    assert SECRET not in str(err.value) and "<hidden>" in str(err.value)


@pytest.mark.parametrize("content, words", [
    (b"\xff\xfe" + SECRET.encode("utf-16-le"), "it is not UTF-8 text"),
    ((SECRET + "\n") * 300, "it holds more than 4096 bytes"),
    ("short", "a token of at least 16 characters"),
    (SECRET + "\x1b[2J", "a token of at least 16 characters, printable"),
])
def test_the_token_file_is_read_bounded_and_its_content_never_shown(tmp_path, content, words):
    token_file = tmp_path / "api-token"
    token_file.write_bytes(content.encode() if isinstance(content, str) else content)
    data = _sim()
    data["api"] = {"token_file": "api-token"}
    with pytest.raises(ConfigError) as err:
        load_config(_write(tmp_path, data))
    assert "api.token_file: got 'api-token', expected a" in str(err.value) and words in str(err.value)
    assert SECRET not in str(err.value) and "\x1b" not in str(err.value)


@pytest.mark.parametrize("token_file, words", [("/dev/zero", "/dev/zero is not a regular file"),
                                               (".", "is not a regular file")])
def test_a_token_file_that_is_not_a_file_is_refused_unread(tmp_path, token_file, words):
    data = _sim()
    data["api"] = {"token_file": token_file}
    with pytest.raises(ConfigError, match=words):
        load_config(_write(tmp_path, data))


def test_a_tls_file_that_is_not_a_regular_file_is_refused_unread(tmp_path):
    data = _sim()
    data["api"] = {"tls_cert": "/dev/zero", "tls_key": str(TLS / "head-key.pem")}
    with pytest.raises(ConfigError, match=r"api\.tls_cert: got '/dev/zero', expected a PEM file \(a regular file"):
        load_config(_write(tmp_path, data))


def test_a_home_directory_that_cannot_be_found_is_a_located_error(tmp_path, monkeypatch):
    data = _sim()
    path = _write(tmp_path, data)

    def no_home(self):
        raise RuntimeError("Could not determine home directory.")

    monkeypatch.setattr(type(tmp_path), "expanduser", no_home)
    with pytest.raises(ConfigError, match=r"state_dir: got '~/.local/state/headctl/sim-ideal', expected a path that can "
                                          r"be expanded \(Could not determine home directory\.\)"):
        load_config(path)


# --- what running needs of this machine: check_runtime -------------------------------------------
@pytest.mark.parametrize("edit, words", [
    (lambda d, tmp: d.update(state_dir="/etc/passwd"),
     "state_dir: got '/etc/passwd', expected a writable directory, or one that can be created (/etc/passwd is a file)"),
    (lambda d, tmp: d.update(state_dir="/etc/passwd/sub/dir"), "(/etc/passwd is a file, not a directory)"),
    (lambda d, tmp: d.update(state_dir="/proc/headctl/state"), "(cannot create anything in /proc: "),
    (lambda d, tmp: d["logging"].update(file="/nonexistent/x.log"),
     "logging.file: got '/nonexistent/x.log', expected a file that can be written, in an existing directory "
     "(/nonexistent: No such file or directory)"),
    (lambda d, tmp: d["logging"].update(file=str(tmp)), "is a directory)"),
    (lambda d, tmp: d["logging"].update(file="/proc/headctl.log"), "cannot create headctl.log in /proc: "),
])
def test_check_runtime_refuses_a_state_dir_or_log_file_that_cannot_be_written(tmp_path, edit, words):
    data = _sim()
    edit(data, tmp_path)
    path = _write(tmp_path, data)
    config = load_config(path)  # the file is fine: clients (status, look) read it as it is
    with pytest.raises(ConfigError) as err:
        check_runtime(config)
    assert str(err.value).startswith(f"{path}: ") and words in str(err.value)


def test_check_runtime_accepts_a_state_dir_to_create_and_creates_nothing(tmp_path):
    data = _sim()
    data.update(state_dir="state/of/the/head", logging={"file": str(tmp_path / "head.log")})
    config = load_config(_write(tmp_path, data))
    check_runtime(config)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["head.yaml"]
    check_runtime(config.with_state_dir(tmp_path))  # an existing directory
    with pytest.raises(ConfigError, match="state_dir: got '/etc/passwd'"):
        check_runtime(config.with_state_dir("/etc/passwd"))  # --state-dir is checked as the key


@pytest.mark.parametrize("edit, words", [
    (lambda d: d.update(state_dir="/etc/passwd"), "state_dir: got '/etc/passwd'"),
    (lambda d: d["logging"].update(file="/nonexistent/x"), "logging.file: got '/nonexistent/x'"),
    (lambda d: d["cameras"]["left"].update(backend="no_such_pkg:Cam"), "cameras.left.backend"),
    (lambda d: d["servo_bus"].update(retries=1), "servo_bus.retries"),
])
def test_check_no_connect_fails_where_run_would(tmp_path, capsys, edit, words):
    data = _sim()
    edit(data)
    path = _write(tmp_path, data)
    assert main(["check", "--no-connect", "--config", str(path)]) == 2
    assert f"headctl check: {path}: {words}" in capsys.readouterr().err


@pytest.mark.parametrize("key, value", [("global_memory", 0.5), ("gaussian_cutoff", 1.0), ("robust_scale", -1.0)])
def test_map_parameters_a_saved_map_would_refuse_are_refused_in_the_config(tmp_path, key, value):
    """What a map file may not hold, a config may not ask for: else the service would refuse its
    own saved map at every start."""
    data = yaml.safe_load((CONFIGS / "sim.yaml").read_text())
    data["gaze_map"][key] = value
    path = tmp_path / "head.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match=f"gaze_map.{key}"):
        load_config(path)


@pytest.mark.parametrize(("profile", "given", "expected"), [
    ("paper", None, "paper"), ("default", None, "default"), ("paper", "default", "default")])
def test_the_correspondence_follows_the_map_profile_unless_set(tmp_path, profile, given, expected):
    data = _sim()
    data.setdefault("gaze_map", {})["profile"] = profile
    if given is not None:
        data.setdefault("fixation", {})["correspondence"] = {"profile": given}
    config = load_config(_write(tmp_path, data))
    assert config.fixation.params.correspondence.profile == expected
    # Exploration too: the paper's random poses in motor space with its profile, unless set.
    assert config.fixation.params.exploration == ("random" if profile == "paper" else "teaching")
    data["fixation"] = {**data.get("fixation", {}), "exploration": "teaching"}
    assert load_config(_write(tmp_path, data)).fixation.params.exploration == "teaching"


def test_a_relative_textures_folder_is_found_beside_the_config(tmp_path, monkeypatch):
    import cv2
    import numpy as np

    photos = tmp_path / "heads" / "photos"
    photos.mkdir(parents=True)
    cv2.imwrite(str(photos / "wall.png"), np.random.default_rng(0).integers(0, 255, (64, 64), dtype=np.uint8))
    data = _sim()
    data["cameras"]["scene"] = {"textures": "photos"}
    monkeypatch.chdir(tmp_path)  # elsewhere than the config: the folder is found beside it all the same
    config = load_config(_write(tmp_path / "heads", data))
    assert config.cameras.scene.folder == photos
    data["cameras"]["scene"] = {"textures": "missing"}
    with pytest.raises(ConfigError, match=r"cameras\.scene\.textures: got '.*heads/missing'"):
        load_config(_write(tmp_path / "heads", data))

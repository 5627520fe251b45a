"""The head's YAML config (headctl.config) and `headctl check`."""
from __future__ import annotations

import subprocess
import sys

import pytest
import yaml

from calib_free.fixation import FixationParams
from headctl.cli import main
from headctl.config import DEFAULT_CONFIG, load_config
from headctl.errors import ConfigError
from tests.support import CONFIGS, TLS

EXAMPLES = ["sim.yaml", "xm430-u2d2-aravis.yaml", "usb-webcams.yaml"]



def _write(tmp_path, data, name="head.yaml"):
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data))
    return path


def _sim():
    return yaml.safe_load((CONFIGS / "sim.yaml").read_text())


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
    assert config.fixation.explore and config.fixation.vergence_range == (1.0, 20.0)


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
                                       "cameras, gaze_map, fixation, service, state_dir, logging, api); "
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

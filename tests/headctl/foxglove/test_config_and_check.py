"""The `foxglove:` section read and refused as every section is; `headctl check` and `run`
naming the install step when the view is on but foxglove-sdk is missing; the service and its
other front ends built and run without the package."""
from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from headctl.cli.main import main
from headctl.config.head import load_config
from headctl.errors import ConfigError
from tests.support.daemon_proc import ROOT
from tests.support.sections import refusals_without, with_section


def write(tmp_path: Path, foxglove: object) -> Path:
    return with_section(tmp_path, "foxglove", foxglove)


def test_off_by_default_on_loopback() -> None:
    section = load_config().foxglove
    assert (section.enabled, section.host, section.port, section.jpeg_quality) == (False, "127.0.0.1", 8766, 80)


def test_the_section_read(tmp_path: Path) -> None:
    section = load_config(write(tmp_path, {"enabled": True, "host": "::1", "port": 9000, "jpeg_quality": 60})).foxglove
    assert (section.enabled, section.host, section.port, section.jpeg_quality) == (True, "::1", 9000, 60)


@pytest.mark.parametrize("foxglove, message", [
    ({"port": 70000}, "foxglove.port: got 70000, expected a TCP port, 0 for an ephemeral one"),
    ({"host": "not a host"}, "foxglove.host: got 'not a host', expected an IP address or a host name"),
    ({"jpeg_quality": 5}, "foxglove.jpeg_quality: got 5, expected 10 to 100"),
    ({"enabled": "yes"}, "foxglove.enabled: got 'yes'"),
    ({"prot": 1}, "foxglove.prot"),
])
def test_bad_values_are_refused_naming_key_value_and_expected(tmp_path: Path, foxglove: object, message: str) -> None:
    path = write(tmp_path, foxglove)
    with pytest.raises(ConfigError) as err:
        load_config(path)
    assert str(err.value).startswith(f"{path}: ") and message in str(err.value), str(err.value)


def test_check_and_run_name_the_install_step_when_foxglove_sdk_is_missing(tmp_path: Path, monkeypatch,
                                                                          capsys) -> None:
    path = write(tmp_path, {"enabled": True})
    for command, err in refusals_without("foxglove", path, monkeypatch, capsys).items():
        assert f"headctl {command}: {path}: foxglove.enabled is true but foxglove-sdk is not installed" in err
        assert "pip install 'headctl[foxglove]'" in err


def test_check_tells_the_view_when_it_is_on(tmp_path: Path, capsys) -> None:
    path = write(tmp_path, {"enabled": True, "port": 9001})
    assert main(["check", "--config", str(path), "--no-connect"]) == 0
    assert "  foxglove: live view on ws://127.0.0.1:9001" in capsys.readouterr().out


def test_the_service_builds_its_front_ends_without_the_package(tmp_path: Path) -> None:
    """In a process where `import foxglove` fails: the front ends of a config without the view
    are made and the API imports; with the view on, entering it names the install step."""
    code = textwrap.dedent(f"""
        import dataclasses, sys
        sys.modules["foxglove"] = None  # import foxglove: ImportError
        from headctl.api.compose import front_ends
        from headctl.config.foxglove import FoxgloveConfig
        from headctl.config.head import load_config
        from headctl.errors import HeadctlError
        from headctl.foxglove.view import FoxgloveView
        config = load_config().with_state_dir({str(tmp_path / 'state')!r})
        assert front_ends(config) is not None
        on = dataclasses.replace(config, foxglove=FoxgloveConfig(enabled=True))
        try:
            FoxgloveView(None, on).__enter__()
        except HeadctlError as err:
            print(err)
        assert "foxglove" not in [m for m in sys.modules if sys.modules[m] is not None]
    """)
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120,
                          env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})
    assert done.returncode == 0, done.stderr
    assert "foxglove.enabled is true but foxglove-sdk is not installed: pip install 'headctl[foxglove]'" in done.stdout

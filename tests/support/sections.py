"""Config files with one optional section set, and the CLI's refusal of a section whose extra
is missing: what the tests of the optional front ends (ROS 2, Foxglove) share."""
from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest
import yaml

from headctl.cli.main import main
from headctl.config.head import DEFAULT_CONFIG


def with_section(tmp_path: Path, key: str, section: object) -> Path:
    """The packaged simulated head's config with `key: section`, its state in `tmp_path`."""
    data = yaml.safe_load(DEFAULT_CONFIG.read_text())
    data["state_dir"] = str(tmp_path / "state")
    data[key] = section
    path = tmp_path / "head.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def refusals_without(module: str, path: Path, monkeypatch: pytest.MonkeyPatch,
                     capsys: pytest.CaptureFixture[str]) -> dict[str, str]:
    """What `headctl check --no-connect` and `headctl run` print on stderr for the config at
    `path` when `module` is not installed (each must exit 1), by command."""
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == module else real(name, *a))
    out = {}
    for command in ("check", "run"):
        assert main([command, "--config", str(path), *(["--no-connect"] if command == "check" else [])]) == 1
        out[command] = capsys.readouterr().err
    return out

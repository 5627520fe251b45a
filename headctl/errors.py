"""The one exception hierarchy of `headctl`."""
from __future__ import annotations


class HeadctlError(Exception):
    """Root of every error raised by `headctl`."""


class ConfigError(HeadctlError, ValueError):
    """A configuration file is invalid: the message names the file, key path, value and what was expected."""

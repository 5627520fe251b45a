"""The `api:` section of a head's config: the HTTP control API's address, token and TLS files.

Apart from the rest of the config (`headctl.config.head`, which holds `ApiConfig` in `HeadConfig`)
because the API's section is the one that names secrets and files: `resolve_api` reads the
token file (bounded; its content never shown) and checks the TLS certificate and key (regular
files, bounded, a pair that loads), and `secrets_in` and `scrub` keep a token out of every
config error, also one under a misspelt key. `beside` finds a file a config names, relative
to the config file (the loader uses it for `state_dir` too).
"""
from __future__ import annotations

import dataclasses
import ipaddress
import os
import re
import ssl
import stat
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TypedDict

from drivers.config.reader import check_settings, config_keys, setting
from drivers.config.file import read_bounded
from drivers.config.messages import HIDDEN, Shown
from headctl.errors import ConfigError

MAX_TOKEN_FILE_BYTES = 4096
MAX_PEM_BYTES = 1 << 20
_HOSTNAME = re.compile(r"(?=.{1,253}$)[A-Za-z0-9]([A-Za-z0-9-]{0,61}[A-Za-z0-9])?(\.[A-Za-z0-9]([A-Za-z0-9-]{0,61}"
                       r"[A-Za-z0-9])?)*\.?")


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def is_ip_address(host: str) -> bool:
    try:
        ipaddress.ip_address(host)
    except ValueError:
        return False
    return True


def is_host(host: str) -> bool:
    """An IP address or a host name."""
    return is_ip_address(host) or bool(_HOSTNAME.fullmatch(host))


@dataclass(frozen=True)
class ApiConfig:
    """The `api:` section: the HTTP control API and dashboard (`headctl.api.app`)."""

    enabled: bool = True
    # any other address needs a token
    host: str = setting("127.0.0.1", check=is_host, expected="an IP address or a host name")
    # 0: an ephemeral port, written to <state_dir>/api.url
    port: int = setting(8765, lo=0, hi=65535, expected="a TCP port, 0 for an ephemeral one")
    # 'Authorization: Bearer <token>' (or ?token=); a secret: never in a message or a log line
    token: str | None = setting(None, secret=True, repr=False, check=lambda t: len(t) >= 16 and t.isprintable(),
                                expected="at least 16 characters, printable")
    token_file: str | None = None  # a file holding the token (mode 0600); relative to the config file
    tls_cert: str | None = None  # HTTPS: the certificate (PEM, with its chain); relative to the config file
    tls_key: str | None = None  # ... and its private key (PEM, mode 0600)
    max_queued_looks: int = setting(16, lo=1, hi=1000, expected="1 to 1000")
    # MJPEG frames a second per client
    stream_fps: float = setting(10.0, lo=0.1, hi=60.0, expected="0.1 to 60 frames a second")
    jpeg_quality: int = setting(80, lo=10, hi=100, expected="10 to 100")

    def __post_init__(self) -> None:
        check_settings(self)

    @property
    def url(self) -> str:
        host = "127.0.0.1" if self.host in ("0.0.0.0", "") else ("[::1]" if self.host == "::" else self.host)
        return f"{'https' if self.tls_cert else 'http'}://{host}:{self.port}"


class ApiChanges(TypedDict, total=False):
    """Fields of an `ApiConfig` to replace (`HeadConfig.with_api`)."""

    enabled: bool
    host: str
    port: int
    token: str | None
    token_file: str | None
    tls_cert: str | None
    tls_key: str | None
    max_queued_looks: int
    stream_fps: float
    jpeg_quality: int


def resolve_api(api: ApiConfig, path: Path) -> ApiConfig:
    """The api section with its token file read and its TLS files found and checked."""
    if api.token is not None and api.token_file is not None:
        raise ConfigError(key_path="api.token_file", value=api.token_file,
                          expected="either api.token or api.token_file, not both")
    if api.token_file is not None:
        token_path = beside(path, api.token_file, "api.token_file")
        token = _read_token_file(token_path, api.token_file)
        api = dataclasses.replace(api, token=token, token_file=str(token_path))
    if api.enabled and not is_loopback(api.host) and api.token is None:
        raise ConfigError(key_path="api.token", value=None,
                          expected=f"a token (api.token or api.token_file): api.host {api.host!r} is not "
                                   "a loopback address, and the API moves the head")
    if (api.tls_cert is None) != (api.tls_key is None):
        missing = "api.tls_key" if api.tls_key is None else "api.tls_cert"
        raise ConfigError(key_path=missing, value=None,
                          expected="both api.tls_cert and api.tls_key (HTTPS needs the certificate and its key)")
    if api.tls_cert is not None and api.tls_key is not None:
        cert, key = beside(path, api.tls_cert, "api.tls_cert"), beside(path, api.tls_key, "api.tls_key")
        for name, file, given in (("api.tls_cert", cert, api.tls_cert), ("api.tls_key", key, api.tls_key)):
            if not os.access(file, os.R_OK):
                raise ConfigError(key_path=name, value=given,
                                  expected=f"a readable PEM file ({file} is missing or unreadable)")
            # ssl reads the whole file: a device, a pipe or a huge file would hang or exhaust it.
            mode_size = _regular_file(file)
            if mode_size is None or mode_size > MAX_PEM_BYTES:
                raise ConfigError(key_path=name, value=given,
                                  expected=f"a PEM file (a regular file of at most {MAX_PEM_BYTES} bytes; {file} "
                                           "is not)")
        # Here, not when the daemon starts: `headctl check` and the CLI see a bad pair too.
        context = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
        try:
            context.load_verify_locations(cafile=cert)
        except ssl.SSLError as err:
            raise ConfigError(key_path="api.tls_cert", value=api.tls_cert,
                              expected=f"a PEM certificate ({err.reason or err})") from None
        try:
            context.load_cert_chain(cert, key)
        except ssl.SSLError as err:
            raise ConfigError(key_path="api.tls_key", value=api.tls_key,
                              expected=f"the PEM private key of the certificate in api.tls_cert "
                                       f"({err.reason or err})") from None
        api = dataclasses.replace(api, tls_cert=str(cert), tls_key=str(key))
    return api


def _regular_file(file: Path) -> int | None:
    """The size of `file` if it is a regular file, else None."""
    try:
        st = os.stat(file)
    except OSError:
        return None
    return st.st_size if stat.S_ISREG(st.st_mode) else None


def _read_token_file(file: Path, given: str) -> str:
    """The token a token file holds; its content never appears in an error."""
    def refused(why: str) -> ConfigError:
        return ConfigError(key_path="api.token_file", value=given,
                           expected=f"a readable file holding the token ({why})")

    if _regular_file(file) is None:
        try:
            os.stat(file)
        except OSError as err:
            raise refused(err.strerror or "cannot be read") from None
        raise refused(f"{file} is not a regular file")
    try:
        raw = read_bounded(file, MAX_TOKEN_FILE_BYTES)
    except OSError as err:
        raise refused(err.strerror or "cannot be read") from None
    if raw is None:
        raise refused(f"it holds more than {MAX_TOKEN_FILE_BYTES} bytes")
    try:
        token = raw.decode("utf-8").strip()
    except UnicodeDecodeError:
        raise refused("it is not UTF-8 text") from None
    if len(token) < 16 or not token.isprintable():
        raise ConfigError(key_path="api.token_file", value=given,
                          expected="a file holding a token of at least 16 characters, printable, on one line")
    return token


def beside(config_path: Path, value: str, key_path: str) -> Path:
    """A path from the config: ~ and $VARS expanded, relative to the config file's directory."""
    try:
        file = Path(os.path.expandvars(value)).expanduser()
    except RuntimeError as err:  # no home directory to expand ~ to
        raise ConfigError(key_path=key_path, value=value, expected=f"a path that can be expanded ({err})") from None
    return file if file.is_absolute() else config_path.resolve().parent / file


def secrets_in(data: object) -> list[str]:
    """Strings of a raw config that may be secrets: the values of keys that name a token
    anywhere (not a token file's path), and of keys the api section does not know (a
    misspelt `token`)."""
    found: list[str] = []
    known_api = set(config_keys(ApiConfig)) - {"token"}

    def walk(value: object, depth: int) -> None:
        if depth > 40:
            return
        if isinstance(value, Mapping):
            for key, item in value.items():
                name = str(key).lower()
                if isinstance(item, str) and "token" in name and not name.endswith("_file") and len(item) >= 4:
                    found.append(item)
                walk(item, depth + 1)
        elif isinstance(value, (list, tuple)):
            for item in value:
                walk(item, depth + 1)

    walk(data, 0)
    api = data.get("api") if isinstance(data, Mapping) else None
    if isinstance(api, Mapping):
        found += [v for k, v in api.items() if k not in known_api and isinstance(v, str) and len(v) >= 4]
    return found


def scrub(err: ConfigError, secrets: list[str]) -> None:
    """Hide every one of `secrets` wherever `err`'s message would show it."""
    for secret in sorted(set(secrets), key=len, reverse=True):
        if err.value is not None and err.value is not HIDDEN:
            try:
                text = repr(err.value)
            except (ValueError, RecursionError):
                text = ""
            if secret in text:
                err.value = Shown(text.replace(secret, repr(HIDDEN)))
        if err.expected is not None and secret in err.expected:
            err.expected = err.expected.replace(secret, repr(HIDDEN))
        if err.message is not None and secret in err.message:
            err.message = err.message.replace(secret, repr(HIDDEN))

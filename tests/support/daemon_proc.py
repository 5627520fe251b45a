"""`headctl run` in a subprocess with a state directory of its own, driven through its HTTP API.

Shared by the end-to-end, API and dashboard tests. The API listens on an ephemeral port
(`--api-port 0`); the URL is read from `<state_dir>/api.url`, which the daemon writes once it
listens. Waiting polls the state with a deadline and fails with the last state seen.
"""
from __future__ import annotations

import os
import pathlib
import signal
import subprocess
import sys
import time

from headctl.api.client import ApiClient, ApiError

ROOT = pathlib.Path(__file__).resolve().parents[2]
SIM = ROOT / "configs" / "sim.yaml"


class DaemonProcess:
    def __init__(self, state_dir: pathlib.Path, config: pathlib.Path = SIM, *extra: str,
                 token: str | None = None) -> None:
        self.state_dir = state_dir
        state_dir.mkdir(parents=True, exist_ok=True)
        (state_dir / "api.url").unlink(missing_ok=True)
        self.log_path = state_dir.parent / f"{state_dir.name}-daemon.log"
        self.log = open(self.log_path, "ab")
        self.token = token
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        env.pop("NOTIFY_SOCKET", None)
        self.proc = subprocess.Popen([sys.executable, "-m", "headctl.cli.main", "run", "--config", str(config),
                                      "--state-dir", str(state_dir), "--api-port", "0", *extra], cwd=ROOT, env=env,
                                     stdout=self.log, stderr=subprocess.STDOUT)
        self._client: ApiClient | None = None

    @property
    def client(self) -> ApiClient:
        """The API client, once the daemon listens (waits up to 30 s for `api.url`)."""
        if self._client is None:
            url_file = self.state_dir / "api.url"
            deadline = time.monotonic() + 30.0
            while not url_file.exists():
                self._check_alive("its API to listen")
                assert time.monotonic() < deadline, f"no {url_file} within 30 s; log: {self.tail()}"
                time.sleep(0.05)
            self._client = ApiClient(url_file.read_text().strip(), self.token, timeout_s=5.0)
        return self._client

    @property
    def url(self) -> str:
        return self.client.url

    def status(self) -> dict:
        return self.client.state()

    def inject(self, fault: str, **args) -> None:
        self.client.request("POST", "/api/v1/sim/faults", {"fault": fault, **args})

    def wait(self, predicate, timeout_s: float, what: str) -> dict:
        """Poll the state until `predicate(state)`; fail with the last state after the deadline."""
        deadline = time.monotonic() + timeout_s
        status: dict = {}
        while time.monotonic() < deadline:
            self._check_alive(what)
            try:
                status = self.status()
            except ApiError:
                status = {}
            if status and predicate(status):
                return status
            time.sleep(0.05)
        raise AssertionError(f"timed out after {timeout_s} s waiting for {what}; last state {status}")

    def _check_alive(self, what: str) -> None:
        assert self.proc.poll() is None, \
            f"the daemon exited with {self.proc.returncode} waiting for {what}; log: {self.tail()}"

    def tail(self, lines: int = 30) -> str:
        self.log.flush()
        return "\n".join(self.log_path.read_text(errors="replace").splitlines()[-lines:])

    def terminate(self, timeout_s: float = 5.0) -> tuple[int, float]:
        started = time.monotonic()
        self.proc.send_signal(signal.SIGTERM)
        code = self.proc.wait(timeout_s + 2.0)
        return code, time.monotonic() - started

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(5)
        self.log.close()

"""`headctl run` in a child process for the benchmarks that load it from another process: its
log kept beside a temporary state directory, waiting for its API with a deadline, stopping it."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
import urllib.parse
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
LOOPBACK = ("127.0.0.1", "::1", "localhost")


class BenchDaemon:
    """The daemon on `config` with its state in `state_dir`; `error` is what its failures raise."""

    def __init__(self, config: Path, state_dir: Path, error: type[Exception]) -> None:
        self.state_dir = state_dir
        self.error = error
        self.log_path = state_dir.parent / "daemon.log"
        self.log = open(self.log_path, "wb")
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        env.pop("NOTIFY_SOCKET", None)
        self.proc = subprocess.Popen([sys.executable, "-m", "headctl.cli.main", "run", "--config", str(config),
                                      "--state-dir", str(state_dir), "--api-port", "0"], cwd=ROOT, env=env,
                                     stdout=self.log, stderr=subprocess.STDOUT)
        self.url = ""

    def tail(self, lines: int = 20) -> str:
        self.log.flush()
        return "\n".join(self.log_path.read_text(errors="replace").splitlines()[-lines:])

    def check_alive(self) -> None:
        if self.proc.poll() is not None:
            raise self.error(f"the daemon exited with {self.proc.returncode}; its log ends:\n{self.tail()}")

    def wait_url(self, deadline_s: float) -> str:
        """The API's URL once the daemon listens (on loopback only: these benchmarks load it)."""
        url_file = self.state_dir / "api.url"
        while not url_file.exists() or not url_file.read_text().strip():
            self.check_alive()
            if time.monotonic() > deadline_s:
                raise self.error(f"no {url_file} in time; the daemon's log ends:\n{self.tail()}")
            time.sleep(0.05)
        self.url = url_file.read_text().strip()
        host = urllib.parse.urlsplit(self.url).hostname
        if host not in LOOPBACK:
            raise self.error(f"the daemon listens on {host}: these benchmarks load loopback only")
        return self.url

    def stop(self, timeout_s: float = 15.0) -> int | None:
        """SIGTERM, then SIGKILL after `timeout_s`; the exit code."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout_s)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
        self.log.close()
        return self.proc.returncode

"""sd_notify (headctl.service.supervision.systemd) and the one-daemon-per-state-directory lock."""
from __future__ import annotations

import os
import socket
import subprocess
import sys

import pytest

from headctl.errors import HeadctlError
from headctl.service.persistence import StateDirLock
from headctl.service.supervision.systemd import SystemdNotifier


def test_sd_notify_datagrams_reach_the_notify_socket(tmp_path):
    path = str(tmp_path / "notify")
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as server:
        server.bind(path)
        notifier = SystemdNotifier({"NOTIFY_SOCKET": path, "WATCHDOG_USEC": "3000000",
                                    "WATCHDOG_PID": str(os.getpid())})
        assert notifier.enabled and notifier.watchdog_s == 3.0
        notifier.notify(ready=1, status="running: 0 fixations")
        assert server.recv(4096) == b"READY=1\nSTATUS=running: 0 fixations"
        notifier.close()
        notifier.close()
    assert not SystemdNotifier({}).enabled
    assert SystemdNotifier({"WATCHDOG_USEC": "100", "WATCHDOG_PID": "1"}).watchdog_s is None  # not ours


def test_one_daemon_per_state_directory_and_the_lock_dies_with_its_holder(tmp_path):
    path = tmp_path / "headctl.lock"
    with StateDirLock(path):
        with pytest.raises(HeadctlError, match=f"another headctl daemon \\(pid {os.getpid()}\\)"):
            StateDirLock(path).__enter__()
    with StateDirLock(path) as lock:  # released: free again
        lock.close()
        lock.close()  # idempotent
    # A holder killed with -9 leaves the file but not the lock.
    holder = subprocess.Popen([sys.executable, "-c", "import fcntl, os, sys, time; fd = os.open(sys.argv[1], "
                               "os.O_RDWR | os.O_CREAT); fcntl.flock(fd, fcntl.LOCK_EX); print('held', flush=True); "
                               "time.sleep(60)", str(path)], stdout=subprocess.PIPE, text=True)
    assert holder.stdout.readline().strip() == "held"
    with pytest.raises(HeadctlError, match="another headctl daemon"):
        StateDirLock(path).__enter__()
    holder.kill()
    holder.wait(5)
    with StateDirLock(path):
        assert path.read_text().strip() == str(os.getpid())

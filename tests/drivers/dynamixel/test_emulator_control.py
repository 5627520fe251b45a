"""Faults injected into the servo emulator from outside (drivers.dynamixel.emulator.control): every
command through a real Unix socket and through `headctl emulate-servos --control -`, each
answered with one line, and bad commands answered with an error while serving goes on."""
from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import stat
import subprocess
import sys
import tempfile

import dynamixel_sdk as sdk
import pytest

from drivers.clock import ManualClock
from drivers.dynamixel.tables.x_series import XAddr
from drivers.dynamixel.emulator.server import DxlEmulator
from drivers.dynamixel.emulator.control import MAX_LINE_BYTES, ControlSocket, EmulatorControl
from drivers.dynamixel.sdk import BlockingPortHandler
from tests.support.daemon_proc import ROOT


@pytest.fixture
def short_dir():
    """A directory with a short path: a Unix socket's path must fit in 108 bytes."""
    path = tempfile.mkdtemp(prefix="dxlctl-")
    yield path
    shutil.rmtree(path, ignore_errors=True)


class Client:
    """A control client on the socket: one command out, one line back."""

    def __init__(self, path: str) -> None:
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self.sock.settimeout(10.0)
        self.sock.connect(path)
        self.file = self.sock.makefile("rb")

    def send(self, raw: bytes) -> str:
        self.sock.sendall(raw)
        return self.file.readline().decode().rstrip("\n")

    def ask(self, command: str) -> str:
        return self.send(command.encode() + b"\n")

    def status(self) -> dict:
        answer = self.ask("status")
        assert answer.startswith("ok {")
        return json.loads(answer[3:])

    def close(self) -> None:
        self.file.close()
        self.sock.close()


@pytest.fixture
def served(short_dir):
    """An emulator on a manual clock with its control socket; yields (emulator, client, port)."""
    clock = ManualClock(10.0)
    emulator = DxlEmulator([1, 2, 3, 4], clock=clock, link=os.path.join(short_dir, "servos")).start()
    server = ControlSocket(EmulatorControl(emulator), os.path.join(short_dir, "ctl")).start()
    client = Client(server.path)
    port = _open(emulator.port)
    try:
        yield emulator, client, port, clock, server
    finally:
        port.closePort()
        client.close()
        server.stop()
        emulator.stop()


def _open(path: str) -> BlockingPortHandler:
    """A client port that waits without spinning (the emulator thread shares this process)."""
    port = BlockingPortHandler(path, latency_timer_ms=20.0, reply_slack_ms=10.0)
    assert port.openPort() and port.setBaudRate(1_000_000)
    return port


def _ping(port, servo_id):
    """One ping: its result (a dropped reply is a timeout, and is drained away)."""
    result = sdk.PacketHandler(2.0).ping(port, servo_id)[1]
    if result != sdk.COMM_SUCCESS:
        port.drain_late_replies()
    return result


def _retried(port, call, *args):
    """One SDK transaction, again after a timeout (5 tries), as a robust client does on a
    loaded machine; the late reply is drained first."""
    for _ in range(5):
        reply = call(port, *args)
        if reply[-2] != sdk.COMM_RX_TIMEOUT:  # (..., result, error)
            return reply
        port.drain_late_replies()
    return reply


def _answers(port, servo_id) -> bool:
    return _retried(port, sdk.PacketHandler(2.0).ping, servo_id)[1] == sdk.COMM_SUCCESS


def test_every_command_through_a_real_socket_answers_one_line_and_acts(served):
    emulator, client, port, clock, server = served
    assert client.ask("help").startswith("ok commands: drop ID [N] | corrupt ID [N] | delay ID SECONDS [N]")
    status = client.status()
    assert status["vanished"] is False and status["link"] == emulator.link
    assert status["servos"]["4"] == {"drop": 0, "corrupt": 0, "delay_count": 0, "delay_s": 0.0,
                                     "hardware_error": 0, "torque_on": False, "booting": False, "present": True}

    assert client.ask("drop 4 2") == "ok id 4: the next 2 replies dropped"
    assert client.status()["servos"]["4"]["drop"] == 2
    assert _ping(port, 4) == sdk.COMM_RX_TIMEOUT
    emulator.wait_idle()
    assert client.status()["servos"]["4"]["drop"] == 1

    assert client.ask("corrupt 3") == "ok id 3: the next 1 reply with a bad CRC"
    assert _ping(port, 3) == sdk.COMM_RX_CORRUPT
    assert _answers(port, 3)

    assert client.ask("delay 2 0.05 3") == "ok id 2: the next 3 replies 0.05 s late"
    delayed = client.status()["servos"]["2"]
    assert (delayed["delay_count"], delayed["delay_s"]) == (3, 0.05)

    assert client.ask("clear 2") == "ok pending drops, corruptions and delays cancelled for id 2"
    assert client.status()["servos"]["2"]["delay_count"] == 0
    assert client.ask("clear") == "ok pending drops, corruptions and delays cancelled for every id"
    assert client.status()["servos"]["4"]["drop"] == 0

    # Hardware errors: by number or by names; the Shutdown bits cut torque (it was on).
    packet = sdk.PacketHandler(2.0)
    assert _retried(port, packet.write1ByteTxRx, 1, XAddr.TORQUE_ENABLE, 1)[0] == sdk.COMM_SUCCESS
    assert client.ask("hwerror 1 voltage") == "ok id 1: hardware error 0x01 (voltage) raised; status now 0x01, torque on"
    assert client.ask("hwerror 1 0x20") == "ok id 1: hardware error 0x20 (overload) raised; status now 0x21, torque off"
    assert client.ask("hwerror 2 overheating+shock") == (
        "ok id 2: hardware error 0x14 (overheating+shock) raised; status now 0x14, torque off")
    assert _retried(port, packet.read1ByteTxRx, 1, XAddr.HARDWARE_ERROR_STATUS)[0] == 0x21

    # A power cycle: RAM defaults (the error cleared), silent while it boots.
    assert client.ask("powercycle 1") == "ok id 1: power cycled (RAM defaults, torque off; booting)"
    assert client.status()["servos"]["1"]["booting"] is True
    assert _ping(port, 1) == sdk.COMM_RX_TIMEOUT
    clock.advance(1.0)
    booted = client.status()["servos"]["1"]
    assert (booted["booting"], booted["hardware_error"], booted["torque_on"]) == (False, 0, False)
    assert _answers(port, 1)

    # A servo off the bus and back: it answers nothing, then boots with RAM defaults.
    assert _retried(port, packet.write1ByteTxRx, 4, XAddr.TORQUE_ENABLE, 1)[0] == sdk.COMM_SUCCESS
    assert client.ask("remove 4") == "ok id 4: off the bus (it answers nothing until `add 4`)"
    assert client.status()["servos"]["4"]["present"] is False
    assert _ping(port, 4) == sdk.COMM_RX_TIMEOUT
    assert client.ask("add 4") == "ok id 4: back on the bus (RAM defaults, torque off; booting)"
    clock.advance(1.0)
    back = client.status()["servos"]["4"]
    assert (back["present"], back["booting"], back["torque_on"]) == (True, False, False)
    assert _answers(port, 4)


def test_a_brown_out_silences_every_servo_then_they_boot_with_ram_defaults(served):
    emulator, client, port, clock, _server = served
    packet = sdk.PacketHandler(2.0)
    assert _retried(port, packet.write4ByteTxRx, 2, XAddr.PROFILE_VELOCITY, 50)[1] == sdk.COMM_SUCCESS
    assert _retried(port, packet.write1ByteTxRx, 2, XAddr.TORQUE_ENABLE, 1)[0] == sdk.COMM_SUCCESS
    assert client.ask("brownout 2 voltage") == (
        "ok every servo without power for 2 s, then back with RAM defaults and hardware error 0x01")
    assert all(servo["booting"] for servo in client.status()["servos"].values())
    assert _ping(port, 1) == sdk.COMM_RX_TIMEOUT and _ping(port, 4) == sdk.COMM_RX_TIMEOUT
    clock.advance(1.0)
    assert _ping(port, 2) == sdk.COMM_RX_TIMEOUT  # still without power
    clock.advance(1.5)
    servos = client.status()["servos"]
    assert all((s["booting"], s["hardware_error"], s["torque_on"]) == (False, 1, False) for s in servos.values())
    assert _retried(port, packet.read4ByteTxRx, 2, XAddr.PROFILE_VELOCITY)[0] == 0  # RAM default
    assert client.ask("brownout 0.5") == "ok every servo without power for 0.5 s, then back with RAM defaults"


def test_vanish_for_a_while_then_back_by_itself_and_vanish_until_told(served):
    emulator, client, port, _clock, _server = served
    assert client.ask("vanish 0.2") == "ok port vanished for 0.2 s"
    status = client.status()
    assert status["vanished"] is True and status["port"] is None and 0.0 <= status["back_in_s"] <= 0.2
    assert not os.path.lexists(emulator.link)
    path = emulator.wait_port(timeout=5.0)  # the emulator's own thread brings it back
    assert path == emulator.link and os.path.realpath(emulator.link).startswith("/dev/pts/")
    assert client.status()["vanished"] is False
    assert client.ask("vanish") == "ok port vanished until `reappear`"
    assert client.status()["back_in_s"] is None
    assert client.ask("reappear") == f"ok port back at {emulator.link}"
    again = _open(emulator.port)
    try:
        assert _answers(again, 2)  # a client on the new pty is served
    finally:
        again.closePort()


@pytest.mark.parametrize(("command", "reason"), [
    ("explode", "error unknown command 'explode'; commands: drop ID"),
    ("drop", "error drop: expected drop ID [N]"),
    ("drop 9", "error drop: no servo with id 9; ids: 1, 2, 3, 4"),
    ("drop x", "error drop: servo id 'x' is not a number"),
    ("drop 4 0", "error drop: count 0: expected 1 to 1000000"),
    ("drop 4 -3", "error drop: count -3: expected 1 to 1000000"),
    ("drop 4 2 7", "error drop: expected drop ID [N]"),
    ("corrupt 4 lots", "error corrupt: count 'lots' is not a whole number"),
    ("delay 2", "error delay: expected delay ID SECONDS [N]"),
    ("delay 2 nan", "error delay: nan s: expected 0 to 10 s"),
    ("delay 2 -1", "error delay: -1 s: expected 0 to 10 s"),
    ("delay 2 3600", "error delay: 3600 s: expected 0 to 10 s"),
    ("hwerror 2 0", "error hwerror: bits 0: expected 1 to 0xff (a hardware error is cleared only by a reboot"),
    ("hwerror 2 0x100", "error hwerror: bits 0x100: expected 1 to 0xff"),
    ("hwerror 2 melting", "error hwerror: bits 'melting': expected a number (0x20) or names joined by '+'"),
    ("powercycle", "error powercycle: expected powercycle ID"),
    ("remove", "error remove: expected remove ID"),
    ("add 9", "error add: no servo with id 9; ids: 1, 2, 3, 4"),
    ("brownout", "error brownout: expected brownout SECONDS [BITS]"),
    ("brownout -1", "error brownout: -1 s: expected 0 to 3600 s"),
    ("brownout 1 fizz", "error brownout: bits 'fizz': expected a number"),
    ("vanish soon", "error vanish: 'soon' is not a number of seconds"),
    ("vanish inf", "error vanish: inf s: expected 0 to 3600 s"),
    ("reappear now", "error reappear: takes no arguments"),
    ("status please", "error status: takes no arguments"),
])
def test_a_bad_command_is_answered_with_an_error_and_changes_nothing(served, command, reason):
    emulator, client, port, _clock, _server = served
    before = client.status()
    answer = client.ask(command)
    assert answer.startswith(reason), answer
    assert "\n" not in answer
    assert client.status() == before
    assert _answers(port, 1)  # still serving


def test_garbage_on_the_socket_is_refused_line_by_line(served):
    emulator, client, _port, _clock, server = served
    assert client.send(b"\xff\xfe\n") == "error not UTF-8 text"
    assert client.send(b"x" * (MAX_LINE_BYTES + 10) + b"\n") == f"error line longer than {MAX_LINE_BYTES} bytes"
    assert client.send(b"\n# a comment, no answer\n  \nstatus\r\n").startswith("ok {")
    # Two commands in one write, answered in order; a second client at the same time.
    other = Client(server.path)
    try:
        client.sock.sendall(b"drop 1\ndrop 2 5\n")
        assert client.file.readline() == b"ok id 1: the next 1 reply dropped\n"
        assert client.file.readline() == b"ok id 2: the next 5 replies dropped\n"
        assert other.ask("clear") == "ok pending drops, corruptions and delays cancelled for every id"
    finally:
        other.close()
    assert emulator.last_error is None


def test_the_socket_is_private_and_a_live_one_is_not_taken_over(served, short_dir):
    emulator, _client, _port, _clock, server = served
    assert stat.S_IMODE(os.stat(server.path).st_mode) == 0o600
    with pytest.raises(OSError, match="another emulator's control socket answers there"):
        ControlSocket(EmulatorControl(emulator), server.path).start()
    plain = os.path.join(short_dir, "plain")
    with open(plain, "w"):
        pass
    with pytest.raises(FileExistsError):
        ControlSocket(EmulatorControl(emulator), plain).start()
    # A socket left by an emulator that died is replaced.
    stale = os.path.join(short_dir, "stale")
    dead = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    dead.bind(stale)
    dead.close()
    replacement = ControlSocket(EmulatorControl(emulator), stale).start()
    try:
        client = Client(stale)
        assert client.ask("help").startswith("ok commands:")
        client.close()
    finally:
        replacement.stop()
    assert not os.path.lexists(stale)


def test_emulate_servos_takes_commands_on_stdin_and_a_socket(short_dir):
    link, control = os.path.join(short_dir, "servos"), os.path.join(short_dir, "ctl")
    proc = subprocess.Popen(
        [sys.executable, "-m", "headctl.cli.main", "emulate-servos", "--ids", "1,2,3,4", "--link", link,
         "--control", "-", "--control", control],
        cwd=ROOT, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    try:
        pty_path = proc.stdout.readline().strip()
        assert pty_path.startswith("/dev/pts/") and os.path.realpath(link) == pty_path

        def ask(command: str) -> str:
            proc.stdin.write(command + "\n")
            proc.stdin.flush()
            return proc.stdout.readline().rstrip("\n")

        assert ask("help").startswith("ok commands:")
        assert ask("drop 4 3") == "ok id 4: the next 3 replies dropped"
        assert ask("frobnicate").startswith("error unknown command 'frobnicate'")
        assert ask("hwerror 3 overload") == "ok id 3: hardware error 0x20 (overload) raised; status now 0x20, torque off"
        # The socket sees what stdin injected: one emulator behind both.
        client = Client(control)
        try:
            servos = client.status()["servos"]
            assert servos["4"]["drop"] == 3 and servos["3"]["hardware_error"] == 0x20
            assert client.ask("powercycle 3") == "ok id 3: power cycled (RAM defaults, torque off; booting)"
        finally:
            client.close()
        assert ask("vanish 0.1") == "ok port vanished for 0.1 s"
        assert json.loads(ask("status")[3:])["vanished"] is True
        proc.stdin.close()  # the end of stdin ends that control only: the emulator serves on
        client = Client(control)
        try:
            assert client.ask("clear") == "ok pending drops, corruptions and delays cancelled for every id"
        finally:
            client.close()
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=10) == 0
        assert not os.path.lexists(control) and not os.path.lexists(link)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_emulate_servos_refuses_a_control_path_it_cannot_take(short_dir):
    taken = os.path.join(short_dir, "taken")
    with open(taken, "w"):
        pass
    out = subprocess.run([sys.executable, "-m", "headctl.cli.main", "emulate-servos", "--control", taken],
                         cwd=ROOT, capture_output=True, text=True, timeout=30)
    assert out.returncode == 2 and f"--control {taken}:" in out.stderr and "not a socket" in out.stderr

"""A Dynamixel servo emulator serving virtual servos on a pseudo-terminal, in Protocol 2.0
(X-series) or Protocol 1.0 (AX, RX, MX).

`DxlEmulator` serves any number of emulated servos on an `os.openpty()` pseudo-terminal
from its own named thread: `drivers.dynamixel.emulator.servo_v2.EmulatedServo` speaking the wire format of
`drivers.dynamixel.protocol.v2`, or with `protocol=1.0` `drivers.dynamixel.emulator.servo_v1.EmulatedServo1`
speaking `drivers.dynamixel.protocol.v1` (answered by `drivers.dynamixel.emulator.v1`). The real
dynamixel-sdk, or any other client, talks to it exactly as to a real bus, so the backend
is tested byte for byte without a head. Each id may have its own model and firmware.

Protocol 2.0 instructions: Ping (also broadcast), Read, Write, Sync Read, Fast Sync Read
(servos with firmware >= 45; older ones ignore it, like real ones), Sync Write, Bulk Read,
Bulk Write, Reboot; others get an Instruction Error status. Protocol 1.0: Ping, Read,
Write, Sync Write, Bulk Read (MX models).

Faults can be injected: dropped replies, corrupted CRCs, delayed replies, hardware error
bits, a servo power cycle, and the port vanishing and coming back, by itself after a while
or when told (a stable symlink, like a udev rule's, follows the new pseudo-terminal);
`injected()` says what is pending. The motion model runs on an injectable clock; reply
delays (Return Delay Time, injected delays) and how long the port stays away are wire
timing and real time.

Run it with `headctl emulate-servos --ids 1,2,3,4 --link /tmp/head-servos` (`--protocol
1.0` for AX-12A servos, `--model` for others); from outside, faults go in through
`--control` (`drivers.dynamixel.emulator.control`).
"""
from __future__ import annotations

import collections
import logging
import os
import queue
import select
import termios
import threading
import time
import tty
from collections.abc import Callable, Iterable, Iterator, Mapping
from typing import Any

from drivers.clock import SYSTEM_CLOCK, Clock
from drivers.dynamixel.tables.x_series import X_BAUD_CODES, X_MODELS
from drivers.dynamixel.tables.v1 import P1_BAUD_CODES, P1_MODELS
from drivers.dynamixel.emulator.v1 import dispatch1
from drivers.dynamixel.emulator.v2 import dispatch2, fast_sync_read
from drivers.dynamixel.protocol.v2 import BROADCAST_ID, INST_FAST_SYNC_READ, Packet, PacketParser, build_packet
from drivers.dynamixel.protocol.v1 import PacketParser1
from drivers.dynamixel.protocol.v1 import build_packet as build_packet1
from drivers.dynamixel.emulator.servo_v2 import EmulatedServo
from drivers.dynamixel.emulator.servo_v1 import EmulatedServo1
from drivers.errors import DeviceStateError, DeviceTimeoutError
from drivers.servo.bus import TRACE

log = logging.getLogger(__name__)

# Not a Dynamixel instruction: the marker `DxlEmulator.wait_idle` sends itself.
_INST_BARRIER = 0x7F
_TERMIOS_SPEEDS = {baud: getattr(termios, f"B{baud}") for baud in X_BAUD_CODES | P1_BAUD_CODES
                   if hasattr(termios, f"B{baud}")}
DEFAULT_MODELS = {2.0: "XM430-W350", 1.0: "AX-12A"}
DEFAULT_FIRMWARE = {2.0: 48, 1.0: 24}


class _Parser:
    """The packet parser of either protocol."""

    def __init__(self, protocol: float) -> None:
        self._parser: PacketParser | PacketParser1 = PacketParser1() if protocol == 1.0 else PacketParser()

    def reset(self) -> None:
        self._parser.reset()

    def feed(self, data: bytes) -> Iterator[Packet]:
        return self._parser.feed(data)


class _Faults:
    """Pending injected faults for one servo id."""

    def __init__(self) -> None:
        self.drop = 0
        self.corrupt = 0
        self.delay_count = 0
        self.delay_s = 0.0


class DxlEmulator:
    """Virtual Protocol 2.0 servos on a pseudo-terminal, served from a named thread.

    Use as a context manager (or `start()` / `stop(timeout)`). `port` is the path to
    open; `link` (optional) is a symlink kept pointing at the pty, also across `vanish()`
    and `reappear()`. `baud`: the servos only understand a client whose port is set to
    this rate (the pty carries the client's termios speed), so scans at other rates find
    nothing. An exception while handling a packet is logged, kept in `last_error` and
    passed to `on_error`; the emulator goes on serving.
    """

    def __init__(self, ids: Iterable[int] = (1, 2, 3, 4), *, protocol: float = 2.0, model: str | None = None,
                 models: Mapping[int, str] | None = None, firmware: int | Mapping[int, int] | None = None,
                 clock: Clock = SYSTEM_CLOCK, link: str | None = None, baud: int = 1_000_000,
                 positions_ticks: dict[int, int] | None = None, absent: Iterable[int] = (),
                 on_error: Callable[[BaseException], None] | None = None) -> None:
        if protocol not in DEFAULT_MODELS:
            raise ValueError(f"protocol {protocol}: expected 1.0 or 2.0")
        known = P1_MODELS if protocol == 1.0 else X_MODELS
        bauds = P1_BAUD_CODES if protocol == 1.0 else X_BAUD_CODES
        if baud not in bauds:
            raise ValueError(f"baud {baud}: a Protocol {protocol} servo here offers {sorted(bauds)}")
        ids = sorted(set(ids))
        model_of = {i: (models or {}).get(i, model or DEFAULT_MODELS[protocol]) for i in ids}
        for servo_id, name in model_of.items():
            if name not in known:
                raise ValueError(f"servo id {servo_id}: model {name!r} does not speak Protocol {protocol}; "
                                 f"expected one of {', '.join(known)}")
        firmware_of = {i: firmware if isinstance(firmware, int) else
                       (firmware or {}).get(i, DEFAULT_FIRMWARE[protocol]) for i in ids}
        self.protocol = protocol
        self.clock = clock
        self.link = link
        self.baud = baud
        positions_ticks = positions_ticks or {}
        self.servos: dict[int, Any] = {}  # EmulatedServo, or EmulatedServo1 on Protocol 1.0
        for i in ids:
            if protocol == 1.0:
                self.servos[i] = EmulatedServo1(i, model_of[i], clock=clock, baud=baud, firmware=firmware_of[i],
                                                position_ticks=positions_ticks.get(i))
            else:
                self.servos[i] = EmulatedServo(i, model_of[i], clock=clock, baud=baud, firmware=firmware_of[i],
                                               position_ticks=positions_ticks.get(i, 2048))
        self._absent = set(absent)  # ids off the bus (unplugged, unpowered): they hear and answer nothing
        if not self._absent <= set(ids):
            raise ValueError(f"absent ids {sorted(self._absent - set(ids))}: not among the servos {ids}")
        self.on_error = on_error
        self.last_error: BaseException | None = None
        self.packets_received = 0
        self.instructions_received: collections.Counter[int] = collections.Counter()  # instruction -> packets
        self.replies_sent = 0
        self._faults = {i: _Faults() for i in self.servos}
        self._lock = threading.RLock()
        self._idle = threading.Condition(self._lock)
        self._barrier_sent = 0
        self._barrier_seen = 0
        self._stop = threading.Event()
        self._commands: queue.Queue[tuple[str, threading.Event]] = queue.Queue()
        self._wake_r, self._wake_w = os.pipe()
        self._master: int | None = None
        self._slave: int | None = None
        self._port: str | None = None
        self._reappear_at_s: float | None = None  # time.monotonic() at which a vanished port comes back
        self._thread: threading.Thread | None = None
        self._closed = False
        self._open_pty()

    # -- lifecycle -------------------------------------------------------------------------
    @property
    def port(self) -> str:
        """The path to open: the symlink if there is one, else the pty itself."""
        return self.link or self.pty_path

    @property
    def pty_path(self) -> str:
        if self._port is None:
            raise DeviceStateError("dxl emulator: the port has vanished (call reappear())")
        return self._port

    def start(self) -> "DxlEmulator":
        if self._closed:
            raise DeviceStateError("dxl emulator: already stopped; make a new one")
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name=f"dxl-emulator({self.port})", daemon=True)
            self._thread.start()
            log.info("dxl emulator: %d servo(s) %s on %s", len(self.servos), sorted(self.servos), self.port)
        return self

    def stop(self, timeout: float | None = 2.0) -> None:
        """Stop the thread and release the pty and the symlink. Safe to call twice."""
        if self._closed:
            return
        self._stop.set()
        self._wake()
        if self._thread is not None:
            self._thread.join(timeout)
            if self._thread.is_alive():
                raise DeviceTimeoutError(f"dxl emulator on {self.link or self._port}: thread did not stop in {timeout} s")
        self._closed = True
        self._close_pty()
        for fd in (self._wake_r, self._wake_w):
            os.close(fd)

    close = stop

    def __enter__(self) -> "DxlEmulator":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def __del__(self) -> None:
        if not getattr(self, "_closed", True):
            log.warning("dxl emulator on %s was not stopped", getattr(self, "_port", "?"))

    # -- fault injection -------------------------------------------------------------------
    def drop_replies(self, servo_id: int, count: int = 1) -> None:
        """The next `count` replies of `servo_id` are not sent (a timeout for the client)."""
        with self._lock:
            self._faults[servo_id].drop += count

    def corrupt_replies(self, servo_id: int, count: int = 1) -> None:
        """The next `count` replies of `servo_id` go out with a wrong CRC."""
        with self._lock:
            self._faults[servo_id].corrupt += count

    def delay_replies(self, servo_id: int, delay_s: float, count: int = 1) -> None:
        """The next `count` replies of `servo_id` go out `delay_s` late (real time)."""
        with self._lock:
            faults = self._faults[servo_id]
            faults.delay_s, faults.delay_count = delay_s, faults.delay_count + count

    def set_hardware_error(self, servo_id: int, bits: int) -> None:
        """Raise Hardware Error Status bits; shutdown bits cut torque (like a real servo)."""
        with self._lock:
            self.servos[servo_id].set_hardware_error(bits)

    def power_cycle(self, servo_id: int) -> None:
        """The servo loses power and comes back: RAM defaults (torque off, indirect map reset)."""
        with self._lock:
            self.servos[servo_id].reboot(self.clock.monotonic())

    def remove_servo(self, servo_id: int) -> None:
        """The servo leaves the bus (its cable unplugged, its power gone): it hears nothing and
        answers nothing until `add_servo`."""
        with self._lock:
            self.servos[servo_id].update(self.clock.monotonic())
            self._absent.add(servo_id)

    def add_servo(self, servo_id: int) -> None:
        """The servo is back on the bus, just powered up: RAM defaults (torque off), silent
        while it boots."""
        with self._lock:
            servo = self.servos[servo_id]
            self._absent.discard(servo_id)
            servo.reboot(self.clock.monotonic())
    def brown_out(self, seconds: float, bits: int = 0) -> None:
        """Every servo loses power for `seconds` (the emulator's clock): silent all that time,
        then back with RAM defaults (torque off, Goal Position := present, profiles and the
        indirect map at their defaults) and Hardware Error Status `bits` (0x01: input voltage)."""
        if not 0.0 <= seconds < float("inf"):
            raise ValueError(f"brown-out of {seconds} s: expected a finite time >= 0")
        with self._lock:
            now = self.clock.monotonic()
            for servo in self.servos.values():
                servo.reboot(now)
                servo.booting_until_s = now + max(seconds, servo.BOOT_TIME_S)
                if bits:
                    servo.set_hardware_error(bits)

    def clear_faults(self, servo_id: int | None = None) -> None:
        """Cancel the pending dropped, corrupted and delayed replies of `servo_id` (or of all).
        Hardware errors stay: a servo clears them only when it reboots."""
        with self._lock:
            if servo_id is not None and servo_id not in self._faults:
                raise KeyError(f"dxl emulator: no servo with id {servo_id}")
            for i in self._faults if servo_id is None else [servo_id]:
                self._faults[i] = _Faults()

    def vanish(self, timeout: float = 2.0, *, for_s: float | None = None) -> None:
        """The adapter is unplugged: the pty closes (clients get EIO) and the symlink goes.
        With `for_s` it comes back by itself that many seconds later (real time; the
        emulator must be running), else on `reappear()`."""
        if for_s is not None and not 0.0 <= for_s < float("inf"):
            raise ValueError(f"vanish for {for_s} s: expected a finite time >= 0")
        with self._lock:
            self._reappear_at_s = None if for_s is None else time.monotonic() + for_s
        self._command("vanish", timeout)

    def reappear(self, timeout: float = 2.0) -> None:
        """The adapter is back: a new pty, and the symlink points at it."""
        self._command("reappear", timeout)

    def wait_port(self, timeout: float = 2.0) -> str:
        """Wait until the port is there (it may have vanished); returns the path to open."""
        with self._idle:
            if not self._idle.wait_for(lambda: self._port is not None, timeout):
                raise DeviceTimeoutError(f"dxl emulator: the port is not back after {timeout} s")
            return self.port

    def injected(self) -> dict[str, Any]:
        """What is injected now: for each servo id its pending dropped, corrupted and delayed
        replies, its Hardware Error Status, torque and whether it is booting; whether the
        port has vanished and in how many seconds it comes back by itself."""
        with self._lock:
            now = self.clock.monotonic()
            servos: dict[int, dict[str, Any]] = {}
            for servo_id, servo in self.servos.items():
                faults = self._faults[servo_id]
                servos[servo_id] = {
                    "drop": faults.drop, "corrupt": faults.corrupt, "delay_count": faults.delay_count,
                    "delay_s": faults.delay_s if faults.delay_count else 0.0,
                    "hardware_error": servo.hardware_error_bits,
                    "torque_on": servo.torque_on, "booting": servo.is_booting(now),
                    "present": servo_id not in self._absent,
                }
            back_in_s = None
            if self._port is None and self._reappear_at_s is not None:
                back_in_s = round(max(0.0, self._reappear_at_s - time.monotonic()), 3)
            return {"port": self._port, "link": self.link, "vanished": self._port is None,
                    "back_in_s": back_in_s, "servos": servos}

    def servo(self, servo_id: int) -> Any:
        """The servo, its motion brought up to now, for inspection. Read it after
        `wait_idle()`: the emulator thread may change it while requests are in flight."""
        with self._lock:
            servo = self.servos[servo_id]
            servo.update(self.clock.monotonic())
            return servo

    def wait_idle(self, timeout: float = 2.0) -> None:
        """Wait until every byte written to the emulator so far has been handled and answered.

        A marker packet goes into the pty behind the client's bytes (through the
        emulator's own handle on the slave side); bytes are handled in order, so once the
        marker is seen everything before it was. No polling, no guessing at timing.
        """
        with self._idle:
            if self._slave is None or self._thread is None:
                return
            self._barrier_sent += 1
            token = self._barrier_sent
            build = build_packet1 if self.protocol == 1.0 else build_packet
            os.write(self._slave, build(BROADCAST_ID, _INST_BARRIER, token.to_bytes(4, "little")))
            if not self._idle.wait_for(lambda: self._barrier_seen >= token or self._slave is None, timeout):
                raise DeviceTimeoutError(f"dxl emulator on {self.port}: not idle after {timeout} s")

    # -- the thread ------------------------------------------------------------------------
    def _run(self) -> None:
        parser = _Parser(self.protocol)
        while not self._stop.is_set():
            wait_s = self._reappear_if_due()
            master = self._master
            fds = [self._wake_r] + ([master] if master is not None else [])
            try:
                readable, _, _ = select.select(fds, [], [], wait_s)
            except OSError as err:
                log.error("dxl emulator on %s: select failed, stopping: %s", self._port, err)
                self._report(err)
                break
            if self._wake_r in readable:
                os.read(self._wake_r, 64)
                self._run_commands(parser)
                continue
            if master is None or master not in readable:
                continue
            try:
                data = os.read(master, 4096)
            except OSError:
                data = b""  # no client has the slave open: nothing to read
            try:
                for packet in parser.feed(data):
                    self._handle(packet)
            except Exception as err:  # a bug here must not kill the bus silently
                log.exception("dxl emulator on %s: failed handling a packet", self._port)
                self._report(err)
        self._run_commands(parser)

    def _reappear_if_due(self) -> float:
        """Bring a port that vanished for a while back once its time has come; returns how
        long the thread may wait for input before looking again."""
        with self._lock:
            at_s = self._reappear_at_s
        if at_s is None or self._master is not None:
            return 0.5
        left_s = at_s - time.monotonic()
        if left_s > 0.0:
            return min(0.5, left_s)
        with self._lock:
            self._reappear_at_s = None
        self._open_pty()
        log.info("dxl emulator: port back at %s", self.port)
        return 0.5

    def _report(self, err: BaseException) -> None:
        self.last_error = err
        if self.on_error is not None:
            self.on_error(err)

    def _run_commands(self, parser: _Parser) -> None:
        while True:
            try:
                name, done = self._commands.get_nowait()
            except queue.Empty:
                return
            if name == "vanish":
                self._close_pty()
                parser.reset()
                log.info("dxl emulator: port vanished")
            elif name == "reappear":
                with self._lock:
                    self._reappear_at_s = None
                if self._master is None:
                    self._open_pty()
                    log.info("dxl emulator: port back at %s", self.port)
            done.set()

    def _command(self, name: str, timeout: float) -> None:
        done = threading.Event()
        self._commands.put((name, done))
        self._wake()
        if self._thread is None:  # not started: do it here
            self._run_commands(_Parser(self.protocol))
        if not done.wait(timeout):
            raise DeviceTimeoutError(f"dxl emulator: {name} not done in {timeout} s")

    def _wake(self) -> None:
        try:
            os.write(self._wake_w, b"x")
        except OSError:
            pass  # closed during stop

    def _open_pty(self) -> None:
        master, slave = os.openpty()
        # Raw mode from the start: no echo or newline translation even before a client
        # configures the port. The emulator keeps the slave open so the master never
        # reads EIO between clients.
        tty.setraw(slave)
        path = os.ttyname(slave)
        if self.link:
            tmp = f"{self.link}.{os.getpid()}.tmp"
            if os.path.lexists(tmp):
                os.unlink(tmp)
            os.symlink(path, tmp)
            os.replace(tmp, self.link)  # atomic, like udev updating its symlink
        with self._idle:
            self._master, self._slave = master, slave
            self._port = path
            self._idle.notify_all()

    def _close_pty(self) -> None:
        for fd in (self._master, self._slave):
            if fd is not None:
                os.close(fd)
        with self._idle:
            self._master = self._slave = None
            self._port = None
            self._idle.notify_all()
        if self.link and os.path.islink(self.link):
            os.unlink(self.link)

    def _client_baud_matches(self) -> bool:
        want = _TERMIOS_SPEEDS.get(self.baud)
        master = self._master
        if master is None:
            return True
        try:
            # On Linux the master reports the slave's termios: the client's baud rate.
            speed = termios.tcgetattr(master)[5]
        except (termios.error, TypeError):
            return True
        return want is None or speed == want

    # -- protocol ----------------------------------------------------------------------------
    def _handle(self, packet: Packet) -> None:
        if packet.instruction == _INST_BARRIER and packet.servo_id == BROADCAST_ID and packet.crc_ok:
            with self._idle:
                self._barrier_seen = max(self._barrier_seen, int.from_bytes(packet.params, "little"))
                self._idle.notify_all()
            return
        with self._lock:
            self.packets_received += 1
            self.instructions_received[packet.instruction] += 1
            if not self._client_baud_matches():
                log.log(TRACE, "dxl emulator: packet at another baud rate ignored")
                return
            now = self.clock.monotonic()
            log.log(TRACE, "dxl emulator: rx id %d inst 0x%02x %s", packet.servo_id, packet.instruction,
                    packet.params.hex())
            replies = self._dispatch(packet, now)
        for servo_id, reply, delay_s in replies:
            if servo_id is None:
                self._write_reply(reply, delay_s, "piece of a fast sync read reply")
            else:
                self._send(servo_id, reply)

    def _dispatch(self, packet: Packet, now: float) -> list[tuple[int | None, bytes, float]]:
        """The replies to one packet in the order they go out: (servo id, status packet,
        0.0), or for a Fast Sync Read (None, each servo's piece of the packet they share,
        the delay before it). Absent servos neither act nor answer. Called with the lock held."""
        servos = {i: s for i, s in self.servos.items() if i not in self._absent} if self._absent else self.servos
        if self.protocol == 1.0:
            return [(i, reply, 0.0) for i, reply in dispatch1(servos, packet, now)]
        if packet.instruction == INST_FAST_SYNC_READ and packet.crc_ok:
            return [(None, piece, delay_s) for delay_s, piece in fast_sync_read(servos, packet.params, now, self)]
        return [(i, reply, 0.0) for i, reply in dispatch2(servos, packet, now)]

    def consume_drop(self, servo_id: int) -> bool:
        faults = self._faults[servo_id]
        if not faults.drop:
            return False
        faults.drop -= 1
        log.debug("dxl emulator: injected fault: reply of id %d dropped", servo_id)
        return True

    def consume_corrupt(self, servo_id: int) -> bool:
        faults = self._faults[servo_id]
        if not faults.corrupt:
            return False
        faults.corrupt -= 1
        log.debug("dxl emulator: injected fault: reply of id %d with a bad %s", servo_id,
                  "checksum" if self.protocol == 1.0 else "CRC")
        return True

    def consume_delay(self, servo_id: int) -> float:
        faults = self._faults[servo_id]
        if not faults.delay_count:
            return 0.0
        faults.delay_count -= 1
        log.debug("dxl emulator: injected fault: reply of id %d %.3f s late", servo_id, faults.delay_s)
        return faults.delay_s

    def _send(self, servo_id: int, reply: bytes) -> None:
        with self._lock:
            if self.consume_drop(servo_id):
                return
            if self.consume_corrupt(servo_id):
                reply = reply[:-1] + bytes([reply[-1] ^ 0xFF])
            delay_s = self.servos[servo_id].return_delay_s + self.consume_delay(servo_id)
        self._write_reply(reply, delay_s, f"reply of id {servo_id}")

    def _write_reply(self, reply: bytes, delay_s: float, what: str) -> None:
        if delay_s > 0:
            # Wire timing (Return Delay Time, injected delays) is real time, not the
            # motion clock: the client's timeouts are real time too.
            time.sleep(delay_s)
        master = self._master
        if master is None:
            return
        try:
            os.write(master, reply)
            with self._lock:
                self.replies_sent += 1
        except OSError as err:
            log.debug("dxl emulator: %s not delivered: %s", what, err)
